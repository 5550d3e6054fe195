"""Real-time iteration (``"sqp-rti"``): one Gauss–Newton SQP step per sampling instant.

The NLP is the multiple-shooting NLP every exact backend solves (:mod:`uuv_ocp.solvers.nlp`),
with the same variants (hard terminal equality, its exact-penalty relaxation) and the same
terminal strategy (``"sticky"`` by default).  An iteration linearises it at the current
primal point ``w`` and solves the structured QP

    min_d  ½ dᵀ H d + ∇f(w)ᵀ d
    s.t.   lbg − g(w) ≤ ∇g(w)ᵀ d ≤ ubg − g(w),   lbx − w ≤ d ≤ ubx − w

with the Gauss–Newton Hessian ``H = 2 s JᵣᵀJᵣ`` (plus the exact Hessian of the non-least-squares
cost terms, as :meth:`NlpSolver.gauss_newton_hessian`), then takes the full step ``w + d``.  The
QP multipliers are the new NLP multipliers.  The QP holds the control box, the rate bounds and
every constraint of the problem *linearised* as hard constraints; the nonlinear dynamics and
terminal residuals of one iteration are what the Gauss–Newton step leaves (quadratically small
near the solution).

Phases (acados' split): :meth:`RtiSolver.prepare` linearises at the shifted previous iterate
with every parameter of the next instance but the measured state; :meth:`RtiSolver.feedback`
puts the measured state into the initial-state rows (the only place ``x0`` enters the NLP, and
it enters linearly, so the prepared QP is exact) and solves the QP.

Modes (options):

``mode="rti"`` (default)
    ``iterations`` (default 1) Gauss–Newton steps per call from the warm start.  A call without
    a warm start (first step from rest, after :meth:`NMPC.reset`, the cold retry of a failed
    step) is far from the optimum, and full Gauss–Newton steps without globalisation cycle
    there (measured on s2 from rest: 50 iterations without convergence).  ``cold_start``:
    ``"ipopt"`` (default) solves that call with IPOPT on the same NLP variant (globalised,
    duals included, so the next RTI steps start at a KKT point); ``"converged"`` iterates
    Gauss–Newton to ``tol``; ``"rti"`` takes ``iterations`` steps there too.  IPOPT is also
    the last resort after a failed RTI attempt (``robust_options``), as in the other backends'
    fallback chain.
``mode="converged"``
    Iterate until the step ``‖d‖∞ ≤ tol`` (default 1e-8, scaled variables) or ``max_iter``
    (default 50) steps: the full Gauss–Newton SQP (no globalisation), converging to the
    optimum of the NLP where Gauss–Newton converges.

``deadline`` (seconds): no further iteration starts once it has passed (the first always runs),
so ``iterations=k`` with a deadline is "extra iterations up to the deadline"; a call that
outlasted it reports ``success=False`` like every exact backend.

Success: the QP solution is finite and satisfies the linearised constraints and bounds within
``qp_tolerance`` (default 1e-6, in the NLP's units: scaled controls, the problem's constraint
units); in ``mode="converged"`` the iteration must also have converged.  A failed hard QP (an
unreachable terminal equality) falls back to the soft NLP exactly as in :class:`NlpSolver`.

QP solvers (``qpsol``): ``"hpipm"`` (default; CasADi's HPIPM interface with the stage structure
detected from the variable and constraint order), ``"qrqp"`` and ``"osqp"`` (measured slower
and, for qrqp, wrong on this QP: see docs/solvers.md).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.solvers.base import reraise_interrupt
from uuv_ocp.solvers.nlp import NLP_OPTIONS, NlpSolver
from uuv_ocp.solvers.options import AUTO, Option, one_of, option_defaults, option_names, revise
from uuv_ocp.solvers.result import Iterate, SolveResult
from uuv_ocp.solvers.rti_ocp import (
    STOP_CONVERGED,
    STOP_DEADLINE,
    STOP_EVALUATION,
    STOP_INFEASIBLE,
    OcpQpStep,
    ocp_qp_options,
)
from uuv_ocp.transcription.multiple_shooting import NlpData

QP_SOLVERS = ("hpipm", "hpipm-ocp", "qrqp", "osqp")
MODES = ("rti", "converged")
#: HPIPM's residual tolerances in ``mode="converged"`` (its defaults, kept in ``mode="rti"``, are
#: 1e-6 / 1e-8): with weights ~1e4 a 1e-6 stationarity residual moved the converged Gauss–Newton
#: point by 1.4e-6 in the scaled controls from IPOPT's optimum (tol 1e-12, no bound relaxation);
#: with 1e-10 they agree to 3e-11.  Not the RTI default: from a cold guess HPIPM cannot reach
#: 1e-10 on the soft QP and runs its 100 iterations (14 with its defaults).
HPIPM_DEFAULTS: dict[str, Any] = {
    "hpipm": {"res_g_max": 1e-10, "res_b_max": 1e-10, "res_d_max": 1e-10, "res_m_max": 1e-10}
}
COLD_STARTS = ("ipopt", "converged", "rti")
#: Iteration limit of the converged mode and of a cold start by Gauss–Newton steps.
RTI_MAX_ITER = 50

RTI_OPTIONS: tuple[Option, ...] = (
    *revise(
        NLP_OPTIONS,
        max_iter={"meaning": f"{RTI_MAX_ITER} (converged mode and cold starts by SQP steps)"},
        plugin_options={
            "description": "must stay empty (no nlpsol plugin): the QP's options are `qpsol_options`"
        },
    ),
    Option("mode", "rti", one_of(MODES), "one Gauss–Newton SQP step per call, or iterate to `tol`"),
    Option("iterations", 1, "int >= 1", "SQP steps per call in `rti` mode"),
    Option("tol", 1e-8, "float > 0", "step-size tolerance of the converged mode (scaled variables)"),
    Option("cold_start", "ipopt", one_of(COLD_STARTS), "how a call without a warm start is solved"),
    Option(
        "qpsol",
        "hpipm",
        one_of(QP_SOLVERS),
        "QP solver: a CasADi `conic` plugin on the full-space QP, or `hpipm-ocp`: the whole step "
        "in C on HPIPM's OCP-QP API (no compiler: `hpipm`, one warning)",
    ),
    Option(
        "qpsol_options",
        AUTO,
        "dict",
        "options of the QP solver (`hpipm-ocp`: `mode`, `iter_max`, `tol_stat`, `tol_eq`, "
        "`tol_ineq`, `tol_comp`, `warm_start`)",
        meaning="`HPIPM_DEFAULTS` (residuals 1e-10) for hpipm in converged mode, else `{}`",
    ),
    Option(
        "qp_tolerance",
        1e-6,
        "float > 0",
        "largest violation of the linearised constraints a QP solution may have to count as solved",
    ),
)


@dataclass(frozen=True)
class Preparation:
    """What :meth:`RtiSolver.prepare` computed before the state was measured.

    Parameters
    ----------
    variant : str
        NLP variant the first QP belongs to (``"hard"``, ``"soft"``, …).
    p : numpy.ndarray
        Parameter vector of the instance with the guessed state.
    primal : numpy.ndarray
        Linearisation point (the shifted warm start).
    qp : tuple of numpy.ndarray
        Nonzeros of ``H``, ``∇f``, nonzeros of ``∇gᵀ``, ``g`` at ``primal``.
    still_water : bool
        Whether the still-water NLP was linearised.
    time : float
        Wall time of the preparation (s).
    """

    variant: str
    p: np.ndarray
    primal: np.ndarray
    qp: tuple[np.ndarray, ...]
    still_water: bool
    time: float


def qp_functions(
    data: NlpData, still_water_slice: slice | None, objective_scale: float, name: str
) -> tuple[ca.Function, ca.Sparsity, ca.Sparsity]:
    """``linearise(w, p) -> (H_nz, grad, A_nz, g)`` of an NLP variant, and the sparsities of H, A.

    ``H`` is the Gauss–Newton Hessian of ``objective_scale · f`` (upper and lower part), ``A``
    the constraint Jacobian.  With ``still_water_slice`` the current parameters are set to zero
    *after* differentiation, so the still-water Function has the same nonzero layout as the
    general one (CasADi simplifies the vanished terms inside the entries).
    """
    nlp = data.nlp
    w, p = nlp["x"], nlp["p"]
    jacobian = ca.jacobian(data.residual, w)
    hessian = (2.0 * objective_scale) * ca.mtimes(jacobian.T, jacobian)
    other_hessian, _ = ca.hessian(data.other_objective, w)
    if other_hessian.nnz():  # expression costs (not least squares) keep their exact curvature
        hessian += objective_scale * other_hessian
    constraint_jacobian = ca.jacobian(nlp["g"], w)
    outputs = [
        _nonzeros(hessian),
        objective_scale * ca.gradient(nlp["f"], w),
        _nonzeros(constraint_jacobian),
        nlp["g"],
    ]
    if still_water_slice is not None:
        current = p[still_water_slice]
        outputs = ca.substitute(outputs, [current], [ca.DM.zeros(current.numel())])
    linearise = ca.Function(name, [w, p], outputs, ["w", "p"], ["h", "grad", "a", "g"])
    return linearise, hessian.sparsity(), constraint_jacobian.sparsity()


def _nonzeros(matrix: ca.SX) -> ca.SX:
    """Column of the structural nonzeros of ``matrix`` (column-major, CasADi's order)."""
    entries: list[Any] = matrix.nonzeros()
    return ca.vertcat(*entries) if entries else ca.SX(0, 1)


def qp_step_function(
    hessian: ca.Sparsity,
    jacobian: ca.Sparsity,
    qpsol: str,
    qpsol_options: dict[str, Any],
    name: str,
) -> ca.Function:
    """``step(h_nz, grad, a_nz, g, w, lbx, ubx, lbg, ubg) -> (d, lam_x, lam_g, violation)``.

    Solves the QP of the module doc with ``qpsol`` and measures how far its solution ``d``
    violates the linearised constraints and bounds (``inf`` when not finite): the success test.
    """
    solver = ca.conic(
        f"{name}_qp", qpsol, {"h": hessian, "a": jacobian}, {"error_on_fail": False, **qpsol_options}
    )
    h = ca.MX.sym("h", hessian.nnz())
    grad = ca.MX.sym("grad", hessian.size1())
    a = ca.MX.sym("a", jacobian.nnz())
    g = ca.MX.sym("g", jacobian.size1())
    w = ca.MX.sym("w", hessian.size1())
    lbx, ubx = ca.MX.sym("lbx", w.numel()), ca.MX.sym("ubx", w.numel())
    lbg, ubg = ca.MX.sym("lbg", g.numel()), ca.MX.sym("ubg", g.numel())
    H = ca.MX(hessian, h)
    A = ca.MX(jacobian, a)
    solution = solver(h=H, g=grad, a=A, lbx=lbx - w, ubx=ubx - w, lba=lbg - g, uba=ubg - g)
    d = solution["x"]
    linear = g + ca.mtimes(A, d)
    excess = ca.vertcat(
        ca.fmax(linear - ubg, 0), ca.fmax(lbg - linear, 0), ca.fmax(w + d - ubx, 0), ca.fmax(lbx - w - d, 0)
    )
    violation = ca.mmax(excess) if excess.numel() else ca.MX(0)
    # NaN compares false: a non-finite solution must not pass the test
    finite = ca.logic_and(ca.le(ca.mmax(ca.fabs(d)), 1e300), ca.le(violation, 1e300))
    violation = ca.if_else(finite, violation, ca.inf)
    return ca.Function(
        name,
        [h, grad, a, g, w, lbx, ubx, lbg, ubg],
        [d, solution["lam_x"], solution["lam_a"], violation],
        ["h", "grad", "a", "g", "w", "lbx", "ubx", "lbg", "ubg"],
        ["d", "lam_x", "lam_g", "violation"],
    )


class RtiSolver(NlpSolver):
    """Real-time iteration Gauss–Newton SQP on a structured QP (see the module doc).

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    options : dict, optional
        Those of :class:`NlpSolver` (``terminal_strategy``, ``slack_tolerance``, ``max_iter``,
        ``deadline``, ``compiled``, ``still_water``, ``terminal_penalty``, …; ``plugin_options``
        must stay empty: the QP's options are ``qpsol_options``) and ``mode``, ``iterations``,
        ``tol``, ``cold_start``, ``qpsol``, ``qpsol_options``, ``qp_tolerance``.
    """

    name = "sqp-rti"
    plugin = "rti"
    default_max_iter = RTI_MAX_ITER
    OPTIONS = RTI_OPTIONS
    option_names = option_names(RTI_OPTIONS)

    def __init__(self, problem: Transcribed, options: dict[str, Any] | None = None) -> None:
        options = dict(options or {})
        default = option_defaults(self.OPTIONS)
        self.mode = check.choice("options['mode']", options.pop("mode", default["mode"]), MODES)
        self.iterations = check.positive_int(
            "options['iterations']", options.pop("iterations", default["iterations"])
        )
        self.tol = check.positive_float("options['tol']", options.pop("tol", default["tol"]))
        self.cold_start = check.choice(
            "options['cold_start']", options.pop("cold_start", default["cold_start"]), COLD_STARTS
        )
        self.qpsol = check.choice("options['qpsol']", options.pop("qpsol", default["qpsol"]), QP_SOLVERS)
        tight = self.qpsol == "hpipm" and self.mode == "converged"
        qpsol_options = options.pop("qpsol_options", default["qpsol_options"])
        given_qp_options = qpsol_options
        if qpsol_options is AUTO:
            qpsol_options = HPIPM_DEFAULTS if tight else {}
        if not isinstance(qpsol_options, dict):
            raise ValueError(f"options['qpsol_options'] must be a dict, got {check.shown(qpsol_options)}")
        self.qpsol_options = dict(qpsol_options)
        self.ocp_qp_options: dict[str, Any] = {}
        if self.qpsol == "hpipm-ocp":
            self.ocp_qp_options = ocp_qp_options(
                {} if given_qp_options is AUTO else self.qpsol_options, self.mode == "converged"
            )
        self.qp_tolerance = check.positive_float(
            "options['qp_tolerance']", options.pop("qp_tolerance", default["qp_tolerance"])
        )
        super().__init__(problem, options)
        if self.plugin_options:
            raise ValueError(
                "options['plugin_options'] is not used by 'sqp-rti' (no nlpsol plugin); pass the QP "
                f"solver's options as options['qpsol_options'], got {check.shown(self.plugin_options)}"
            )
        self._qp_structure: dict[str, tuple[ca.Function, ca.Sparsity, ca.Sparsity]] = {}
        self._linearisations: dict[tuple[str, bool], BufferedFunction] = {}
        self._steps: dict[str, BufferedFunction] = {}
        self._initial_rows: dict[str, np.ndarray] = {}
        self._prepared: Preparation | None = None
        self._x0 = problem.spec().layout.x0
        self._ocp_steps: dict[tuple[str, bool], OcpQpStep | None] = {}
        self._c_time = 0.0

    # ---------------------------------------------------------------- functions
    def _sparsities(self, variant: str) -> tuple[ca.Function, ca.Sparsity, ca.Sparsity]:
        if variant not in self._qp_structure:
            self._qp_structure[variant] = qp_functions(
                self.variants[variant], None, self.objective_scale, f"rti_linearise_{variant}"
            )
        return self._qp_structure[variant]

    def linearisation(self, variant: str, still_water: bool = False) -> BufferedFunction:
        """Zero-copy ``linearise(w, p)`` of ``variant`` (compiled with ``compiled=True``)."""
        key = (variant, still_water)
        if key not in self._linearisations:
            if still_water:
                function, _, _ = qp_functions(
                    self.variants[variant],
                    self._still_water_slice,
                    self.objective_scale,
                    f"rti_linearise_{variant}_still_water",
                )
            else:
                function = self._sparsities(variant)[0]
            if self.compiled:
                function = self._compiled(function)
            self._linearisations[key] = BufferedFunction(function)
        return self._linearisations[key]

    def qp_step(self, variant: str) -> BufferedFunction:
        """Zero-copy QP step Function of ``variant`` (see :func:`qp_step_function`)."""
        if variant not in self._steps:
            _, hessian, jacobian = self._sparsities(variant)
            self._steps[variant] = BufferedFunction(
                qp_step_function(hessian, jacobian, self.qpsol, self.qpsol_options, f"rti_qp_{variant}")
            )
        return self._steps[variant]

    def ocp_step(self, variant: str, still_water: bool = False) -> OcpQpStep | None:
        """Return the C step of ``variant`` on HPIPM's OCP-QP (``qpsol="hpipm-ocp"``), built once.

        ``None`` when this backend does not use it, or when it cannot be built (no compiler, a
        failed build, an NLP without the stage structure): the backend then warns once and
        keeps CasADi's ``hpipm`` path for the rest of its life.
        """
        if self.qpsol != "hpipm-ocp":
            return None
        key = (variant, still_water)
        if key not in self._ocp_steps:
            from uuv_ocp.codegen import default_cache_directory
            from uuv_ocp.native.compile import CodegenError
            from uuv_ocp.solvers.rti_ocp import UnsupportedStructure, build_step

            spec = self.problem.spec()
            try:
                self._ocp_steps[key] = build_step(
                    self.variants[variant],
                    spec.state_dim,
                    np.arange(spec.layout.size)[self._x0],
                    self.objective_scale,
                    self._still_water_slice if still_water else None,
                    self.ocp_qp_options,
                    default_cache_directory(),
                    f"uuv_ocp_rti_{variant.replace('.', '_')}{'_still_water' if still_water else ''}",
                )
            except (CodegenError, OSError, UnsupportedStructure) as error:
                warnings.warn(
                    f"sqp-rti: qpsol='hpipm-ocp' unavailable ({type(error).__name__}: {error}); "
                    "using CasADi's hpipm interface",
                    RuntimeWarning,
                    stacklevel=3,
                )
                self.qpsol = "hpipm"
                self.qpsol_options = HPIPM_DEFAULTS if self.mode == "converged" else {}
                self._ocp_steps.clear()
                return None
        return self._ocp_steps[key]

    def _compiled(self, function: ca.Function) -> ca.Function:
        """Compile ``function`` to C in the solvers' cache (CasADi's VM if unavailable)."""
        from uuv_ocp.codegen import default_cache_directory
        from uuv_ocp.native.compile import load_or_fallback

        loaded, library = load_or_fallback([function], default_cache_directory(), name="uuv_ocp_rti")
        if library is None:
            self.compiled = False
        return loaded[function.name()]

    def _state_rows(self, variant: str) -> np.ndarray:
        """Rows of ``g`` holding ``X_0[:nx] − x0`` (where the measured state enters)."""
        if variant not in self._initial_rows:
            keys = self.variants[variant].constraint_keys
            position = {key: i for i, key in enumerate(keys)}
            self._initial_rows[variant] = np.array(
                [position[("initial", None, i)] for i in range(self._state_dim)], dtype=int
            )
        return self._initial_rows[variant]

    # ------------------------------------------------------------------ phases
    def first_variant(self, warm_start: Iterate | None) -> str:
        """NLP variant the next :meth:`solve` tries first (the terminal strategy's choice)."""
        if "soft" not in self.variants:
            return "hard"
        strategy = self.terminal_strategy
        if strategy == "soft" or (
            strategy == "sticky" and warm_start is not None and warm_start.terminal_relaxed
        ):
            if warm_start is not None and warm_start.variant in self._escalations:
                return warm_start.variant
            return "soft"
        return "hard"

    def prepare(self, p: np.ndarray, warm_start: Iterate | None) -> Preparation | None:
        """Linearise at ``warm_start`` for instance ``p`` (its state part a guess); keep it.

        Returns ``None`` (nothing prepared) without a warm start: the cold initial guess
        depends on the measured state.
        """
        if warm_start is None:
            self._prepared = None
            return None
        start = time.perf_counter()
        variant = self.first_variant(warm_start)
        primal, _, _ = self._initial_point(variant, p, warm_start)
        still_water = self._uses_still_water(p)
        ocp = self.ocp_step(variant, still_water)
        if ocp is not None:
            ocp.prepare(primal, p)  # the QP stays in the C step's memory
            qp: tuple[np.ndarray, ...] = ()
        else:
            qp = tuple(self.linearisation(variant, still_water)(primal, p))
        self._prepared = Preparation(
            variant, np.array(p, dtype=float), primal, qp, still_water, time.perf_counter() - start
        )
        return self._prepared

    def feedback(self, p: np.ndarray, warm_start: Iterate | None) -> SolveResult:
        """Solve instance ``p`` from the prepared linearisation (see :meth:`prepare`).

        The preparation is used when its variant is the first one tried and ``p`` differs from
        its parameters only in the state; otherwise this is :meth:`solve`.
        """
        return self.solve(p, warm_start)

    def _matching_preparation(
        self, variant: str, p: np.ndarray, primal: np.ndarray, still_water: bool
    ) -> Preparation | None:
        """Return the kept preparation if it linearised this instance but its state (then forget it)."""
        prepared, self._prepared = self._prepared, None
        if prepared is None or prepared.variant != variant or prepared.still_water != still_water:
            return None
        if prepared.primal is not primal and not np.array_equal(prepared.primal, primal):
            return None
        other = np.ones(p.size, dtype=bool)
        other[self._x0] = False
        if not np.array_equal(prepared.p[other], p[other]):
            return None
        return prepared

    def _take_prepared(self, variant: str, p: np.ndarray, primal: np.ndarray, still_water: bool):
        prepared = self._matching_preparation(variant, p, primal, still_water)
        if prepared is None or not prepared.qp:
            return None
        h, grad, a, g = prepared.qp
        g = g.copy()
        # g_init = X_0[:nx] − x0: the measured state moves these rows only (linearly)
        g[self._state_rows(variant)] += prepared.p[self._x0] - p[self._x0]
        return h, grad, a, g

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
    ) -> SolveResult:
        """Solve the instance ``p`` by real-time iteration (see the module doc).

        With ``qpsol="hpipm-ocp"`` the result's ``details["c_time"]`` is the time (s) the C
        step measured itself: the preparation used and this call's linearisations and QPs.
        """
        self._c_time = 0.0
        try:
            result = super().solve(p, warm_start, rng, time_limit=time_limit)
        finally:
            self._prepared = None
        if self.qpsol == "hpipm-ocp":
            result.details["c_time"] = self._c_time
        return result

    def robust_options(self) -> dict[str, Any]:
        """IPOPT on the same NLP variant: the cold start and the last resort (see module doc)."""
        from uuv_ocp.solvers.ipopt import ipopt_options

        return {"plugin": "ipopt", **ipopt_options(self.max_iter, self.deadline)}

    def _attempt(
        self, variant: str, p: np.ndarray, warm_start: Iterate | None, robust: bool | str = False
    ) -> dict[str, Any]:
        if robust or (warm_start is None and self.cold_start == "ipopt"):
            self._prepared = None
            return super()._attempt(variant, p, warm_start, robust=True)
        data = self.variants[variant]
        primal, lam_g, lam_x = self._initial_point(variant, p, warm_start)
        primal = np.array(primal, dtype=float)
        lam_g = np.zeros(data.lbg.size) if lam_g is None else lam_g
        lam_x = np.zeros(data.lbx.size) if lam_x is None else lam_x
        still_water = self._uses_still_water(p)
        converge = self.mode == "converged" or (warm_start is None and self.cold_start == "converged")
        limit = (self.max_iter or self.default_max_iter) if converge else self.iterations
        ocp = self.ocp_step(variant, still_water)
        if ocp is not None:
            return self._attempt_in_c(ocp, variant, p, primal, lam_x, lam_g, still_water, converge, limit)
        linearise, step = self.linearisation(variant, still_water), self.qp_step(variant)
        prepared = self._take_prepared(variant, p, primal, still_water)
        start = time.perf_counter()
        iterations, converged, feasible, status = 0, False, False, "max_iter"
        violation, step_norm = math.inf, math.inf
        while iterations < limit:
            if iterations and time.perf_counter() >= self._clock.at:
                status = "stopped by the deadline"
                break
            try:
                h, grad, a, g = prepared if prepared is not None else linearise(primal, p)
                prepared = None
                d, new_lam_x, new_lam_g, (violation,) = step(
                    h, grad, a, g, primal, data.lbx, data.ubx, data.lbg, data.ubg
                )
            except RuntimeError as error:
                reraise_interrupt(error)
                status, feasible = f"QP failed: {error}", False
                break
            iterations += 1
            feasible = bool(violation <= self.qp_tolerance)
            if not feasible:
                status = (
                    f"QP solution infeasible (linearised violation {violation:.3g} > {self.qp_tolerance:g})"
                )
                break
            primal = primal + d
            lam_x, lam_g = new_lam_x / self.objective_scale, new_lam_g / self.objective_scale
            step_norm = float(np.max(np.abs(d))) if d.size else 0.0
            if step_norm <= self.tol:
                converged, status = True, "converged"
                break
        else:
            status = "max_iter" if converge else f"rti ({iterations} iteration(s))"
        success = feasible and (converged or not converge)
        if feasible and not converge and not converged:
            status = f"rti ({iterations} iteration(s), last step {step_norm:.3g})"
        return {
            "variant": variant,
            "robust": robust,
            "still_water": still_water,
            "primal": primal,
            "lam_g": lam_g,
            "lam_x": lam_x,
            "success": success,
            "status": status,
            "iterations": iterations,
            "evaluations": iterations,
            "plugin_time": time.perf_counter() - start,
        }

    def _attempt_in_c(
        self,
        ocp: OcpQpStep,
        variant: str,
        p: np.ndarray,
        primal: np.ndarray,
        lam_x: np.ndarray,
        lam_g: np.ndarray,
        still_water: bool,
        converge: bool,
        limit: int,
    ) -> dict[str, Any]:
        """Run the iterations of :meth:`_attempt` in one call of the C step (same stops, statuses)."""
        prepared = self._matching_preparation(variant, p, primal, still_water) is not None
        scale = self.objective_scale
        start = time.perf_counter()
        budget = self._clock.at - start if math.isfinite(self._clock.at) else math.inf
        primal, lam_x, lam_g, info = ocp.iterate(
            primal, p, lam_x * scale, lam_g * scale, prepared, limit, self.tol, self.qp_tolerance, budget
        )
        plugin_time = time.perf_counter() - start
        # seconds inside C: the preparation used, then this call's linearisations and QPs
        self._c_time += float(info[8] + info[6] + info[7])
        iterations, violation, step_norm, stop = int(info[0]), float(info[1]), float(info[2]), int(info[3])
        converged = stop == STOP_CONVERGED
        feasible = stop not in (STOP_INFEASIBLE, STOP_EVALUATION)
        if stop == STOP_INFEASIBLE:
            status = f"QP solution infeasible (linearised violation {violation:.3g} > {self.qp_tolerance:g})"
        elif stop == STOP_EVALUATION:
            status = "QP failed: the linearisation could not be evaluated"
        elif stop == STOP_DEADLINE:
            status = "stopped by the deadline"
        elif converged:
            status = "converged"
        else:
            status = "max_iter" if converge else f"rti ({iterations} iteration(s), last step {step_norm:.3g})"
        if feasible and not converge and not converged:
            status = f"rti ({iterations} iteration(s), last step {step_norm:.3g})"
        return {
            "variant": variant,
            "robust": False,
            "still_water": still_water,
            "primal": primal,
            "lam_g": lam_g / scale,
            "lam_x": lam_x / scale,
            "success": feasible and (converged or not converge),
            "status": status,
            "iterations": iterations,
            "evaluations": iterations,
            "plugin_time": plugin_time,
            "qp_iterations": int(info[4]),
        }


