"""The tracking optimal-control problem: one formulation for every solver.

:class:`TrackingProblem` is a plain description (vehicle, reference, horizon, weights, terminal
mode).  :meth:`TrackingProblem.build` turns it, once, into CasADi objects that every backend
shares:

* a **multiple-shooting NLP** in stage-wise order (for fatrop's structure detection), in a hard
  and, for ``terminal="equality"``, an exact-penalty soft variant;
* a **condensed cost** ``J(U; p)`` obtained by rolling out the *same* RK4 Function, used by the
  derivative-free solvers and by :func:`score`, the one judge of every solver.

Formulation (DESIGN §4).  Stage ``k`` carries the lifted state ``[x_k, z_{k-1}]`` (the previous
scaled control, so rate bounds are stage-local) and the scaled control ``z_k = τ_k / τ_max`` in
``[-1, 1]³``.  The objective is

    Σ_{k=0}^{N-1} ‖z_k − z_{k−1}‖²_S + Σ_{k=1}^{N-1} ℓ(x_k, x_R,k) + V_N(x_N)
      + ρ_tube Σ_k 1ᵀ s_k

with ``ℓ = q_x e_x² + q_y e_y² + q_ψ · 2(1 − cos(ψ − ψ_R)) + ‖ν − ν_R‖²_R`` (wrap-safe heading
error), ``V_N = ℓ`` for ``terminal="none"``, a weighted ``‖x_N − x_R,N‖²`` for ``"cost"`` and
``0`` with the hard constraint ``x_N = x_R,N`` for ``"equality"`` (the paper).  Hard bounds:
``|z_k| ≤ 1``, ``|z_k − z_{k−1}| ≤ τ̇_max dt / τ_max`` (``z_{−1}`` from the last applied control).
The optional position tube ``|e_x|, |e_y| ≤ tube + s_k`` on nodes 1..N−1 is an exact L1 penalty.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.integrators import rk4_step
from uuv_ocp.reference.path import UNWRAP_STEP, Reference
from uuv_ocp.model.planar import CONTROL_DIM, CURRENT_DIM, STATE_DIM, Vehicle

TERMINAL_MODES = ("equality", "cost", "none")
LIFTED_DIM = STATE_DIM + CONTROL_DIM
SAMPLE_BLOCK = 64  # sampling intervals per cached block of reference samples


@dataclass(frozen=True)
class Weights:
    """Cost weights of the tracking problem.

    Parameters
    ----------
    pose : tuple of 3 floats
        (q_x, q_y, q_ψ) on position errors (1/m²) and on the wrap-safe heading error
        ``2(1 − cos(ψ − ψ_R))`` (1/rad²).
    velocity : tuple of 3 floats
        Weights on surge, sway (s²/m²) and yaw-rate (s²/rad²) errors.
    rate : tuple of 3 floats
        Weights on the scaled control increments ``Δτ / τ_max`` (dimensionless).
    terminal : tuple of 6 floats
        Terminal weights on ``x_N − x_R,N`` for ``terminal="cost"``.
    terminal_penalty : float
        Exact L1 penalty weight ρ on terminal residuals (m, rad, m/s, rad/s) in the soft
        fallback of ``terminal="equality"`` and in the derivative-free solvers' cost.  Exact
        (same minimiser as the hard problem) whenever ρ exceeds the largest terminal multiplier.
    rate_penalty : float
        Penalty weight on the scaled rate-bound excess, used by derivative-free solvers only.
    tube_penalty : float
        L1 weight on position-tube slacks (1/m).
    """

    pose: tuple[float, float, float] = (1e4, 1e4, 1e3)
    velocity: tuple[float, float, float] = (10.0, 10.0, 10.0)
    rate: tuple[float, float, float] = (0.1, 0.1, 0.1)
    terminal: tuple[float, ...] = (1e4, 1e4, 1e3, 100.0, 100.0, 100.0)
    terminal_penalty: float = 1e4
    rate_penalty: float = 1e4
    tube_penalty: float = 1e3

    def __post_init__(self) -> None:
        set_field = object.__setattr__
        set_field(self, "pose", check.vector("weights.pose", self.pose, 3, nonnegative=True))
        set_field(self, "velocity", check.vector("weights.velocity", self.velocity, 3, nonnegative=True))
        set_field(self, "rate", check.vector("weights.rate", self.rate, 3, nonnegative=True))
        set_field(self, "terminal", check.vector("weights.terminal", self.terminal, 6, nonnegative=True))
        for name in ("terminal_penalty", "rate_penalty", "tube_penalty"):
            set_field(self, name, check.positive_float(f"weights.{name}", getattr(self, name)))


@dataclass(frozen=True)
class NlpData:
    """A multiple-shooting NLP ready for ``casadi.nlpsol``.

    ``f = ‖residual‖² + (linear slack penalties)``.  ``variable_labels`` and
    ``constraint_labels`` name every entry so that iterates can be mapped between the hard and
    soft variants.
    """

    nlp: dict[str, ca.SX]
    residual: ca.SX
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    equality: list[bool]
    variable_labels: tuple[str, ...]
    constraint_labels: tuple[str, ...]
    state_index: np.ndarray
    control_index: np.ndarray
    terminal_slack_index: np.ndarray


@dataclass
class _Built:
    step: ca.Function
    hard: NlpData
    soft: NlpData | None
    cost: ca.Function
    rollout: ca.Function
    score_terms: ca.Function


@dataclass(frozen=True)
class TrackingProblem:
    """NMPC trajectory-tracking problem of a 3-DOF vehicle (paper §3.2, DESIGN §4).

    Parameters
    ----------
    vehicle : Vehicle
        The controller's model of the vehicle.
    reference : Reference
        Path to track.
    horizon : int
        Number of shooting intervals N, >= 1.
    dt : float
        Sampling time (s), > 0.
    terminal : {"equality", "cost", "none"}
        Terminal condition: hard ``x_N = x_R,N`` (paper, with an exact-penalty fallback when
        infeasible), a weighted terminal cost, or nothing.
    weights : Weights
        Cost weights.
    substeps : int
        RK4 steps per interval in the prediction model, >= 1.
    rate_limits : bool
        Enforce ``|Δτ| ≤ τ̇_max dt``.
    position_tube : float or None
        Half-width (m) of a soft tube on the position error of nodes 1..N−1, or ``None``.
    """

    vehicle: Vehicle
    reference: Reference
    horizon: int = 20
    dt: float = 0.1
    terminal: str = "equality"
    weights: Weights = Weights()
    substeps: int = 1
    rate_limits: bool = True
    position_tube: float | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        if not isinstance(self.vehicle, Vehicle):
            raise ValueError(f"vehicle must be a uuv_ocp.Vehicle, got {type(self.vehicle).__name__}")
        if not isinstance(self.reference, Reference):
            raise ValueError(f"reference must be a uuv_ocp.Reference, got {type(self.reference).__name__}")
        object.__setattr__(self, "horizon", check.positive_int("horizon", self.horizon))
        object.__setattr__(self, "dt", check.positive_float("dt", self.dt))
        check.choice("terminal", self.terminal, TERMINAL_MODES)
        if not isinstance(self.weights, Weights):
            raise ValueError(f"weights must be a uuv_ocp.Weights, got {self.weights!r}")
        object.__setattr__(self, "substeps", check.positive_int("substeps", self.substeps))
        check.boolean("rate_limits", self.rate_limits)
        if self.position_tube is not None:
            tube = check.positive_float("position_tube", self.position_tube)
            object.__setattr__(self, "position_tube", tube)
        if self.reference.t_end - self.reference.t_start < self.horizon * self.dt:
            raise ValueError(
                f"horizon * dt = {self.horizon * self.dt} s exceeds the reference window "
                f"[{self.reference.t_start}, {self.reference.t_end}] s"
            )

    # ------------------------------------------------------------- dimensions
    @property
    def control_dim(self) -> int:
        """Number of decision controls of the condensed problem, ``3 N``."""
        return CONTROL_DIM * self.horizon

    @property
    def parameter_dim(self) -> int:
        """Length of the parameter vector ``p``."""
        return STATE_DIM + STATE_DIM * (self.horizon + 1) + CONTROL_DIM + CURRENT_DIM * self.horizon

    @property
    def max_thrust(self) -> np.ndarray:
        """Control bounds (N, N, N·m)."""
        return np.asarray(self.vehicle.max_thrust)

    @property
    def rate_step_bound(self) -> np.ndarray:
        """Largest scaled control change per interval, ``τ̇_max dt / τ_max``."""
        return np.asarray(self.vehicle.max_thrust_rate) * self.dt / self.max_thrust

    @property
    def soft_terminal_available(self) -> bool:
        """Whether the exact-penalty fallback exists (``terminal="equality"``)."""
        return self.terminal == "equality"

    def latest_start(self) -> float:
        """Latest start time t0 (s) whose horizon stays inside the reference window."""
        return self.reference.t_end - self.horizon * self.dt

    def replace(self, **changes: Any) -> TrackingProblem:
        """A copy with some fields changed (a new, unbuilt problem)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------- parameters
    def check_state(self, x0: object, name: str = "x0") -> np.ndarray:
        """Validate a state vector: shape (6,), finite."""
        return check.finite_array(name, x0, (STATE_DIM,))

    def check_time(self, t0: object) -> float:
        """Validate a start time: finite and inside ``[t_start, latest_start()]``."""
        t0 = check.finite_float("t0", t0)
        if t0 < self.reference.t_start - 1e-12 or t0 > self.latest_start() + 1e-9:
            raise ValueError(
                f"t0 must lie in [{self.reference.t_start}, {self.latest_start()}] s so that the "
                f"horizon stays inside the reference window, got {t0}"
            )
        return t0

    def reference_window(self, t0: float, heading: float | None = None) -> np.ndarray:
        """Reference states at ``t0 + k dt``, k = 0..N, shape (N+1, 6).

        The heading is shifted by a multiple of 2π so that its first value is the one closest
        to ``heading`` (the vehicle's), which keeps the terminal equality wrap-safe.

        When ``t0`` is a sampling instant ``i dt`` (a closed loop started at a multiple of
        ``dt``), the window is cut from blocks of reference samples at ``(i + k) dt``
        evaluated once per problem; otherwise, or if a block cannot be evaluated, the
        reference is evaluated at ``t0 + k dt``.  The two agree to floating-point rounding
        (the sample times differ by an ulp, the heading branch is chosen the same way).
        """
        window = self._window_from_samples(t0)
        if window is None:
            times = np.minimum(t0 + self.dt * np.arange(self.horizon + 1), self.reference.t_end)
            if self.dt <= UNWRAP_STEP and times[-1] > times[-2]:
                window = self.reference.evaluate_grid(times)
            else:
                window = self.reference.evaluate(times)
        if heading is None:  # the first heading in [-π, π], as the reference gives it
            heading = math.remainder(window[0, 2], 2.0 * math.pi)
        _move_heading_branch(window, heading)
        return window

    def _window_from_samples(self, t0: float) -> np.ndarray | None:
        """The window at ``t0 = i dt`` from cached sample blocks, or ``None`` (see above)."""
        dt, horizon, reference = self.dt, self.horizon, self.reference
        if not math.isfinite(t0):
            return None
        first = round(t0 / dt)
        last = first + horizon
        if first * dt != t0 or dt > UNWRAP_STEP or last * dt > reference.t_end:
            return None
        parts: list[np.ndarray] = []
        for block in range(first // SAMPLE_BLOCK, last // SAMPLE_BLOCK + 1):
            samples = self._sample_block(block)
            if samples is None:
                return None
            start_index, states = samples
            lo, hi = max(first, start_index), min(last, start_index + states.shape[0] - 1)
            if lo > hi:
                return None  # the reference starts after t0
            part = states[lo - start_index : hi - start_index + 1].copy()
            if parts:
                # neighbouring blocks share their boundary sample: drop it, and move this
                # block's heading to the branch of the previous one
                _move_heading_branch(part, parts[-1][-1, 2])
                part = part[1:]
            parts.append(part)
        window = parts[0] if len(parts) == 1 else np.concatenate(parts)
        return window if window.shape[0] == horizon + 1 else None

    def _sample_block(self, block: int) -> tuple[int, np.ndarray] | None:
        """Reference samples at ``i dt`` for ``i`` in block ``block`` (its first index, states)."""
        blocks = self._cache.setdefault("sample_blocks", {})
        if block not in blocks:
            dt, reference = self.dt, self.reference
            indices = block * SAMPLE_BLOCK + np.arange(SAMPLE_BLOCK + 1)
            times = indices * dt
            inside = (times >= reference.t_start) & (times <= reference.t_end)
            try:
                blocks[block] = (int(indices[inside][0]), reference.evaluate_grid(times[inside]))
            except (IndexError, ValueError):  # empty, or the speed vanishes inside the block
                blocks[block] = None
        return blocks[block]

    def parameters(
        self,
        x0: object,
        t0: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
    ) -> np.ndarray:
        """Parameter vector ``p = [x0, reference window, last control, current over horizon]``.

        Parameters
        ----------
        x0 : array_like, shape (6,)
            Current state (m, m, rad, m/s, m/s, rad/s).
        t0 : float
            Current time (s); the reference is sampled at ``t0 + k dt``.
        u_prev : array_like, shape (3,), optional
            Last applied control (N, N, N·m); defaults to zero.
        current : array_like, shape (2,) or (N, 2), optional
            Inertial current velocity (m/s) the model assumes on each interval.
        """
        x0 = self.check_state(x0)
        t0 = self.check_time(t0)
        if u_prev is None:
            u_prev = np.zeros(CONTROL_DIM)
        u_prev = check.finite_array("u_prev", u_prev, (CONTROL_DIM,))
        if current is None:
            current = np.zeros((self.horizon, CURRENT_DIM))
        current = np.asarray(current, dtype=float)
        if current.shape == (CURRENT_DIM,):
            current = np.tile(current, (self.horizon, 1))
        current = check.finite_array("current", current, (self.horizon, CURRENT_DIM))
        window = self.reference_window(t0, heading=x0[2])
        return np.concatenate([x0, window.ravel(), u_prev, current.ravel()])

    def _parameter_slices(self) -> tuple[slice, slice, slice, slice]:
        """Where x0, the reference window, u_prev and the current sit in ``p``."""
        n = self.horizon
        offsets = np.cumsum([0, STATE_DIM, STATE_DIM * (n + 1), CONTROL_DIM, CURRENT_DIM * n]).tolist()
        return tuple(slice(start, stop) for start, stop in zip(offsets[:-1], offsets[1:], strict=True))

    @property
    def current_slice(self) -> slice:
        """Where the current over the horizon, ``(N, 2)`` row by row (m/s), sits in ``p``."""
        return self._parameter_slices()[3]

    def parameter_parts(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Numeric ``p`` -> (x0 (6,), reference (N+1, 6), u_prev (3,), current (N, 2))."""
        n = self.horizon
        x0, reference, u_prev, current = self._parameter_slices()
        return (
            p[x0],
            p[reference].reshape(n + 1, STATE_DIM),
            p[u_prev],
            p[current].reshape(n, CURRENT_DIM),
        )

    def split_parameters(self, p: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
        """Symbolic ``p`` -> (x0 (6,), reference (6, N+1), u_prev (3,), current (2, N))."""
        n = self.horizon
        x0, reference, u_prev, current = self._parameter_slices()
        return (
            p[x0],
            ca.reshape(p[reference], STATE_DIM, n + 1),
            p[u_prev],
            ca.reshape(p[current], CURRENT_DIM, n),
        )

    # ------------------------------------------------------------------ build
    def build(self) -> _Built:
        """Build (once) and return the CasADi objects shared by all solvers."""
        if "built" not in self._cache:
            self._cache["built"] = _build(self)
        return self._cache["built"]

    # -------------------------------------------------------------- helpers
    def controls_from_scaled(self, scaled: np.ndarray) -> np.ndarray:
        """Scaled controls ``(3N,)`` or ``(N, 3)`` -> physical ``(N, 3)`` (N, N, N·m)."""
        return np.reshape(scaled, (self.horizon, CONTROL_DIM)) * self.max_thrust

    def scaled_from_controls(self, controls: object) -> np.ndarray:
        """Physical controls ``(N, 3)`` -> flat scaled vector ``(3N,)``."""
        controls = check.finite_array("controls", controls, (self.horizon, CONTROL_DIM))
        return (controls / self.max_thrust).ravel()

    def rollout(self, controls: object, p: np.ndarray) -> np.ndarray:
        """States ``(N+1, 6)`` from the prediction model under physical ``controls`` (N, 3)."""
        return self.rollout_scaled(self.scaled_from_controls(controls), p)

    def rollout_scaled(
        self, scaled: np.ndarray, p: np.ndarray, rollout: BufferedFunction | None = None
    ) -> np.ndarray:
        """States ``(N+1, 6)`` under flat scaled controls ``(3N,)`` (no validation: hot path).

        ``rollout`` is a caller of an equal Function (e.g. the compiled one); default: the
        built one on CasADi's virtual machine.
        """
        (states,) = (rollout or self.buffered("rollout"))(scaled, p)
        return states.reshape(self.horizon + 1, STATE_DIM)

    def buffered(self, name: str) -> BufferedFunction:
        """Zero-copy caller of the built Function ``name`` (``"rollout"``, ``"score_terms"``, …)."""
        callers = self._cache.setdefault("buffered", {})
        if name not in callers:
            callers[name] = BufferedFunction(getattr(self.build(), name))
        return callers[name]


def _move_heading_branch(states: np.ndarray, heading: float) -> None:
    """Shift the heading column of ``states`` by the multiple of 2π that brings its first value
    closest to ``heading`` (in place)."""
    turns = np.round((heading - states[0, 2]) / (2.0 * math.pi))
    states[:, 2] += 2.0 * math.pi * turns


# ============================================================================ building
def _build(problem: TrackingProblem) -> _Built:
    vehicle = problem.vehicle
    step = rk4_step(vehicle.dynamics_function(), problem.dt, problem.substeps, name="model_step")
    pieces = _CostPieces(problem)
    hard = _build_nlp(problem, step, pieces, soft=False)
    soft = _build_nlp(problem, step, pieces, soft=True) if problem.soft_terminal_available else None
    cost, rollout, score_terms = _build_condensed(problem, step, pieces)
    return _Built(step=step, hard=hard, soft=soft, cost=cost, rollout=rollout, score_terms=score_terms)


class _CostPieces:
    """Symbolic stage functions shared by the NLP and the condensed cost.

    Every quadratic term is written as a weighted residual ``r`` with cost ``‖r‖²``: the
    heading term uses ``2(1 − cos e) = (2 sin(e/2))²``, so the sqp backend can form an exact
    Gauss–Newton Hessian ``2 JᵣᵀJᵣ`` that is positive semidefinite by construction.
    """

    def __init__(self, problem: TrackingProblem) -> None:
        weights = problem.weights
        state = ca.SX.sym("x", STATE_DIM)
        ref = ca.SX.sym("x_ref", STATE_DIM)
        scaled = ca.SX.sym("z", CONTROL_DIM)
        scaled_prev = ca.SX.sym("z_prev", CONTROL_DIM)
        error = state - ref
        wrapped_error = ca.vertcat(error[0], error[1], 2.0 * ca.sin(error[2] / 2.0), error[3:])

        def weighted(name: str, values: tuple[float, ...]) -> ca.Function:
            residual = ca.sqrt(ca.DM(values)) * wrapped_error
            return ca.Function(name, [state, ref], [residual])

        self.node_residual = weighted("node_residual", (*weights.pose, *weights.velocity))
        self.terminal_residual = weighted("terminal_residual", weights.terminal)
        rate_residual = ca.sqrt(ca.DM(weights.rate)) * (scaled - scaled_prev)
        self.rate_residual = ca.Function("rate_residual", [scaled, scaled_prev], [rate_residual])
        self.node = ca.Function("node_cost", [state, ref], [ca.sumsqr(self.node_residual(state, ref))])
        self.rate = ca.Function("rate_cost", [scaled, scaled_prev], [ca.sumsqr(rate_residual)])
        self.position_error = ca.Function("position_error", [state, ref], [error[:2]])

    def final_residual(self, problem: TrackingProblem, state: ca.SX, ref: ca.SX) -> ca.SX:
        """Residual of the terminal node for the problem's terminal mode (empty for equality)."""
        if problem.terminal == "none":
            return self.node_residual(state, ref)
        if problem.terminal == "cost":
            return self.terminal_residual(state, ref)
        return ca.SX(0, 1)

    def final_node(self, problem: TrackingProblem, state: ca.SX, ref: ca.SX) -> ca.SX:
        """Terminal cost ``‖final_residual‖²``."""
        return ca.sumsqr(self.final_residual(problem, state, ref))


def _build_nlp(problem: TrackingProblem, step: ca.Function, pieces: _CostPieces, soft: bool) -> NlpData:
    n = problem.horizon
    max_thrust = ca.DM(problem.max_thrust)
    p = ca.SX.sym("p", problem.parameter_dim)
    x0, reference, u_prev, current = problem.split_parameters(p)
    tube = problem.position_tube
    weights = problem.weights
    terminal_slack = None

    variables: list[tuple[str, ca.SX, float, float]] = []
    constraints: list[tuple[str, ca.SX, float | np.ndarray, float | np.ndarray, bool]] = []

    def add_variables(label: str, size: int, lower: float, upper: float) -> ca.SX:
        symbol = ca.SX.sym(label, size)
        for i in range(size):
            variables.append((f"{label}[{i}]", symbol[i], lower, upper))
        return symbol

    def add_constraint(label: str, expression: ca.SX, lower: float, upper: float, equality: bool) -> None:
        for i in range(expression.numel()):
            constraints.append((f"{label}[{i}]", expression[i], lower, upper, equality))

    # Fatrop's structure detection wants, per stage k: the gap-closing constraint
    # X_{k+1} - F(X_k, z_k) first, then the path constraints of stage k.
    residuals: list[ca.SX] = []
    objective = ca.SX(0)  # linear (slack) part; the quadratic part is ‖residuals‖²
    lifted = add_variables("X_0", LIFTED_DIM, -np.inf, np.inf)
    for k in range(n):
        state, scaled_prev = lifted[:STATE_DIM], lifted[STATE_DIM:]
        scaled = add_variables(f"z_{k}", CONTROL_DIM, -1.0, 1.0)
        path: list[tuple[str, ca.SX, object, object, bool]] = []
        if k == 0:
            path.append(("initial", lifted - ca.vertcat(x0, u_prev / max_thrust), 0.0, 0.0, True))
        residuals.append(pieces.rate_residual(scaled, scaled_prev))
        if k > 0:
            residuals.append(pieces.node_residual(state, reference[:, k]))
        if problem.rate_limits:
            bound = problem.rate_step_bound
            increment = scaled - scaled_prev
            for i in range(CONTROL_DIM):
                path.append((f"rate_{k}_{i}", increment[i], -bound[i], bound[i], False))
        if tube is not None:
            slack = add_variables(f"tube_{k}", 2, 0.0, np.inf)
            error = pieces.position_error(state, reference[:, k])
            path.append((f"tube_upper_{k}", error - slack, -np.inf, tube, False))
            path.append((f"tube_lower_{k}", error + slack, -tube, np.inf, False))
            # node 0 is fixed by x0: its slack costs nothing and stays at its optimum
            objective += (weights.tube_penalty if k > 0 else 0.0) * ca.sum1(slack)
        next_state = step(state, scaled * max_thrust, current[:, k])
        if soft and k == n - 1:
            terminal_slack = add_variables("terminal_slack", STATE_DIM, 0.0, np.inf)
            residual = next_state - reference[:, n]
            path.append(("terminal_upper", residual - terminal_slack, -np.inf, 0.0, False))
            path.append(("terminal_lower", residual + terminal_slack, 0.0, np.inf, False))
            objective += weights.terminal_penalty * ca.sum1(terminal_slack)
        following = add_variables(f"X_{k + 1}", LIFTED_DIM, -np.inf, np.inf)
        add_constraint(f"dynamics_{k}", following - ca.vertcat(next_state, scaled), 0.0, 0.0, True)
        for entry in path:
            add_constraint(*entry)
        lifted = following
    final_state = lifted[:STATE_DIM]
    residuals.append(pieces.final_residual(problem, final_state, reference[:, n]))
    residual = ca.vertcat(*residuals)
    objective = ca.sumsqr(residual) + objective
    if problem.terminal == "equality" and not soft:
        add_constraint("terminal", final_state - reference[:, n], 0.0, 0.0, True)

    w = ca.vertcat(*[entry[1] for entry in variables])
    g = ca.vertcat(*[entry[1] for entry in constraints])
    labels = tuple(entry[0] for entry in variables)
    index = {label: i for i, label in enumerate(labels)}
    state_index = np.array(
        [[index[f"X_{k}[{i}]"] for i in range(STATE_DIM)] for k in range(n + 1)], dtype=int
    )
    control_index = np.array(
        [[index[f"z_{k}[{i}]"] for i in range(CONTROL_DIM)] for k in range(n)], dtype=int
    )
    slack_index = (
        np.array([index[f"terminal_slack[{i}]"] for i in range(STATE_DIM)], dtype=int)
        if terminal_slack is not None
        else np.zeros(0, dtype=int)
    )
    return NlpData(
        nlp={"x": w, "p": p, "f": objective, "g": g},
        residual=residual,
        lbx=np.array([entry[2] for entry in variables], dtype=float),
        ubx=np.array([entry[3] for entry in variables], dtype=float),
        lbg=np.array([entry[2] for entry in constraints], dtype=float),
        ubg=np.array([entry[3] for entry in constraints], dtype=float),
        equality=[bool(entry[4]) for entry in constraints],
        variable_labels=labels,
        constraint_labels=tuple(entry[0] for entry in constraints),
        state_index=state_index,
        control_index=control_index,
        terminal_slack_index=slack_index,
    )


def _build_condensed(
    problem: TrackingProblem, step: ca.Function, pieces: _CostPieces
) -> tuple[ca.Function, ca.Function, ca.Function]:
    """Rollout-based cost ``J(U; p)``, penalty, and the raw terms :func:`score` reports."""
    n = problem.horizon
    weights = problem.weights
    max_thrust = ca.DM(problem.max_thrust)
    scaled_all = ca.SX.sym("U", CONTROL_DIM * n)
    p = ca.SX.sym("p", problem.parameter_dim)
    x0, reference, u_prev, current = problem.split_parameters(p)
    scaled = ca.reshape(scaled_all, CONTROL_DIM, n)
    states = [x0]
    objective = ca.SX(0)
    rate_excess = []
    scaled_prev = u_prev / max_thrust
    bound = ca.DM(problem.rate_step_bound)
    tube_excess = ca.SX(0)
    for k in range(n):
        state = states[-1]
        objective += pieces.rate(scaled[:, k], scaled_prev)
        if k > 0:
            objective += pieces.node(state, reference[:, k])
            if problem.position_tube is not None:
                error = pieces.position_error(state, reference[:, k])
                excess = ca.fmax(0, ca.fabs(error) - problem.position_tube)
                tube_excess += ca.sum1(excess)
        if problem.rate_limits:
            rate_excess.append(ca.fmax(0, ca.fabs(scaled[:, k] - scaled_prev) - bound))
        states.append(step(state, scaled[:, k] * max_thrust, current[:, k]))
        scaled_prev = scaled[:, k]
    objective += weights.tube_penalty * tube_excess
    objective += pieces.final_node(problem, states[-1], reference[:, n])
    if problem.terminal == "equality":
        terminal_residual = states[-1] - reference[:, n]
    else:
        terminal_residual = ca.SX.zeros(STATE_DIM)
    rate_excess_vector = ca.vertcat(*rate_excess) if rate_excess else ca.SX.zeros(1)
    bound_excess = ca.fmax(0, ca.fabs(scaled_all) - 1)
    penalty = weights.terminal_penalty * ca.sum1(ca.fabs(terminal_residual)) + weights.rate_penalty * ca.sum1(
        rate_excess_vector
    )
    cost = ca.Function("cost", [scaled_all, p], [objective, penalty], ["U", "p"], ["objective", "penalty"])
    rollout = ca.Function("rollout", [scaled_all, p], [ca.horzcat(*states)], ["U", "p"], ["X"])
    score_terms = ca.Function(
        "score_terms",
        [scaled_all, p],
        [objective, terminal_residual, rate_excess_vector, bound_excess],
        ["U", "p"],
        ["objective", "terminal_residual", "rate_excess", "bound_excess"],
    )
    return cost, rollout, score_terms


# ============================================================================ judge
def score(
    problem: TrackingProblem,
    controls: object,
    x0: object,
    t0: float = 0.0,
    *,
    u_prev: object | None = None,
    current: object | None = None,
) -> tuple[float, float]:
    """Exact objective and largest constraint violation of a control sequence: the one judge.

    Parameters
    ----------
    problem : TrackingProblem
    controls : array_like, shape (N, 3)
        Physical controls (N, N, N·m).
    x0, t0, u_prev, current
        As in :meth:`TrackingProblem.parameters`.

    Returns
    -------
    cost : float
        The NLP objective at the rollout of ``controls`` through the prediction model.
    max_violation : float
        Largest violation among: terminal equality residual (m, rad, m/s, rad/s; equality mode
        only), thrust-bound and rate-bound excess (as fractions of ``max_thrust``).
    """
    p = problem.parameters(x0, t0, u_prev, current)
    return score_parameters(problem, problem.scaled_from_controls(controls), p)


def score_parameters(
    problem: TrackingProblem,
    scaled: np.ndarray,
    p: np.ndarray,
    terms: BufferedFunction | None = None,
) -> tuple[float, float]:
    """:func:`score` on a flat scaled control vector and a ready parameter vector.

    ``terms`` is a caller of a Function equal to the built ``score_terms`` (e.g. its compiled,
    verified twin); default: the built one on CasADi's virtual machine.
    """
    objective, terminal, rate, bound = (terms or problem.buffered("score_terms"))(scaled, p)
    violation = max(float(np.max(np.abs(terminal))), float(np.max(rate)), float(np.max(bound)))
    return float(objective[0]), violation
