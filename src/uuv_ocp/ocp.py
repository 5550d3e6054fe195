"""Symbolic optimal-control problems: declare states, controls, dynamics, costs, constraints.

:class:`Ocp` follows rockit's problem-first style: declare symbols, give continuous-time
dynamics with :meth:`Ocp.set_der`, add costs and constraints as CasADi expressions, and solve
with any backend by name (``uo.solve(ocp, "fatrop", x0=..., parameters=...)``).  The
transcription (multiple shooting for the exact solvers, a condensed rollout for the swarms, the
same integrator for both) is hidden; see ``docs/formulation.md``.

Conventions
-----------
* Stage ``k`` holds ``x_k`` and ``u_k`` for ``k = 0..N-1``; node ``N`` holds ``x_N`` only.
* :meth:`Ocp.add_stage_cost` is summed over ``k = start..N-1`` (``start=0`` by default;
  ``start=1`` drops the constant ``x_0`` term), :meth:`Ocp.add_terminal_cost` at node ``N``.
* :meth:`Ocp.subject_to` with ``at="path"`` holds on every node where its expression is
  defined: ``k = 0..N-1`` if it involves a control, else ``k = 1..N`` (``x_0`` is given).
  ``at="initial"`` is node 0, ``at="terminal"`` node ``N`` (states and parameters only).
* Controls are searched in scaled form ``z = (u − c) / s`` with ``c, s`` the centre and
  half-width of a finite box (``c = 0, s = 1`` on unbounded components), so box bounds become
  ``[-1, 1]``; rate bounds ``|u_k − u_{k−1}| ≤ max_rate · dt`` (``u_{−1}``: the last applied
  control, a parameter) are stage-local through a lifted copy of the previous control.
* Parameters are ``global`` (one value) or ``stagewise`` (one value per node ``0..N``; on an
  interval ``k`` the dynamics see node ``k``'s value).
* Hard constraints are held by the exact solvers; ``soft=ρ`` adds an exact L1 penalty
  ``ρ Σ max(0, violation)`` (through slacks in the NLP).  Derivative-free solvers hold control
  box and rate bounds by their search box and see every other hard constraint as the exact
  penalty ``constraint_penalty · Σ violation`` (terminal equalities: ``terminal_penalty``).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

import uuv_ocp.transcription.collocation  # noqa: F401 - registers the collocation strategy
from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.build import Transcribed
from uuv_ocp.transcription.base import transcription, transcription_names

INTEGRATORS = ("rk4",)
#: The built-in transcriptions (:mod:`uuv_ocp.transcription.base`; more can be registered).
TRANSCRIPTIONS = ("multiple_shooting", "collocation")
PLACES = ("path", "initial", "terminal")
MAX_HORIZON = 10_000  # larger horizons exhaust memory while building the NLP (documented bound)
#: Largest number of entries of one declared state, control or parameter.  The NLP holds
#: N + 1 copies of each, and CasADi allocates the symbol at once: ``state("z", 10**12)`` died
#: in ``std::bad_alloc``.  1e5 is far beyond the dense OCPs this package builds (a 6-DOF
#: vehicle has 12 states) and still allocates in milliseconds.
MAX_SYMBOL_SIZE = 100_000

_COMPARISONS = {ca.OP_LE: "<=", ca.OP_LT: "<", ca.OP_EQ: "=="}


@dataclass(frozen=True)
class Declared:
    """One declared symbol of an :class:`Ocp` (state, control or parameter)."""

    name: str
    kind: str
    symbol: ca.SX
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    max_rate: np.ndarray | None = None
    stagewise: bool = False

    @property
    def size(self) -> int:
        """Number of scalar entries."""
        return int(self.symbol.numel())


@dataclass(frozen=True)
class CostTerm:
    """A cost term: ``‖residual‖²`` (least squares) or a scalar ``expression``, from ``start``."""

    expression: ca.SX
    least_squares: bool
    start: int


@dataclass(frozen=True)
class Constraint:
    """``lower <= expression <= upper`` on the nodes of ``place`` (hard, or soft with ``weight``)."""

    expression: ca.SX
    lower: np.ndarray
    upper: np.ndarray
    place: str  # "stage" (k = 0..N-1), "node" (k = 1..N), "initial" (0) or "terminal" (N)
    soft: float | None
    label: str

    @property
    def equality(self) -> np.ndarray:
        """Which entries are equalities."""
        return self.lower == self.upper


def check_transcription(name: object, degree: object, substeps: int) -> tuple[str, int]:
    """Validate an Ocp's ``transcription`` and ``degree``; return them (degree 0: none taken).

    Raises
    ------
    ValueError
        An unregistered transcription, or a degree (or ``substeps``) the strategy refuses.
    """
    strategy = transcription(check.choice("transcription", name, transcription_names()))
    return strategy.name, strategy.check_degree(degree, substeps)


class Ocp(Transcribed):
    """A finite-horizon optimal-control problem declared symbolically.

    Parameters
    ----------
    horizon : int
        Number of intervals N, 1 <= N <= 10 000.
    dt : float
        Interval length (s), > 0.
    integrator : {"rk4"}
        Multiple shooting's integrator on each interval.
    substeps : int
        Integrator steps per interval, >= 1 (multiple shooting; collocation takes 1).
    transcription : {"multiple_shooting", "collocation"} or a registered name
        How the dynamics become constraints (:mod:`uuv_ocp.transcription.base`):
        ``"multiple_shooting"`` (the state at each node is a variable, ``x_{k+1} = F(x_k, u_k)``
        by ``integrator``) or ``"collocation"`` (direct Radau IIA collocation: the exact solvers
        also carry ``degree`` collocation states per interval and the collocation equations;
        rollouts, the swarms and the judge solve those equations per interval,
        :mod:`uuv_ocp.transcription.collocation`).
    degree : int, optional
        Collocation points per interval, 1..5 (Radau IIA of order ``2 degree − 1``); 3 by
        default with ``transcription="collocation"``; only with it.
    terminal_penalty : float
        Exact L1 weight of terminal-equality residuals in the exact solvers' soft fallback and
        in the derivative-free solvers' cost.
    constraint_penalty : float
        Exact L1 weight of every other hard-constraint violation in the derivative-free
        solvers' cost.
    rate_penalty : float
        Weight of the scaled rate-bound excess in the derivative-free solvers' cost.
    name : str
        Label of the problem.

    Examples
    --------
    >>> import casadi as ca, uuv_ocp as uo
    >>> ocp = uo.Ocp(horizon=10, dt=0.1)
    >>> pos = ocp.state("pos"); vel = ocp.state("vel")
    >>> acc = ocp.control("acc", lower=-1.0, upper=1.0)
    >>> ocp.set_der(pos, vel); ocp.set_der(vel, acc)
    >>> ocp.add_stage_cost(pos**2 + 0.1 * acc**2)
    >>> res = uo.solve(ocp, "ipopt", x0=[1.0, 0.0])
    """

    def __init__(
        self,
        horizon: int = 20,
        dt: float = 0.1,
        integrator: str = "rk4",
        substeps: int = 1,
        *,
        transcription: str = "multiple_shooting",
        degree: int | None = None,
        terminal_penalty: float = 1e4,
        constraint_penalty: float = 1e4,
        rate_penalty: float = 1e4,
        name: str = "ocp",
    ) -> None:
        self.horizon = check.positive_int("horizon", horizon)
        if self.horizon > MAX_HORIZON:
            raise ValueError(f"horizon must be an integer <= {MAX_HORIZON}, got {horizon!r}")
        self.dt = check.positive_float("dt", dt)
        self.integrator = check.choice("integrator", integrator, INTEGRATORS)
        self.substeps = check.positive_int("substeps", substeps)
        self.transcription, self.degree = check_transcription(transcription, degree, self.substeps)
        self.terminal_penalty = check.positive_float("terminal_penalty", terminal_penalty)
        self.constraint_penalty = check.positive_float("constraint_penalty", constraint_penalty)
        self.rate_penalty = check.positive_float("rate_penalty", rate_penalty)
        if not isinstance(name, str):
            raise ValueError(f"name must be a string, got {name!r}")
        self.name = name
        self._states: list[Declared] = []
        self._controls: list[Declared] = []
        self._parameters: list[Declared] = []
        self._previous: dict[str, ca.SX] = {}
        self._derivatives: dict[str, ca.SX] = {}
        self._stage_costs: list[CostTerm] = []
        self._terminal_costs: list[CostTerm] = []
        self._constraints: list[Constraint] = []
        self._frozen = False
        # derived from the declaration once it is frozen: the description, and the slack box
        # of u_prev (no builds, no backends: those live in the package's cache and their owners)
        self._spec: OcpSpec | None = None
        self._previous_bounds: tuple[list[float], list[float]] | None = None

    # ------------------------------------------------------------ declarations
    def _declare(self, kind: str, name: object, size: object, **extra: Any) -> Declared:
        self._check_open(f"declare a {kind}")
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"{kind} name must be a Python identifier string, got {name!r}")
        if name in self._names():
            raise ValueError(f"{kind} {name!r} is already declared (names must be unique)")
        count = _symbol_size(f"size of {kind} {name!r}", size)
        declared = Declared(name, kind, ca.SX.sym(name, count), **extra)
        {"state": self._states, "control": self._controls, "parameter": self._parameters}[kind].append(
            declared
        )
        return declared

    def state(self, name: str, size: int = 1) -> ca.SX:
        """Declare a state of ``size`` entries (1..``MAX_SYMBOL_SIZE``), in the state's order."""
        return self._declare("state", name, size).symbol

    def control(
        self,
        name: str,
        size: int = 1,
        lower: object = -math.inf,
        upper: object = math.inf,
        max_rate: object = None,
    ) -> ca.SX:
        """Declare a control with box bounds and an optional rate bound.

        Parameters
        ----------
        name : str
        size : int
        lower, upper : float or array_like
            Box bounds (units of the control); ``±inf`` for none.
        max_rate : float or array_like, optional
            Bound on ``|u_k − u_{k−1}| / dt`` (units per second), ``inf`` entries for none.
        """
        count = _symbol_size(f"size of control {name!r}", size)
        low = _bound_vector(f"lower of control {name!r}", lower, count)
        high = _bound_vector(f"upper of control {name!r}", upper, count)
        if np.any(low > high):
            raise ValueError(f"lower of control {name!r} must be <= upper, got {low} > {high}")
        rate = None
        if max_rate is not None:
            rate = _bound_vector(f"max_rate of control {name!r}", max_rate, count)
            if np.any(rate <= 0):
                raise ValueError(f"max_rate of control {name!r} must be > 0, got {rate}")
        return self._declare("control", name, count, lower=low, upper=high, max_rate=rate).symbol

    def parameter(self, name: str, size: int = 1, stagewise: bool = False) -> ca.SX:
        """Declare a parameter: one value (``stagewise=False``) or one per node ``k = 0..N``."""
        stagewise = check.boolean(f"stagewise of parameter {name!r}", stagewise)
        return self._declare("parameter", name, size, stagewise=stagewise).symbol

    def previous(self, control: ca.SX) -> ca.SX:
        """Symbol of the control applied on the previous interval, ``u_{k−1}`` (for rate costs).

        At ``k = 0`` it is the last applied control ``u_prev`` given at solve time.
        """
        declared = self._find(control, self._controls, "previous")
        if declared.name not in self._previous:
            self._check_open("use previous()")
            self._previous[declared.name] = ca.SX.sym(f"{declared.name}_prev", declared.size)
        return self._previous[declared.name]

    def set_der(self, state: ca.SX, derivative: object) -> None:
        """Continuous-time dynamics ``d state / dt = derivative``."""
        self._check_open("set dynamics")
        declared = self._find(state, self._states, "set_der")
        if declared.name in self._derivatives:
            raise ValueError(f"state {declared.name!r} already has dynamics (set_der called twice)")
        expression = _as_sx("derivative", derivative)
        if expression.shape != declared.symbol.shape:
            raise ValueError(
                f"derivative of state {declared.name!r} must have shape {declared.symbol.shape}, "
                f"got {expression.shape}"
            )
        # an undeclared symbol here crashed much later, in CasADi's Function constructor
        self._check_symbols(expression, f"derivative of state {declared.name!r}")
        _check_constants(expression, f"derivative of state {declared.name!r}", allow_inf=False)
        self._derivatives[declared.name] = expression

    # ------------------------------------------------------------------ costs
    def add_stage_cost(
        self,
        expression: object = None,
        *,
        residual: object = None,
        weight: object = None,
        start: int = 0,
    ) -> None:
        """Add ``expression`` (scalar) or ``Σ weight_i residual_i²`` summed over ``k = start..N-1``.

        The residual form keeps the objective a sum of squares, which the Gauss–Newton SQP
        backend uses for a positive semidefinite Hessian.
        """
        start = check.positive_int("start", start, minimum=0)
        if start >= self.horizon:
            raise ValueError(f"start must be < horizon = {self.horizon}, got {start}")
        self._stage_costs.append(self._cost_term(expression, residual, weight, start, "stage cost"))

    def add_terminal_cost(
        self, expression: object = None, *, residual: object = None, weight: object = None
    ) -> None:
        """Add a terminal cost at node ``N`` (states and parameters only)."""
        term = self._cost_term(expression, residual, weight, 0, "terminal cost")
        if self._depends_on_controls(term.expression):
            raise ValueError("terminal cost must not depend on controls (node N has none)")
        self._terminal_costs.append(term)

    def _cost_term(
        self, expression: object, residual: object, weight: object, start: int, what: str
    ) -> CostTerm:
        self._check_open(f"add a {what}")
        if (expression is None) == (residual is None):
            raise ValueError(f"{what}: give exactly one of expression or residual=")
        if expression is not None:
            if weight is not None:
                raise ValueError(f"{what}: weight= goes with residual=, not with an expression")
            sx = _as_sx("expression", expression)
            if sx.shape != (1, 1):
                raise ValueError(f"{what} expression must be scalar, got shape {sx.shape}")
            self._check_symbols(sx, what)
            _check_constants(sx, what, allow_inf=False)
            return CostTerm(sx, False, start)
        sx = ca.vec(_as_sx("residual", residual))
        if weight is not None:
            weights = _bound_vector("weight", weight, sx.numel())
            if np.any(weights < 0) or not np.all(np.isfinite(weights)):
                raise ValueError(f"weight must be finite and >= 0, got {weights}")
            sx = ca.sqrt(ca.DM(weights)) * sx
        self._check_symbols(sx, what)
        _check_constants(sx, f"{what} residual", allow_inf=False)
        return CostTerm(sx, True, start)

    # ------------------------------------------------------------- constraints
    def subject_to(self, constraint: object, *, soft: float | None = None, at: str = "path") -> None:
        """Add constraints given as CasADi comparisons (``<=``, ``>=``, ``==``), elementwise.

        Parameters
        ----------
        constraint : casadi.SX
            e.g. ``ca.sumsqr(pos - c) >= r**2``, ``vel <= 2``, ``pos == goal``.
        soft : float, optional
            Exact L1 penalty weight ρ > 0 (a soft constraint); ``None`` for a hard one.
        at : {"path", "initial", "terminal"}
            Where it holds (see the module notes).
        """
        sx = _as_sx("constraint", constraint)
        lower, upper, expressions = [], [], []
        for i in range(sx.numel()):
            entry = sx[i]
            op = next((op for op in _COMPARISONS if entry.is_op(op)), None)
            if op is None:
                raise ValueError(
                    "constraint must be a CasADi comparison (<=, >=, ==) of expressions, got "
                    f"{entry}; use bounded(lower, expression, upper) for two-sided bounds"
                )
            left, right = entry.dep(0), entry.dep(1)
            expressions.append(left - right)
            lower.append(0.0 if op == ca.OP_EQ else -math.inf)
            upper.append(0.0)
        self._add_constraint(ca.vertcat(*expressions), np.array(lower), np.array(upper), soft, at, str(sx))

    def bounded(
        self, lower: object, expression: object, upper: object, *, soft: float | None = None, at: str = "path"
    ) -> None:
        """Add ``lower <= expression <= upper`` (elementwise; ``±inf`` for one-sided)."""
        sx = ca.vec(_as_sx("expression", expression))
        low = _bound_vector("lower", lower, sx.numel())
        high = _bound_vector("upper", upper, sx.numel())
        if np.any(low > high):
            raise ValueError(f"lower must be <= upper, got {low} and {high}")
        self._add_constraint(sx, low, high, soft, at, f"{low} <= {sx} <= {high}")

    def _add_constraint(
        self, sx: ca.SX, lower: np.ndarray, upper: np.ndarray, soft: object, at: object, label: str
    ) -> None:
        self._check_open("add a constraint")
        at = check.choice("at", at, PLACES)
        weight = None if soft is None else check.positive_float("soft", soft)
        self._check_symbols(sx, "constraint")
        # ``x <= nan`` reached the solver, which read the NaN row as anything it liked
        _check_constants(sx, f"constraint {_short(label)}", allow_inf=True)
        controls = self._depends_on_controls(sx)
        if at == "terminal" and controls:
            raise ValueError("a constraint at='terminal' must not depend on controls (node N has none)")
        place = {"initial": "initial", "terminal": "terminal"}.get(at, "stage" if controls else "node")
        self._constraints.append(Constraint(sx, lower, upper, place, weight, label))

    # --------------------------------------------------------------- helpers
    def _names(self) -> set[str]:
        return {d.name for d in (*self._states, *self._controls, *self._parameters)}

    def _check_open(self, action: str) -> None:
        if self._frozen:
            raise ValueError(
                f"cannot {action}: the Ocp {self.name!r} is built and immutable; create a new Ocp"
            )

    @staticmethod
    def _find(symbol: object, pool: Sequence[Declared], what: str) -> Declared:
        if isinstance(symbol, ca.SX):
            for declared in pool:
                if symbol.shape == declared.symbol.shape and ca.is_equal(symbol, declared.symbol):
                    return declared
        kind = pool[0].kind if pool else "declared symbol"
        raise ValueError(f"{what} expects a {kind} symbol returned by the Ocp's declaration, got {symbol!r}")

    def _all_symbols(self) -> list[ca.SX]:
        declared = [d.symbol for d in (*self._states, *self._controls, *self._parameters)]
        return declared + list(self._previous.values())

    def _check_symbols(self, sx: ca.SX, what: str) -> None:
        known = {ca.SX(s).name() for symbol in self._all_symbols() for s in ca.symvar(symbol)}
        unknown = sorted({s.name() for s in ca.symvar(sx)} - known)
        if unknown:
            raise ValueError(f"{what} depends on undeclared symbol(s) {unknown}; declare them with the Ocp")

    @staticmethod
    def _depends_on(sx: ca.SX, symbols: Sequence[ca.SX]) -> bool:
        return bool(symbols) and ca.depends_on(sx, ca.vertcat(*symbols))

    def _depends_on_controls(self, sx: ca.SX) -> bool:
        return self._depends_on(sx, [d.symbol for d in self._controls] + list(self._previous.values()))

    # ------------------------------------------------------------ dimensions
    @property
    def state_dim(self) -> int:
        """Number of scalar states."""
        return sum(d.size for d in self._states)

    @property
    def control_size(self) -> int:
        """Number of scalar controls per interval."""
        return sum(d.size for d in self._controls)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the declared states, in order."""
        return tuple(d.name for d in self._states)

    @property
    def control_names(self) -> tuple[str, ...]:
        """Names of the declared controls, in order."""
        return tuple(d.name for d in self._controls)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the declared parameters, in order."""
        return tuple(d.name for d in self._parameters)

    # ------------------------------------------------------------------ build
    def spec(self) -> OcpSpec:
        """Check the declaration, make the Ocp immutable and return its frozen description."""
        if self._spec is None:
            with BUILD_LOCK:  # CasADi Functions are built here (uuv_ocp._concurrency)
                if self._spec is None:
                    self._spec = _freeze(self)
                    self._frozen = True
        return self._spec

    def instance_parameters(
        self,
        x0: object,
        t0: float = 0.0,
        *,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: Mapping[str, object] | None = None,
    ) -> np.ndarray:
        """Parameter vector of one instance, in the signature every problem shares.

        An Ocp is time-invariant and has no current of its own: ``t0`` must be 0 and
        ``current`` ``None`` (its data go in ``parameters``); see :meth:`parameters`.
        """
        if current is not None:
            raise ValueError("current is a TrackingProblem argument; an Ocp takes its data in parameters=")
        if t0 != 0.0:
            raise ValueError("t0 is a TrackingProblem argument; an Ocp is time-invariant (use parameters=)")
        return self.parameters(x0, parameters, u_prev)

    def parameters(
        self, x0: object, parameters: Mapping[str, object] | None = None, u_prev: object | None = None
    ) -> np.ndarray:
        """Parameter vector ``p = [x0, u_prev, globals…, stagewise…]`` of one instance.

        Parameters
        ----------
        x0 : array_like, shape (nx,)
            Initial state.
        parameters : dict, optional
            Value of every declared parameter by name: shape ``(size,)`` for a global one,
            ``(N+1, size)`` for a stagewise one (a ``(size,)`` value is held on every node).
        u_prev : array_like, shape (nu,), optional
            Last applied control (for rate bounds and ``previous()``); zero clipped into the box
            by default; it must lie in the control box (to 1e-6 relative: a solver's bound
            tolerance).

        Raises
        ------
        ValueError
            A wrong shape, a non-finite entry, an entry of ``x0`` beyond ±1e9 (the plausibility
            bound :data:`uuv_ocp._validation.PLAUSIBLE_MAGNITUDE`), ``u_prev`` outside the box,
            an unknown, missing or non-numeric parameter.
        """
        spec = self.spec()
        x0 = check.plausible_array("x0", x0, (spec.state_dim,))
        u_prev = self.check_previous(u_prev)
        if not isinstance(parameters, (Mapping, type(None))):
            raise ValueError(f"parameters must be a dict of name -> value, got {check.shown(parameters)}")
        given = dict(parameters or {})
        unknown = sorted(set(given) - set(spec.layout.entries))
        if unknown:
            raise ValueError(
                f"parameters has unknown name(s) {unknown}; declared: {sorted(spec.layout.entries)}"
            )
        checked = {}
        for name, (_, size, stagewise) in spec.layout.entries.items():
            if name not in given:
                raise ValueError(f"parameter {name!r} is missing: pass parameters={{{name!r}: ...}}")
            try:
                value = np.asarray(given[name], dtype=float) if not isinstance(given[name], str) else None
            except (TypeError, ValueError):
                value = None
            if value is None:
                raise ValueError(f"parameter {name!r} must be numbers, got {check.shown(given[name])}")
            if (
                stagewise
                and value.shape in ((size,), (1, size))
                or (stagewise and size == 1 and value.ndim == 0)
            ):
                value = np.broadcast_to(value.reshape(1, size), (spec.horizon + 1, size))
            expected = (spec.horizon + 1, size) if stagewise else (size,)
            if not stagewise and value.ndim == 0 and size == 1:
                value = value.reshape(1)
            if stagewise and size == 1 and value.shape == (spec.horizon + 1,):
                value = value.reshape(-1, 1)
            value = check.finite_array(f"parameters[{name!r}]", value, expected)
            checked[name] = value
        return self.pack(x0, u_prev, checked)

    def check_previous(self, u_prev: object | None) -> np.ndarray:
        """Validate the last applied control (``None``: zero clipped to the box): finite, inside the box.

        Zero clipped, as ``simulate`` starts: a box that excludes zero (a propeller floored
        above 0 rpm) must not refuse a call that gives no previous control.
        """
        spec = self.spec()
        if u_prev is None:
            u_prev = np.clip(np.zeros(spec.control_size), spec.lower, spec.upper)
        # the closed loop's hot path: one comparison with the slack box accepts a good value;
        # anything else takes the checks below for the error
        try:
            value = np.array(u_prev, dtype=float)
        except (TypeError, ValueError):
            pass
        else:
            if value.shape == (spec.control_size,) and check.within(value, *self.previous_bounds()):
                return value
        u_prev = check.finite_array("u_prev", u_prev, (spec.control_size,))
        # solvers hold the box to their tolerance (IPOPT: ~1e-8 relative); more is an error
        slack = 1e-6 * np.maximum(1.0, np.abs(spec.lower)), 1e-6 * np.maximum(1.0, np.abs(spec.upper))
        if np.any(u_prev < spec.lower - slack[0]) or np.any(u_prev > spec.upper + slack[1]):
            raise ValueError(
                f"u_prev must lie inside the control bounds [{spec.lower}, {spec.upper}], got {u_prev}"
            )
        return u_prev

    def previous_bounds(self) -> tuple[list[float], list[float]]:
        """Return the slack box :meth:`check_previous` accepts a last control in (float lists, built once).

        The box widened by ``1e-6 · max(1, |bound|)`` (N, N·m), its infinite ends made the
        largest float so that NaN and ±inf fail ``lower <= u <= upper``.
        """
        bounds = self._previous_bounds
        if bounds is None:
            spec = self.spec()
            slack = 1e-6 * np.maximum(1.0, np.abs(spec.lower)), 1e-6 * np.maximum(1.0, np.abs(spec.upper))
            largest = np.finfo(float).max
            bounds = (
                np.maximum(spec.lower - slack[0], -largest).tolist(),
                np.minimum(spec.upper + slack[1], largest).tolist(),
            )
            self._previous_bounds = bounds
        return bounds

    def pack(self, x0: np.ndarray, u_prev: np.ndarray, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """Assemble ``p`` from already checked parts (no validation: the closed loop's hot path).

        ``values`` holds every declared parameter in the shape :meth:`parameters` checks.
        """
        spec = self.spec()
        p = np.empty(spec.layout.size)
        p[spec.layout.x0] = x0
        p[spec.layout.u_prev] = u_prev
        for name, (part, _, _) in spec.layout.entries.items():
            p[part] = np.ravel(values[name])
        return p


@dataclass(frozen=True)
class ParameterLayout:
    """Where each part sits in the parameter vector ``p`` of a built :class:`Ocp`."""

    x0: slice
    u_prev: slice
    entries: dict  # name -> (slice, size, stagewise)
    size: int


@dataclass(frozen=True)
class OcpSpec:
    """The frozen, checked description of an :class:`Ocp` that transcriptions consume.

    Stage functions take ``(x, u, u_prev, p_global, p_stage)`` in physical units; terminal
    ones ``(x, p_global, p_stage)``.
    """

    name: str
    horizon: int
    dt: float
    substeps: int
    transcription: str
    degree: int  # collocation points per interval; 0 for multiple shooting
    state_dim: int
    control_size: int
    global_dim: int
    stage_dim: int
    lower: np.ndarray
    upper: np.ndarray
    max_rate: np.ndarray  # inf where a component has no rate bound
    control_centre: np.ndarray
    control_scale: np.ndarray
    lifted: bool
    dynamics: ca.Function  # (x, u, p_stage, p_global) -> xdot
    stage_residual: tuple  # of (start, Function(x, u, u_prev, pg, ps) -> residual)
    stage_expression: tuple  # of (start, Function(...) -> scalar)
    terminal_residual: ca.Function | None  # (x, pg, ps) -> residual
    terminal_expression: ca.Function | None  # (x, pg, ps) -> scalar
    constraints: tuple  # of (Constraint, Function)
    terminal_penalty: float
    constraint_penalty: float
    rate_penalty: float
    layout: ParameterLayout
    key: str  # content digest: equal problems share builds

    @property
    def scaled_lower(self) -> np.ndarray:
        """Lower bound of the scaled control ``z`` per component."""
        return (self.lower - self.control_centre) / self.control_scale

    @property
    def scaled_upper(self) -> np.ndarray:
        """Upper bound of the scaled control ``z`` per component."""
        return (self.upper - self.control_centre) / self.control_scale

    @property
    def rate_step_bound(self) -> np.ndarray:
        """Largest scaled control change per interval (inf where unbounded)."""
        return self.max_rate * self.dt / self.control_scale

    @property
    def has_terminal_equality(self) -> bool:
        """Whether a hard terminal equality exists (then a soft fallback NLP is built)."""
        return any(
            c.place == "terminal" and c.soft is None and np.all(c.equality) for c, _ in self.constraints
        )

    def physical(self, scaled: ca.SX | np.ndarray) -> Any:
        """``u = c + s ⊙ z`` (zero centres skipped, so the arithmetic matches ``s ⊙ z``)."""
        if isinstance(scaled, np.ndarray):
            return self.control_centre + self.control_scale * scaled
        value = scaled * ca.DM(self.control_scale)
        return value + ca.DM(self.control_centre) if np.any(self.control_centre) else value

    def scaled(self, physical: Any) -> Any:
        """``z = (u − c) / s``."""
        if isinstance(physical, np.ndarray):
            return (physical - self.control_centre) / self.control_scale
        shifted = physical - ca.DM(self.control_centre) if np.any(self.control_centre) else physical
        return shifted / ca.DM(self.control_scale)


def _check_declaration(ocp: Ocp) -> None:
    """Refuse an Ocp that cannot be transcribed, naming what it misses."""
    if not ocp._states:
        raise ValueError("the Ocp declares no state: call ocp.state(...)")
    if not ocp._controls:
        raise ValueError("the Ocp declares no control: call ocp.control(...)")
    missing = [d.name for d in ocp._states if d.name not in ocp._derivatives]
    if missing:
        raise ValueError(f"state(s) {missing} have no dynamics: call ocp.set_der(state, derivative)")
    if not (ocp._stage_costs or ocp._terminal_costs):
        raise ValueError("the Ocp has no cost: call add_stage_cost or add_terminal_cost")


def _control_scaling(ocp: Ocp) -> tuple[np.ndarray, ...]:
    """Return the controls' box, rate bound, and the centre and half-width that scale a finite box."""
    lower = np.concatenate([d.lower for d in ocp._controls])
    upper = np.concatenate([d.upper for d in ocp._controls])
    rate = np.concatenate(
        [d.max_rate if d.max_rate is not None else np.full(d.size, math.inf) for d in ocp._controls]
    )
    finite = np.isfinite(lower) & np.isfinite(upper) & (upper > lower)
    centre = np.zeros_like(lower)
    scale = np.ones_like(lower)
    centre[finite] = 0.5 * (lower[finite] + upper[finite])
    scale[finite] = 0.5 * (upper[finite] - lower[finite])
    return lower, upper, rate, centre, scale


def _freeze(ocp: Ocp) -> OcpSpec:
    _check_declaration(ocp)
    x = ca.vertcat(*[d.symbol for d in ocp._states])
    u = ca.vertcat(*[d.symbol for d in ocp._controls])
    previous = ca.vertcat(
        *[ocp._previous.get(d.name, ca.SX.sym(f"{d.name}_prev_unused", d.size)) for d in ocp._controls]
    )
    globals_ = [d for d in ocp._parameters if not d.stagewise]
    stagewise = [d for d in ocp._parameters if d.stagewise]
    pg = ca.vertcat(*[d.symbol for d in globals_]) if globals_ else ca.SX(0, 1)
    ps = ca.vertcat(*[d.symbol for d in stagewise]) if stagewise else ca.SX(0, 1)
    xdot = ca.vertcat(*[ocp._derivatives[d.name] for d in ocp._states])
    if ca.depends_on(xdot, previous) if previous.numel() else False:
        raise ValueError("dynamics must not depend on previous() controls")
    dynamics = ca.Function("dynamics", [x, u, ps, pg], [xdot], ["x", "u", "p_stage", "p_global"], ["xdot"])
    stage_inputs = [x, u, previous, pg, ps]
    stage_names = ["x", "u", "u_prev", "p_global", "p_stage"]
    terminal_inputs, terminal_names = [x, pg, ps], ["x", "p_global", "p_stage"]

    def grouped(terms: list[CostTerm], least_squares: bool) -> tuple:
        starts = sorted({t.start for t in terms if t.least_squares == least_squares})
        out = []
        for start in starts:
            chosen = [t.expression for t in terms if t.least_squares == least_squares and t.start == start]
            value = ca.vertcat(*chosen) if least_squares else sum(chosen[1:], chosen[0])
            label = "residual" if least_squares else "cost"
            out.append(
                (start, ca.Function(f"stage_{label}_{start}", stage_inputs, [value], stage_names, [label]))
            )
        return tuple(out)

    def terminal(least_squares: bool) -> ca.Function | None:
        chosen = [t.expression for t in ocp._terminal_costs if t.least_squares == least_squares]
        if not chosen:
            return None
        value = ca.vertcat(*chosen) if least_squares else sum(chosen[1:], chosen[0])
        return ca.Function("terminal_cost", terminal_inputs, [value], terminal_names, ["value"])

    constraints = []
    for i, constraint in enumerate(ocp._constraints):
        if constraint.place == "terminal":
            function = ca.Function(f"c{i}", terminal_inputs, [constraint.expression], terminal_names, ["g"])
        else:
            function = ca.Function(f"c{i}", stage_inputs, [constraint.expression], stage_names, ["g"])
        constraints.append((constraint, function))
    lower, upper, rate, centre, scale = _control_scaling(ocp)
    lifted = bool(np.any(np.isfinite(rate)) or ocp._previous)
    layout = _layout(ocp, globals_, stagewise)
    # one mapping feeds both the content key and the constructor: Any, as OcpSpec's fields differ in type
    spec_fields: dict[str, Any] = dict(
        name=ocp.name,
        horizon=ocp.horizon,
        dt=ocp.dt,
        substeps=ocp.substeps,
        transcription=ocp.transcription,
        degree=ocp.degree,
        state_dim=int(x.numel()),
        control_size=int(u.numel()),
        global_dim=int(pg.numel()),
        stage_dim=int(ps.numel()),
        lower=lower,
        upper=upper,
        max_rate=rate,
        control_centre=centre,
        control_scale=scale,
        lifted=lifted,
        dynamics=dynamics,
        stage_residual=grouped(ocp._stage_costs, True),
        stage_expression=grouped(ocp._stage_costs, False),
        terminal_residual=terminal(True),
        terminal_expression=terminal(False),
        constraints=tuple(constraints),
        terminal_penalty=ocp.terminal_penalty,
        constraint_penalty=ocp.constraint_penalty,
        rate_penalty=ocp.rate_penalty,
        layout=layout,
    )
    # the strategy's class is part of the content: a name registered again (overwrite=True)
    # for another strategy does not reuse the old one's builds
    strategy = type(transcription(ocp.transcription))
    keyed = {
        **spec_fields,
        "transcription": f"{ocp.transcription}:{strategy.__module__}.{strategy.__qualname__}",
    }
    return OcpSpec(**spec_fields, key=_content_key(keyed))


def _layout(ocp: Ocp, globals_: list[Declared], stagewise: list[Declared]) -> ParameterLayout:
    nx, nu, n = ocp.state_dim, ocp.control_size, ocp.horizon
    entries: dict[str, tuple[slice, int, bool]] = {}
    offset = nx + nu
    for d in globals_:
        entries[d.name] = (slice(offset, offset + d.size), d.size, False)
        offset += d.size
    for d in stagewise:
        entries[d.name] = (slice(offset, offset + d.size * (n + 1)), d.size, True)
        offset += d.size * (n + 1)
    return ParameterLayout(slice(0, nx), slice(nx, nx + nu), entries, offset)


def _content_key(fields: Mapping[str, Any]) -> str:
    """Digest of everything that defines the problem (expressions printed by CasADi)."""
    digest = hashlib.sha256()
    for name, value in fields.items():
        digest.update(name.encode())
        if isinstance(value, ca.Function):
            digest.update(value.serialize().encode() if hasattr(value, "serialize") else str(value).encode())
        elif isinstance(value, tuple):
            for item in value:
                digest.update(repr(_printable(item)).encode())
        else:
            digest.update(repr(_printable(value)).encode())
    return digest.hexdigest()[:32]


def _printable(value: Any) -> Any:
    if isinstance(value, ca.Function):
        return value.serialize()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return tuple(_printable(v) for v in value)
    if isinstance(value, Constraint):
        return (str(value.expression), value.lower.tolist(), value.upper.tolist(), value.place, value.soft)
    if isinstance(value, ParameterLayout):
        return (value.x0, value.u_prev, sorted((k, str(v)) for k, v in value.entries.items()), value.size)
    return value


def _as_sx(name: str, value: object) -> ca.SX:
    if isinstance(value, ca.SX):
        return value
    if isinstance(value, (ca.MX,)):
        raise ValueError(f"{name} must be a casadi SX expression of the Ocp's symbols, got an MX")
    try:
        return ca.SX(np.asarray(value, dtype=float)) if not isinstance(value, ca.DM) else ca.SX(value)
    except (TypeError, ValueError, NotImplementedError) as error:
        raise ValueError(f"{name} must be a casadi SX expression or numbers, got {value!r}") from error


def _symbol_size(name: str, size: object) -> int:
    """``size`` as an int in ``[1, MAX_SYMBOL_SIZE]``, or ``ValueError`` naming ``name``."""
    count = check.positive_int(name, size)
    if count > MAX_SYMBOL_SIZE:
        raise ValueError(
            f"{name} must be an integer in [1, {MAX_SYMBOL_SIZE}] (the size bound of one declaration), "
            f"got {count}"
        )
    return count


def _check_constants(sx: ca.SX, what: str, *, allow_inf: bool) -> None:
    """Raise ``ValueError`` if ``sx`` holds a NaN constant (or, unless ``allow_inf``, an infinite one).

    The constants are read from the instructions of a Function of ``sx`` (CasADi keeps every
    constant of an expression graph as one ``OP_CONST`` instruction): exact, and 0.3 ms for the
    RexROV's dynamics.
    """
    function = ca.Function("constants", ca.symvar(sx), [sx])
    for k in range(function.n_instructions()):
        if function.instruction_id(k) != ca.OP_CONST:
            continue
        value = function.instruction_constant(k)
        if math.isnan(value) or (not allow_inf and math.isinf(value)):
            expected = "no NaN" if allow_inf else "finite numbers (no NaN or inf)"
            raise ValueError(f"{what} must hold {expected}, got the constant {value} in {_short(sx)}")


def _short(value: object) -> str:
    """``value`` printed, cut to 120 characters for an error message."""
    text = " ".join(str(value).split())
    return text if len(text) <= 120 else text[:117] + "..."


def _bound_vector(name: str, value: object, size: int) -> np.ndarray:
    array = np.asarray(value, dtype=float).ravel() if not isinstance(value, (str, bytes)) else None
    if array is None or array.size not in (1, size) or np.any(np.isnan(array)):
        raise ValueError(f"{name} must be a number or {size} numbers (inf allowed), got {value!r}")
    return np.broadcast_to(array, (size,)).astype(float).copy()
