"""Exact backends: the multiple-shooting NLP solved by ``casadi.nlpsol`` plugins.

Terminal equality (the paper's ``x_N = x_R,N``) is often infeasible while the vehicle still
accelerates from rest.  Every exact backend therefore handles ``terminal="equality"`` as follows
(the ``terminal_strategy`` option):

``"sticky"`` (default)
    Solve the hard NLP.  If the backend fails, solve the exact-penalty soft NLP (L1 penalty
    ``ρ Σ|x_N − x_R,N|`` through slacks, ρ = ``Weights.terminal_penalty``) within the same
    call and report ``terminal_relaxed=True``.  After a relaxed step the next solve starts with
    the soft NLP; when its terminal slacks vanish (≤ ``slack_tolerance``) the terminal equality
    holds, the solution is a KKT point of the hard NLP (exact penalty) and the result is
    reported as not relaxed.  This pays for at most one failed hard attempt per infeasible
    stretch instead of one per step.
``"hard-first"``
    Always try the hard NLP first.
``"soft"``
    Always solve the soft NLP.

Deadline (``deadline`` option, seconds of wall time per :meth:`NlpSolver.solve`, read on
:func:`uuv_ocp.solvers.watchdog.now`).  Checked at two levels: *between attempts* — after the
deadline no new attempt of the fallback chain (hard → soft → cold retry → penalty escalations →
robust retry → rescue; a backend's rescue also right after an attempt that
:meth:`~NlpSolver.stalled`) starts — and *inside every attempt*: ``ipopt`` and ``sqpmethod`` call
CasADi's ``iteration_callback`` after every iteration and stop when it reports the deadline
passed (IPOPT additionally gets ``max_wall_time`` and ``max_cpu_time`` = the deadline); plugins
without a callback or a time limit (CasADi 3.8's ``fatrop``, ``blocksqp``) run in the watchdog's
worker process (:mod:`~uuv_ocp.solvers.watchdog`), killed at the deadline.  A solve whose wall
time, less the time spent building plugins, exceeds the deadline reports ``success=False``, a
status starting with ``deadline``, and ``details["deadline_hit"] = True``: its plan was not ready
in time, whatever the last attempt reached.  Fatrop's attempts always run in the worker, which
also stops one that stalls inside an iteration or runs past ``max_iter`` iterations counting the
restoration phase (see :class:`~uuv_ocp.solvers.fatrop.FatropSolver`).

A failed solve's ``states`` are the rollout of its ``controls`` (see :meth:`NlpSolver._rolled_out`).

The backends themselves live one per module: :mod:`~uuv_ocp.solvers.ipopt`,
:mod:`~uuv_ocp.solvers.fatrop` and :mod:`~uuv_ocp.solvers.sqp`, above this one (import them from
there or from :mod:`uuv_ocp.solvers`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import score_parameters
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.compile import CodegenError
from uuv_ocp.native.runtime import compiled_nlpsol
from uuv_ocp.solvers import watchdog
from uuv_ocp.solvers.base import reraise_interrupt
from uuv_ocp.solvers.options import (
    Option,
    among,
    boolean,
    declaration,
    factors,
    mapping,
    nonnegative_float,
    one_of,
    option,
    option_names,
    optional,
    parse_options,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import HARD, SOFT, Attempt, Iterate, SolveDetails, SolveResult, Stage, Variant
from uuv_ocp.transcription.base import transcription
from uuv_ocp.transcription.multiple_shooting import NlpData, transfer_map

TERMINAL_STRATEGIES = ("sticky", "hard-first", "soft")
# nlpsol plugins that call CasADi's ``iteration_callback`` after each iteration (checked on
# CasADi 3.8: fatrop and blocksqp never call it)
CALLBACK_PLUGINS = ("ipopt", "sqpmethod")
# plugin statuses of a stop by the plugin's own time limit (IPOPT's max_wall_time / max_cpu_time)
_TIME_LIMIT_STATUSES = ("Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded")


class _DeadlineClock:
    """The absolute deadline (a :func:`~uuv_ocp.solvers.watchdog.now` time) of the solve that runs.

    Shared with the iteration callbacks; ``fired`` says whether a callback asked the plugin to
    stop during the current attempt.
    """

    def __init__(self) -> None:
        self.at = math.inf
        self.fired = False


class _DeadlineCallback(ca.Callback):
    """``iteration_callback`` that asks the plugin to stop once ``clock.at`` has passed.

    It reads no iterate (``eval_buffer``, no conversion of its inputs): one clock read per
    iteration.
    """

    def __init__(self, name: str, sizes: tuple[int, int, int], clock: _DeadlineClock) -> None:
        ca.Callback.__init__(self)
        nx, ng, np_ = sizes
        dense = ca.Sparsity.dense
        # inputs: the nlpsol outputs x, f, g, lam_x, lam_g, lam_p
        self._sparsities = [dense(nx), ca.Sparsity.scalar(), dense(ng), dense(nx), dense(ng), dense(np_)]
        self._clock = clock
        self.construct(name, {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return self._sparsities[i]

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.scalar()

    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg: tuple[memoryview, ...], res: tuple[memoryview, ...]) -> int:
        stop = watchdog.now() >= self._clock.at
        if stop:
            self._clock.fired = True
        res[0].cast("d")[0] = 1.0 if stop else 0.0  # nonzero: the plugin stops
        return 0


# CasADi's unified statuses, for plugins without a return_status of their own (blocksqp)
_UNIFIED_STATUSES = {
    "SOLVER_RET_SUCCESS": "Solve_Succeeded",
    "SOLVER_RET_LIMITED": "Maximum_Iterations_Exceeded",
    "SOLVER_RET_NAN": "NaN_Detected",
    "SOLVER_RET_INFEASIBLE": "Infeasible_Problem_Detected",
    "SOLVER_RET_EXCEPTION": "Exception_Raised",
    "SOLVER_RET_UNKNOWN": "Unknown_Failure",
}


def plugin_status(plugin: str, stats: dict[str, Any]) -> str:
    """Return the status text of a plugin call: its ``return_status``, else CasADi's unified status.

    ``blocksqp`` reports no ``return_status``; its ``unified_return_status`` is translated to
    IPOPT's wording and the plugin named (``"blocksqp: Maximum_Iterations_Exceeded"``).
    """
    status = stats.get("return_status")
    if status is not None and str(status) != "":
        return str(status)
    unified = stats.get("unified_return_status")
    if unified is not None:
        return f"{plugin}: {_UNIFIED_STATUSES.get(str(unified), str(unified))}"
    success = stats.get("success")
    if success is None:
        return f"{plugin}: no status reported"
    return f"{plugin}: {'Solve_Succeeded' if success else 'failed without a status'}"


@functools.cache
def _is_nlpsol(plugin: str) -> bool:
    """Whether CasADi has an ``nlpsol`` plugin of this name (cached: a miss tries to load a library)."""
    return bool(ca.has_nlpsol(plugin))


def _transfer(values: np.ndarray | None, mapping: np.ndarray, fill: float = 0.0) -> np.ndarray | None:
    if values is None:
        return None
    result = np.full(mapping.shape, fill, dtype=float)
    present = mapping >= 0
    result[present] = values[mapping[present]]
    return result


def _with_slack_curvature(data: NlpData, curvature: float) -> NlpData:
    """Return ``data`` with ``(μ/2) Σ s²`` added on the terminal slacks (an L1 + L2 exact penalty).

    The term enters as the extra residual ``sqrt(μ/2) s``, so ``f = ‖r‖² + linear`` still holds
    and a Gauss–Newton Hessian built from ``residual`` gets ``μ`` on the slack diagonal.
    """
    slacks = ca.vertcat(*[data.nlp["x"][int(i)] for i in data.terminal_slack_index])
    extra = math.sqrt(0.5 * curvature) * slacks
    nlp = dict(data.nlp)
    nlp["f"] = nlp["f"] + ca.sumsqr(extra)
    return dataclasses.replace(data, nlp=nlp, residual=ca.vertcat(data.residual, extra))


@dataclasses.dataclass(frozen=True)
class ChainOptions:
    """Options of the fallback chain of every :class:`NlpSolver` (the NLP variants, the deadline).

    What a backend on :class:`NlpSolver` honours whatever solves its attempts; a backend that
    is not a CasADi ``nlpsol`` (:mod:`~uuv_ocp.solvers.slsqp`) takes these and its own.
    """

    terminal_strategy: str = option(
        "sticky",
        one_of(TERMINAL_STRATEGIES),
        'hard NLP, soft fallback and which is tried first (see "Terminal equality policy")',
        check=among(TERMINAL_STRATEGIES),
    )
    terminal_penalty: float | None = option(
        None,
        "float > 0 or `None`",
        "ρ of the soft NLP's exact penalty ρ Σ|x_N − x_R,N| on the terminal equality",
        unit="cost per unit of the terminal equality",
        meaning="the problem's (`Ocp(terminal_penalty=)`; tracking preset: `Weights.terminal_penalty`)",
        check=optional(positive_float),
    )
    penalty_escalation: tuple[float, ...] = option(
        (),
        "tuple of factors > 0",
        "factors ρ is multiplied by in turn, warm-started, while the soft solve fails",
        meaning="none",
        check=factors,
    )
    slack_curvature: float = option(
        0.0,
        "float >= 0",
        "μ of an added (μ/2) Σ s² on the terminal slacks (an L1 + L2 exact penalty)",
        check=nonnegative_float,
    )
    slack_tolerance: float = option(
        1e-7,
        "float > 0",
        "largest terminal slack of a soft solve still reported as the equality held",
        unit="those of the terminal equality (tracking: the states')",
        check=positive_float,
    )
    max_iter: int | None = option(
        None,
        "int >= 1 or `None`",
        "iteration limit of one attempt of the plugin",
        meaning="the backend's own limit",
        check=optional(positive_int),
    )
    objective_scale: float = option(
        1.0,
        "float > 0",
        "factor on the objective the plugin sees (its absolute tolerances against the weights)",
        check=positive_float,
    )
    deadline: float | None = option(
        None,
        "float > 0 or `None`",
        'wall-time budget of one solve (see "Deadlines")',
        unit="s",
        meaning="none",
        check=optional(positive_float),
    )


@dataclasses.dataclass(frozen=True)
class NlpOptions(ChainOptions):
    """Options of every :class:`NlpSolver` on a CasADi ``nlpsol`` plugin (subclasses add their own)."""

    compiled: bool = option(
        False,
        "`True` or `False`",
        "JIT-compile the NLP functions with the system C compiler (none: the virtual machine, one warning)",
        check=boolean,
    )
    still_water: bool = option(
        True,
        "`True` or `False`",
        "solve the NLP specialised to zero current when the model's current is zero on the whole horizon",
        check=boolean,
    )
    plugin_options: dict = option(
        {},
        "dict",
        "merged into the CasADi `nlpsol` options, over this backend's settings",
        check=mapping,
    )


NLP_OPTIONS: tuple[Option, ...] = declaration(NlpOptions)
"""Rows of :class:`NlpOptions` (the docs' table; subclasses revise defaults and add their own)."""


class ColdRetries:
    """Cold retries shared by several solves of one instance (a hybrid's starts).

    A chain whose first attempt fails retries from the cold guess (``warm_start=None``): the
    same attempt whatever the failed start was.  Solves given one :class:`ColdRetries` (see
    :meth:`NlpSolver.share_cold_retries`) run it once per backend settings, NLP variant and
    instance and reuse it
    after (the same :class:`~uuv_ocp.solvers.result.Attempt`, so the same result); only without
    a time limit, where an attempt does not depend on when it starts.  ``reused`` counts the
    attempts not run again.
    """

    def __init__(self) -> None:
        self.attempts: dict[tuple[str, str, bool, bytes], Attempt] = {}
        self.reused = 0


@dataclasses.dataclass
class _Chain:
    """The fallback chain of one :meth:`NlpSolver.solve` call: its attempts so far, in order.

    ``skipped`` counts attempts not started after the deadline; ``build_time`` (s) is the time
    spent building plugins, which the deadline does not count.  One per call, never shared.
    """

    p: np.ndarray
    attempts: list[Attempt] = dataclasses.field(default_factory=list)
    skipped: int = 0
    build_time: float = 0.0

    @property
    def last(self) -> Attempt:
        """The latest attempt."""
        return self.attempts[-1]


class NlpSolver:
    """Solve any :class:`~uuv_ocp.ocp.Ocp` (or tracking preset) with one ``casadi.nlpsol`` plugin.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    options : dict, optional
        The options of :data:`OPTIONS` (for this class :data:`NLP_OPTIONS`: name, default,
        values and meaning of each; rendered as a table in docs/solvers.md), among them
        ``terminal_strategy`` and ``deadline`` (see module doc) and ``still_water`` (see
        below).

    Notes
    -----
    Still-water specialisation: when the current the model assumes over the horizon is exactly
    zero (the paper's controller, and every closed loop that is not told a current), the solve
    uses the same NLP with the current parameters substituted by zero before differentiation.
    CasADi's simplifier then drops every current term (``cos ψ·0``, ``u − 0``, ``r·0``) from the
    functions and their derivatives: on the RexROV N = 20 NLP the Hessian of the Lagrangian
    goes from 81 k to 58 k virtual-machine instructions and the constraint Jacobian from 40 k
    to 30 k.  The two NLPs are the same function of the decision variables when the current is
    zero (they differ only in floating-point rounding, ~1e-14 on the Hessian); their layouts are
    identical, so warm starts pass between them.  ``still_water=False`` always uses the
    general NLP.
    """

    name = "nlp"
    plugin = ""
    time_limited = True  # solve(..., time_limit=) (the Backend protocol's capability)
    uses_duals = True
    levenberg_marquardt = 0.0
    # the options ``options`` may hold, with their defaults (see uuv_ocp.solvers.options); a
    # subclass with options or defaults of its own declares its own tuple
    #: the options dataclass :func:`~uuv_ocp.solvers.options.parse_options` reads ``options`` into
    Options: type[ChainOptions] = NlpOptions
    # its rows (what catalog.declared_options() and the docs read); a subclass declares both
    OPTIONS: tuple[Option, ...] = NLP_OPTIONS
    option_names: tuple[str, ...] = option_names(NLP_OPTIONS)
    # set from the parsed options (ChainOptions' fields), typed here for the plumbing
    terminal_strategy: str
    terminal_penalty: float | None
    penalty_escalation: tuple[float, ...]
    slack_curvature: float
    slack_tolerance: float
    max_iter: int | None
    objective_scale: float
    deadline: float | None
    # what a backend whose Options lack them (no nlpsol: compiled, still water, plugin options) runs with
    compiled = False
    still_water = False
    plugin_options: Mapping[str, Any] = MappingProxyType({})
    #: caller of the judge's ``score_terms`` (a compiled, verified twin); None: CasADi's VM
    judge_terms: BufferedFunction | None = None

    def __init__(self, problem: Transcribed, options: dict[str, Any] | None = None) -> None:
        self.problem = problem
        self.settings = parse_options(self.Options, options, self.name, self.option_names)
        for key, value in dataclasses.asdict(self.settings).items():
            setattr(self, key, value)  # self.max_iter, self.deadline, ... as the plumbing reads them
        terminal_penalty = self.terminal_penalty
        penalty_escalation = self.penalty_escalation
        if isinstance(self.settings, NlpOptions) and self.plugin:
            # an unknown name or a wrong type crashed the first solve with a CasADi traceback
            check.nlpsol_options("options['plugin_options']", self.plugin, dict(self.plugin_options))
        # the soft NLP's exact-penalty weight may be the solver's own: only the soft variant
        # changes, the hard NLP and the judge (score) stay those of ``problem``
        built = problem.build()
        self.variants: dict[str, NlpData] = {HARD: built.hard}  # keyed by Variant
        self._escalations: list[Variant] = []
        base = terminal_penalty if terminal_penalty is not None else built.spec.terminal_penalty
        soft = built.soft_variant(base)
        if soft is not None:
            self.variants[SOFT] = soft
            for factor in penalty_escalation:
                name = Variant.escalated(factor)
                self.variants[name] = built.soft_variant(base * factor)  # type: ignore[assignment]
                self._escalations.append(name)
            if self.slack_curvature > 0.0:
                for name in (SOFT, *self._escalations):
                    self.variants[name] = _with_slack_curvature(self.variants[name], self.slack_curvature)
        self._solvers: dict[tuple[str, Stage, bool], BufferedFunction] = {}
        self._maps: dict[tuple[str, str, str], tuple[np.ndarray, np.ndarray]] = {}
        self._control_box: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._clock = _DeadlineClock()
        self._plugins: dict[tuple[str, Stage, bool], str] = {}
        # attempts of plugins that cannot stop themselves run in this forked worker (see watched)
        self._worker = watchdog.Worker(self._solvers.__getitem__)
        self._cold_retries: ColdRetries | None = None
        self._deadline_callbacks: list[_DeadlineCallback] = []  # kept alive for their nlpsols
        self._still_water_slice = problem.still_water_slice
        self._state_dim = built.spec.state_dim
        self._lifted = built.spec.lifted

    # --------------------------------------------------------------- plumbing
    def plugin_defaults(self, data: NlpData) -> dict[str, Any]:
        """Options passed to ``casadi.nlpsol`` (overridden by ``plugin_options``)."""
        return {}

    def gauss_newton_hessian(self, data: NlpData) -> ca.Function:
        """``λ_f · s · 2 JᵣᵀJᵣ``: Gauss–Newton Hessian of the scaled objective ``s f``.

        ``f = ‖r‖² + linear`` exactly, so this is the Hessian of ``f`` without the residual
        curvature and without constraint curvature: positive semidefinite, block diagonal per
        stage, and equal to the exact Hessian's dominant part when residuals are small.
        """
        nlp = data.nlp
        jacobian = ca.jacobian(data.residual, nlp["x"])
        objective_factor = ca.SX.sym("lam_f")
        multipliers = ca.SX.sym("lam_g", nlp["g"].numel())
        hessian = objective_factor * (2.0 * self.objective_scale) * ca.mtimes(jacobian.T, jacobian)
        other_hessian, _ = ca.hessian(data.other_objective, nlp["x"])
        if other_hessian.nnz():  # expression costs (not least squares) keep their exact curvature
            hessian += objective_factor * self.objective_scale * other_hessian
        hessian += self.levenberg_marquardt * ca.DM.eye(nlp["x"].numel())
        return ca.Function(
            "nlp_hess_l",
            [nlp["x"], nlp["p"], objective_factor, multipliers],
            [hessian],
            ["x", "p", "lam_f", "lam_g"],
            ["hess_gamma_x_x"],
        )

    def robust_options(self) -> dict[str, Any]:
        """Plugin options of the last-resort retry after every other attempt failed (``{}``: none).

        Backends whose defaults are tuned for speed return their conservative settings here.
        An optional ``"plugin"`` key names a different ``casadi.nlpsol`` plugin for the retry;
        then only the remaining keys are its options (the backend's ``plugin_defaults`` and the
        user's ``plugin_options`` belong to the backend's own plugin and are not applied); the
        NLP it solves is the same, objective scaling (``objective_scale``) included.
        """
        return {}

    def rescue_options(self) -> dict[str, Any]:
        """Options (with a ``"plugin"`` key) of a retry by another plugin from the last iterate.

        Tried after every other attempt failed, or at once after an attempt that
        :meth:`stalled`; ``{}`` (the default): none.
        """
        return {}

    def stalled(self, attempt: Attempt, p: np.ndarray) -> bool:
        """Whether a failed ``attempt`` stalled next to a solution (default: never).

        A backend with a rescue (:meth:`rescue_options`) that says so hands that attempt's
        iterate to the rescue at once, instead of running the rest of its fallback chain first.
        """
        return False

    def _judged(
        self, attempt: Attempt, p: np.ndarray, relaxed: bool | None = None
    ) -> tuple[Iterate, float, float]:
        """Return ``attempt``'s plan and warm start, and the judge's cost and violation of the plan."""
        if relaxed is None:
            relaxed = self.relaxed(attempt.variant, attempt.primal)
        iterate = self.plan_iterate(attempt.variant, attempt.primal, attempt.lam_g, attempt.lam_x, relaxed)
        cost, violation = score_parameters(self.problem, iterate.scaled_controls.ravel(), p, self.judge_terms)
        return iterate, cost, violation

    def _transfer_maps(self, source: str, target: str) -> tuple[np.ndarray, np.ndarray]:
        """Index maps moving primal and dual vectors from one NLP variant to another (cached)."""
        key = ("transfer", source, target)
        if key not in self._maps:
            a, b = self.variants[source], self.variants[target]
            self._maps[key] = (
                transfer_map(a.variable_keys, b.variable_keys),
                transfer_map(a.constraint_keys, b.constraint_keys),
            )
        maps: tuple[np.ndarray, np.ndarray] = self._maps[key]
        return maps

    def plan_iterate(
        self, variant: str, primal: np.ndarray, lam_g: np.ndarray, lam_x: np.ndarray, relaxed: bool
    ) -> Iterate:
        """Return the plan and warm start of a solution ``primal`` of ``variant`` (NLP multipliers).

        Interior-point plugins relax bounds by ~1e-8 (IPOPT's ``bound_relax_factor``): the plan
        holds the control box exactly, so the applied control never leaves it.
        """
        data = self.variants[variant]
        box = self._control_box.get(variant)
        if box is None:  # the variant's control bounds, gathered once
            box = self._control_box[variant] = (data.lbx[data.control_index], data.ubx[data.control_index])
        return Iterate(
            scaled_controls=np.clip(primal[data.control_index], *box),
            states=primal[data.state_index],
            primal=primal,
            lam_g=lam_g,
            lam_x=lam_x,
            variant=variant,
            terminal_relaxed=relaxed,
            primal_shift=data.primal_shift,
            constraint_shift=data.constraint_shift,
        )

    def _iterate_of(self, attempt: Attempt) -> Iterate:
        """Warm start carrying an attempt's primal and dual vectors, in its variant's layout."""
        data = self.variants[attempt.variant]
        primal = attempt.primal
        return Iterate(
            scaled_controls=primal[data.control_index],
            states=primal[data.state_index],
            primal=primal,
            lam_g=attempt.lam_g,
            lam_x=attempt.lam_x,
            variant=attempt.variant,
        )

    def _uses_still_water(self, p: np.ndarray) -> bool:
        """Whether the instance ``p`` is solved with the still-water NLP (see class notes)."""
        part = self._still_water_slice
        return self.still_water and part is not None and not p[part].any()

    def _still_water_nlp(self, data: NlpData) -> dict[str, ca.SX]:
        """``data.nlp`` with the current parameters replaced by zero (CasADi simplifies)."""
        part = self._still_water_slice
        assert part is not None, "only called where _uses_still_water(p) holds"
        current = data.nlp["p"][part]
        zero = ca.DM.zeros(current.numel())
        f, g = ca.substitute([data.nlp["f"], data.nlp["g"]], [current], [zero])
        return {**data.nlp, "f": f, "g": g}

    def _solver(
        self, variant: str, stage: Stage = Stage.PLAIN, still_water: bool = False
    ) -> BufferedFunction:
        """Return the variant's ``nlpsol``, called zero-copy (no numpy -> DM conversions per step)."""
        solver = self._solvers.get((variant, stage, still_water))
        if solver is None:
            with BUILD_LOCK:  # nlpsol, its JIT and callbacks build CasADi objects (uuv_ocp._concurrency)
                solver = self._built_solver(variant, stage, still_water)
        return solver

    def _built_solver(
        self, variant: str, stage: Stage = Stage.PLAIN, still_water: bool = False
    ) -> BufferedFunction:
        """Build (once) and return :meth:`_solver`'s ``nlpsol``; under the package's build lock."""
        key = (variant, stage, still_water)
        if key not in self._solvers:
            data = self.variants[variant]
            # ad_weight 1: constraint Jacobians by reverse-mode AD, fewer virtual-machine
            # instructions than CasADi's automatic choice on these stagewise NLPs, same values
            # (docs/solvers.md, "ad_weight")
            options: dict[str, Any] = {
                "print_time": False,
                "error_on_fail": False,
                "oracle_options": {"ad_weight": 1.0},
            }
            if stage is Stage.RESCUE:
                robust_options = dict(self.rescue_options())
            else:
                robust_options = dict(self.robust_options()) if stage is Stage.ROBUST else {}
            plugin = robust_options.pop("plugin", self.plugin)
            if plugin == self.plugin:
                options.update(self.plugin_defaults(data))
                options.update(robust_options)
                options.update(self.plugin_options)
            else:
                options.update(robust_options)
            nlp = self._still_water_nlp(data) if still_water else dict(data.nlp)
            nlp["f"] = nlp["f"] * self.objective_scale
            suffix = "" if stage is Stage.PLAIN else f"_{stage.value}"
            water = "_still_water" if still_water else ""
            name = f"{plugin}_{variant}{suffix}{water}"
            if self.deadline is not None and plugin in CALLBACK_PLUGINS:
                sizes = (nlp["x"].numel(), nlp["g"].numel(), nlp["p"].numel())
                callback = _DeadlineCallback(f"{name}_deadline", sizes, self._clock)
                self._deadline_callbacks.append(callback)
                options["iteration_callback"] = callback
            if self.watched(plugin) and self.progress_lines(plugin):
                # the watchdog reads the plugin's iteration lines as its progress report
                options.update(self.progress_lines(plugin))
            if self.compiled:
                stages = ([key[1] for key in data.variable_keys], [key[1] for key in data.constraint_keys])
                # one library per plugin and NLP: a robust retry of the same plugin differs
                # only in options, so it loads the plain attempt's library (no second compile)
                library = f"{plugin}_{variant}{water}"
                solver = self._compiled_nlpsol(name, plugin, nlp, options, stages, library)
            else:
                solver = ca.nlpsol(name, plugin, nlp, options)
            self._solvers[key] = BufferedFunction(solver)
            self._plugins[key] = plugin
            if self._worker.alive:  # a worker forked before this build would build it again
                self._worker.restart()
        return self._solvers[key]

    def build(self, p: np.ndarray | None = None) -> None:
        """Build every ``nlpsol`` the fallback chain can use, so that no solve builds one.

        A solve builds what it needs on first use (0.1-0.5 s per plugin, outside its deadline:
        see "Deadlines"); a real-time loop calls this before its first step instead.  ``p``:
        build only the NLPs of that instance (still water or not); ``None``: both.
        """
        if p is not None:
            flags = [self._uses_still_water(p)]
        else:
            flags = [False] + ([True] if self.still_water and self._still_water_slice is not None else [])
        stages = [Stage.PLAIN]
        if self.robust_options():
            stages.append(Stage.ROBUST)
        if self.rescue_options():
            stages.append(Stage.RESCUE)
        for stage in stages:
            if not _is_nlpsol(self._stage_plugin(stage)):  # sqp-rti's own step is no nlpsol
                continue
            for still_water in flags:
                for variant in self.variants:
                    self._solver(variant, stage, still_water)

    def _stage_plugin(self, stage: Stage) -> str:
        """Return the plugin of an attempt: the backend's, or its robust retry's or rescue's own."""
        if stage is Stage.RESCUE:
            return str(self.rescue_options().get("plugin", self.plugin))
        if stage is Stage.ROBUST:
            return str(self.robust_options().get("plugin", self.plugin))
        return self.plugin

    def watched(self, plugin: str) -> bool:
        """Whether an attempt of ``plugin`` runs in the watchdog's worker process.

        Plugins that call CasADi's iteration callback stop themselves at the deadline; the
        others run in the worker when this solver has a ``deadline`` (backends whose plugin can
        hang without one, fatrop, say so always).  Never where ``os.fork`` is missing.
        """
        return watchdog.CAN_WATCH and plugin not in CALLBACK_PLUGINS and self.deadline is not None

    def progress_lines(self, plugin: str) -> dict[str, Any]:
        """Plugin options that print one line per iteration (the watchdog's progress; ``{}``: none)."""
        return {}

    def stall_limit(self, plugin: str) -> float | None:
        """Seconds without an iteration line after which a watched attempt is stalled (``None``: never)."""
        return None

    def iteration_limit(self, plugin: str) -> int | None:
        """Return the iterations (restoration included) after which the watchdog stops ``plugin``.

        ``None``: the plugin's own limit only.
        """
        return None

    def _compiled_nlpsol(
        self,
        name: str,
        plugin: str,
        nlp: dict,
        options: dict,
        stages: tuple[list[int | None], list[int | None]],
        library_name: str | None = None,
    ) -> ca.Function:
        """``nlpsol`` on the NLP functions compiled to C, cached by content; VM if that fails.

        See :func:`uuv_ocp.native.runtime.compiled_nlpsol`: the library is built once per NLP
        content (and compiler, flags, versions) in the solvers' cache, checksummed and verified;
        later processes load it without compiling.  ``stages``: the stage of every variable and
        row (their keys'), by which the NLP is outlined (one C function per stage structure);
        ``library_name``: the library's name (``compiled_nlpsol``), ``name`` if not given.
        """
        try:
            return compiled_nlpsol(name, plugin, nlp, options, *stages, library_name=library_name)[0]
        except (CodegenError, OSError, RuntimeError) as error:
            warnings.warn(
                f"compiled=True unavailable for {self.name} ({error}); using CasADi's virtual machine",
                RuntimeWarning,
                stacklevel=4,
            )
            self.compiled = False
            return ca.nlpsol(name, plugin, nlp, options)

    def compose_primal(
        self, variant: str, states: np.ndarray, scaled: np.ndarray, scaled_prev: np.ndarray
    ) -> np.ndarray:
        """NLP primal vector of ``variant`` from a plan (slacks start at zero)."""
        data = self.variants[variant]
        primal = np.zeros(len(data.variable_keys))
        lifted = data.lifted_index
        primal[lifted[:, : self._state_dim]] = states
        if self._lifted:
            primal[lifted[:, self._state_dim :]] = np.vstack([scaled_prev[None, :], scaled])
        primal[data.control_index] = scaled
        if data.interval_index.size:  # e.g. collocation states: the strategy's own guess
            spec = self.problem.spec()
            primal[data.interval_index] = transcription(spec.transcription).interval_guess(spec, states)
        return primal

    def _initial_point(self, variant: str, p: np.ndarray, warm_start: Iterate | None) -> tuple:
        problem = self.problem
        if warm_start is None:
            states, scaled = problem.initial_guess(p)
            return self.compose_primal(variant, states, scaled, problem.previous_scaled(p)), None, None
        if warm_start.primal is not None and warm_start.variant in self.variants:
            if warm_start.variant == variant:
                return warm_start.primal, warm_start.lam_g, warm_start.lam_x
            x_map, g_map = self._transfer_maps(warm_start.variant, variant)
            return (
                _transfer(warm_start.primal, x_map),
                _transfer(warm_start.lam_g, g_map),
                _transfer(warm_start.lam_x, x_map),
            )
        scaled_prev = problem.previous_scaled(p)
        primal = self.compose_primal(variant, warm_start.states, warm_start.scaled_controls, scaled_prev)
        return primal, None, None

    def _attempt(
        self, variant: Variant, p: np.ndarray, warm_start: Iterate | None, stage: Stage = Stage.PLAIN
    ) -> Attempt:
        """Run one attempt of the fallback chain: ``variant`` from ``warm_start`` with ``stage``'s settings.

        The seam of an exact backend that is not a CasADi ``nlpsol`` (docs/solvers.md): it
        starts from :meth:`_initial_point`, stops at ``self._clock.at``
        (:func:`~uuv_ocp.solvers.watchdog.now` time) and never raises on a solver failure.
        """
        data = self.variants[variant]
        primal, lam_g, lam_x = self._initial_point(variant, p, warm_start)
        if not self.uses_duals or lam_g is None:
            lam_g = np.zeros(data.lbg.size)
        if not self.uses_duals or lam_x is None:
            lam_x = np.zeros(data.lbx.size)
        still_water = self._uses_still_water(p)
        solver = self._solver(variant, stage, still_water)
        scale = self.objective_scale
        self._clock.fired = False
        start = watchdog.now()
        key = (variant, stage, still_water)
        plugin = self._plugins[key]
        # nlpsol inputs in order: x0, p, lbx, ubx, lbg, ubg, lam_x0, lam_g0 (zero = CasADi's default)
        args = (primal, p, data.lbx, data.ubx, data.lbg, data.ubg, lam_x * scale, lam_g * scale)
        watched = self.watched(plugin)
        killed: watchdog.Stopped | watchdog.CrashedWorker | None = None
        if watched:
            try:
                outputs, stats = self._worker.call(
                    key,
                    args,
                    at=self._clock.at,
                    max_iter=self.iteration_limit(plugin),
                    stall=self.stall_limit(plugin),
                )
            except (watchdog.Stopped, watchdog.CrashedWorker) as error:
                killed = error
                outputs, stats = list(args[:1]) + [None, None, args[6], args[7], None], {}
        else:
            outputs, stats = solver(*args), None
        new_primal, _, _, new_lam_x, new_lam_g, _ = outputs
        plugin_time = watchdog.now() - start
        if stats is None:
            stats = solver.stats()
        status = plugin_status(plugin, stats)
        iterations = int(stats.get("iter_count", 0) or 0)
        # the deadline callback's stop is reported as a user stop: not a Ctrl-C
        stopped = self._clock.fired or status in _TIME_LIMIT_STATUSES
        if isinstance(killed, watchdog.Stopped):
            stopped = killed.reason == "deadline"
            status, iterations = str(killed), killed.iterations
        elif killed is not None:
            status = f"{plugin} crashed ({killed})"
        elif not self._clock.fired:
            reraise_interrupt(status)  # Ctrl-C inside the plugin
        if stopped:
            status = f"stopped by the deadline ({status})"
        success = bool(stats.get("success", False)) and not stopped and killed is None
        if not (np.all(np.isfinite(new_primal)) and np.all(np.isfinite(new_lam_g))):
            # a NaN iterate is no plan and no warm start: the attempt's starting point stands
            status, success = f"{status}; NaN or Inf in the returned iterate", False
            new_primal, new_lam_x, new_lam_g = args[0], args[6], args[7]
        return Attempt(
            variant=variant,
            stage=stage,
            still_water=still_water,
            primal=new_primal,
            lam_g=new_lam_g / scale,
            lam_x=new_lam_x / scale,
            success=success,
            status=status,
            iterations=iterations,
            evaluations=int(stats.get("n_call_nlp_f", 0) or stats.get("n_call_nlp_fg", 0) or 0),
            solver_time=plugin_time,
            watched=watched,
        )

    def relaxed(self, variant: str, primal: np.ndarray) -> bool:
        """Whether ``primal`` of ``variant`` needed the exact-penalty relaxation (slack > tolerance)."""
        index = self.variants[variant].terminal_slack_index
        return variant != HARD and bool(index.size) and float(np.max(primal[index])) > self.slack_tolerance

    def share_cold_retries(self, retries: ColdRetries | None) -> None:
        """Reuse the cold retries of ``retries`` in the next solves (``None``: stop; :class:`ColdRetries`)."""
        self._cold_retries = retries

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
    ) -> SolveResult:
        """Solve the instance with parameter vector ``p`` (see ``Ocp.parameters``).

        ``rng`` is accepted for a uniform backend interface and ignored (exact solvers are
        deterministic).  ``time_limit`` (seconds from the call) replaces the ``deadline``
        option for this call (a hybrid gives its exact stage what its swarm left); inside an
        attempt it is enforced only if the solver was built with a ``deadline`` (that is what
        installs the plugins' iteration callback), between attempts always.
        """
        start = watchdog.now()
        limit = self.deadline if time_limit is None else check.positive_float("time_limit", time_limit)
        self._clock.at = math.inf if limit is None else start + limit
        chain = _Chain(p)
        strategy = self.terminal_strategy if SOFT in self.variants else "hard-first"
        soft_variant = self._open_chain(chain, warm_start, strategy)
        self._escalate(chain, warm_start, soft_variant)
        self._last_resorts(chain, warm_start)
        self._clock.at = math.inf
        return self._chain_result(chain, start, limit, strategy)

    def _chain_attempt(
        self, chain: _Chain, variant: Variant, warm: Iterate | None, stage: Stage = Stage.PLAIN
    ) -> bool:
        """Run one attempt unless the deadline has passed (the first one always runs)."""
        if chain.attempts and watchdog.now() >= self._clock.at:
            chain.skipped += 1
            return False
        key = (variant, stage, self._uses_still_water(chain.p))
        if key not in self._solvers and _is_nlpsol(self._stage_plugin(stage)):
            # building a plugin (0.1-0.5 s, once) is no part of the budget: the clock waits
            built = watchdog.now()
            self._solver(*key)
            spent = watchdog.now() - built
            chain.build_time += spent
            self._clock.at += spent
        shared = self._cold_retries
        if shared is not None and warm is None and stage is Stage.PLAIN and math.isinf(self._clock.at):
            # the cold retry of an instance is one attempt whichever start failed before it
            # a backend with other settings (a hybrid's class_exact) runs another attempt
            settings = f"{type(self).__qualname__} {self.settings!r}"
            memo = (settings, str(variant), key[2], np.asarray(chain.p, dtype=float).tobytes())
            attempt = shared.attempts.get(memo)
            if attempt is None:
                attempt = shared.attempts[memo] = self._attempt(variant, chain.p, warm, stage)
            else:
                shared.reused += 1
            chain.attempts.append(attempt)
        else:
            chain.attempts.append(self._attempt(variant, chain.p, warm, stage))
        failed = not chain.last.success and stage is not Stage.RESCUE
        if failed and self.stalled(chain.last, chain.p) and self.rescue_options():
            # stuck next to a solution: the rest of the chain would stall the same way
            self._chain_attempt(chain, variant, self._iterate_of(chain.last), Stage.RESCUE)
        return True

    def _open_chain(self, chain: _Chain, warm_start: Iterate | None, strategy: str) -> Variant:
        """Run the chain's first attempts (hard or soft, then the cold retry); return the soft variant."""
        soft_first = strategy == "soft" or (
            strategy == "sticky" and warm_start is not None and warm_start.terminal_relaxed
        )
        soft_variant = SOFT
        if soft_first and warm_start is not None and warm_start.variant in self._escalations:
            soft_variant = Variant(warm_start.variant)  # stay at the escalated penalty while relaxed
        if soft_first:
            self._chain_attempt(chain, soft_variant, warm_start)
        else:
            self._chain_attempt(chain, HARD, warm_start)
            if not chain.last.success and SOFT in self.variants:
                self._chain_attempt(chain, SOFT, warm_start)
        if not chain.last.success and warm_start is not None:
            # A warm start can sit in a bad region (e.g. after a burst of saturation): one
            # retry from the reference-based cold guess, same NLP variant.
            self._chain_attempt(chain, chain.last.variant, None)
        return soft_variant

    def _escalate(self, chain: _Chain, warm_start: Iterate | None, soft_variant: Variant) -> None:
        """Raise the soft NLP's penalty, one escalation after another, while its attempts fail."""
        start_index = self._escalations.index(soft_variant) + 1 if soft_variant != SOFT else 0
        for variant in self._escalations[start_index:]:
            if chain.last.success or not chain.last.variant.soft:
                break
            # classic exact-penalty update: a larger ρ, warm-started from the closest iterate
            if not self._chain_attempt(chain, variant, warm_start):
                break

    def _last_resorts(self, chain: _Chain, warm_start: Iterate | None) -> None:
        """Run the robust retry, then the rescue, each only if the chain has failed so far."""
        if not chain.last.success and self.robust_options():
            # last resort: the same NLP with the backend's conservative settings
            self._chain_attempt(chain, chain.last.variant, warm_start, Stage.ROBUST)
        if not chain.last.success and self.rescue_options():
            # a backend that stalls near a solution (fatrop under inertia correction on
            # non-convex constraints) hands its last iterate, duals included, to another plugin
            self._chain_attempt(chain, chain.last.variant, self._iterate_of(chain.last), Stage.RESCUE)

    def _chain_result(self, chain: _Chain, start: float, limit: float | None, strategy: str) -> SolveResult:
        """Return the result of the chain's last attempt; a failure if it was not ready by ``limit``."""
        final = chain.last
        relaxed = self.relaxed(final.variant, final.primal)
        elapsed = watchdog.now() - start
        late = limit is not None and elapsed - chain.build_time > limit
        result = self._result(
            chain.p,
            final,
            chain.attempts,
            relaxed,
            elapsed,
            deadline_hit=late,
            build_time=chain.build_time or None,
        )
        if not late:
            return result if result.success else self._rolled_out(result, chain.p)
        return self._late_result(chain, result, limit, elapsed - chain.build_time, strategy)

    def _late_result(
        self, chain: _Chain, result: SolveResult, limit: float | None, elapsed: float, strategy: str
    ) -> SolveResult:
        """Return ``result`` as a failure: not ready in time, whatever its last attempt reached."""
        skipped = chain.skipped
        reason = f"{skipped} further attempt(s) not started" if skipped else "no attempt skipped"
        iterate = result.iterate
        if strategy == "sticky" and SOFT in self.variants and chain.last.variant == HARD:
            # a warm start from this iterate (a closed loop keeps it) goes to the soft NLP, which
            # is always feasible: a hard NLP that never finishes in time would never yield to it
            iterate = dataclasses.replace(iterate, terminal_relaxed=True)
        return dataclasses.replace(
            self._rolled_out(result, chain.p),
            success=False,
            iterate=iterate,
            status=(
                f"deadline: {limit:g} s exceeded ({elapsed:.3g} s, {len(chain.attempts)} attempt(s), "
                f"{reason}); last attempt: {result.status}"
            ),
            details=result.details.replace(attempts_skipped=skipped),
        )

    def _rolled_out(self, result: SolveResult, p: np.ndarray) -> SolveResult:
        """Return ``result`` with ``states`` the rollout of its ``controls`` (for a failed solve).

        A failed attempt's NLP states need not satisfy the dynamics (multiple shooting closes
        the gaps only at convergence); ``SolveResult.states`` promises the states under
        ``controls``, which the judge's cost is computed on.  The iterate keeps the NLP's own
        states: it is the warm start of the next solve.
        """
        states = self.problem.rollout_scaled(result.iterate.scaled_controls.ravel(), p)
        return dataclasses.replace(result, states=states)

    def _result(
        self,
        p: np.ndarray,
        final: Attempt,
        attempts: list[Attempt],
        relaxed: bool,
        elapsed: float,
        **details: Any,
    ) -> SolveResult:
        """Return the result of a solve whose last attempt is ``final`` (``details``: more fields)."""
        problem = self.problem
        iterate, cost, violation = self._judged(final, p, relaxed)
        scaled, states = iterate.scaled_controls, iterate.states
        status = final.status
        if final.variant.soft:
            status = f"soft_terminal: {status}" if relaxed else f"soft_terminal_held: {status}"
        return SolveResult(
            solver=self.name,
            controls=problem.controls_from_scaled(scaled),
            states=states,
            cost=cost,
            max_violation=violation,
            success=final.success,
            status=status,
            solve_time=elapsed,
            iterations=sum(a.iterations for a in attempts),
            evaluations=sum(a.evaluations for a in attempts),
            terminal_relaxed=relaxed,
            iterate=iterate,
            details=SolveDetails(
                attempts=tuple(a.summary() for a in attempts),
                plugin_time=sum(a.solver_time for a in attempts),
                still_water=final.still_water,
                **details,
            ),
        )