def nmpc_step_function(
    problem: Transcribed, name: str = "nmpc_step", qpsol: str = "hpipm-ocp"
) -> tuple[ca.Function, RtiSolver]:
    """One real-time iteration as a single CasADi Function, and the backend that computes it.

    ``nmpc_step(x0, u_prev, p, w) -> (u, w_next, violation)``: the instance ``p`` with its
    state and last-control blocks replaced by ``x0`` and ``u_prev``, one Gauss–Newton QP step
    from the primal ``w`` of the exact-penalty NLP (the hard one if the problem has no terminal
    equality: the soft QP is always feasible, so a C loop needs no fallback chain), ``u`` the
    first control (physical units), ``w_next`` the new primal shifted by one stage (the next
    call's ``w``) and ``violation`` the QP's linearised constraint violation (``inf``: not
    finite).  The returned backend is :class:`RtiSolver` with ``terminal_strategy="soft"``,
    ``cold_start="rti"``, ``still_water=False`` and ``qpsol``: the generated C
    (:func:`uuv_ocp.solvers.rti_ocp.nmpc_step_source`) runs the same C step as that backend
    with ``qpsol="hpipm-ocp"``; the Function here is its symbolic twin on CasADi's ``conic``
    HPIPM interface (the same QP, so equal to the QP solvers' tolerance).
    """
    backend = RtiSolver(
        problem, {"terminal_strategy": "soft", "cold_start": "rti", "still_water": False, "qpsol": qpsol}
    )
    variant = "soft" if "soft" in backend.variants else "hard"
    data = backend.variants[variant]
    linearise, hessian, jacobian = backend._sparsities(variant)
    step = qp_step_function(hessian, jacobian, "hpipm", {}, f"{name}_qp")
    layout = problem.spec().layout
    spec = problem.spec()
    x0 = ca.MX.sym("x0", spec.state_dim)
    u_prev = ca.MX.sym("u_prev", spec.control_size)
    p = ca.MX.sym("p", layout.size)
    w = ca.MX.sym("w", data.lbx.size)
    pieces, position = [], 0
    for part, value in sorted(((layout.x0, x0), (layout.u_prev, u_prev)), key=lambda item: item[0].start):
        pieces += [p[position : part.start], value]
        position = part.stop
    pieces.append(p[position:])
    full = ca.vertcat(*[piece for piece in pieces if piece.numel()])
    h, grad, a, g = linearise(w, full)
    d, _, _, violation = step(h, grad, a, g, w, data.lbx, data.ubx, data.lbg, data.ubg)
    primal = w + d
    first = primal[[int(i) for i in data.control_index[0]]]
    control = spec.physical(first) if isinstance(first, ca.SX) else _physical_mx(spec, first)
    shifted = primal[[int(i) for i in data.primal_shift]]
    function = ca.Function(
        name,
        [x0, u_prev, p, w],
        [control, shifted, violation],
        ["x0", "u_prev", "p", "w"],
        ["u", "w_next", "violation"],
    )
    return function, backend


def _physical_mx(spec: Any, scaled: ca.MX) -> ca.MX:
    value = scaled * ca.DM(spec.control_scale)
    return value + ca.DM(spec.control_centre) if np.any(spec.control_centre) else value
