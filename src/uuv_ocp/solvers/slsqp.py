"""SLSQP backend: the multiple-shooting NLP solved by ``scipy.optimize.minimize(method="SLSQP")``.

The example of an exact backend that is not a CasADi ``nlpsol`` (docs/solvers.md, "Adding an
exact backend"): it reuses :class:`~uuv_ocp.solvers.nlp.NlpSolver`'s fallback chain (hard →
soft → cold retry → penalty escalations), warm starts, deadline and judge, and implements one
attempt (:meth:`SlsqpSolver._attempt`) on the package's CasADi functions of the NLP: the
objective with its gradient and the constraints with their Jacobian, evaluated in ``float64``
and handed to scipy as dense arrays.  SLSQP is a dense method (an ``n × n`` quasi-Newton
matrix, ``n`` the number of decision variables): meant for small problems and as a reference,
not for the speed of the other backends.

``success`` is honest: SLSQP's own convergence *and* the plan judged feasible by
:func:`uuv_ocp.judge.score_terms` within :data:`~uuv_ocp.judge.FEASIBILITY_TOLERANCE` (the
terminal equality excepted on the soft NLP, whose relaxation the result reports as
``terminal_relaxed``).  SLSQP stops on a small change of the objective (``tol``), which can
happen before the constraints close; the judge catches that.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import casadi as ca
import numpy as np
import scipy.optimize

from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.judge import FEASIBILITY_TOLERANCE, score_terms
from uuv_ocp.solvers import watchdog
from uuv_ocp.solvers.base import reraise_interrupt
from uuv_ocp.solvers.nlp import ChainOptions, NlpSolver
from uuv_ocp.solvers.options import (
    Option,
    boolean,
    declaration,
    option,
    option_names,
    optional,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Attempt, Iterate, Stage, Variant
from uuv_ocp.transcription.multiple_shooting import NlpData

SLSQP_MAX_ITER = 200
"""SLSQP's iteration limit when ``max_iter`` is ``None``."""


@dataclasses.dataclass(frozen=True)
class SlsqpOptions(ChainOptions):
    """Options of :class:`SlsqpSolver`: the fallback chain's, ``still_water`` and SLSQP's ``tol``.

    No ``compiled`` and no ``plugin_options``: this backend has no CasADi plugin to compile or
    configure, so the parser refuses them rather than ignore them.
    """

    objective_scale: float = option(
        1e-3,
        "float > 0",
        "factor on the objective SLSQP sees (its absolute `tol` against the weights)",
        check=positive_float,
    )
    max_iter: int | None = option(
        None,
        "int >= 1 or `None`",
        "iteration limit of one attempt of SLSQP",
        meaning=f"{SLSQP_MAX_ITER} (scipy's `maxiter`)",
        check=optional(positive_int),
    )
    still_water: bool = option(
        True,
        "`True` or `False`",
        "solve the NLP specialised to zero current when the model's current is zero on the whole horizon",
        check=boolean,
    )
    tol: float = option(
        1e-11,
        "float > 0",
        "SLSQP's `ftol`: stop when the objective (times `objective_scale`) changes by less",
        check=positive_float,
    )


SLSQP_OPTIONS: tuple[Option, ...] = declaration(SlsqpOptions)


class _Oracle:
    """The NLP's functions of one variant as scipy calls them; each evaluated once per point."""

    def __init__(self, nlp: dict[str, ca.SX], scale: float, data: NlpData) -> None:
        x, p = nlp["x"], nlp["p"]
        f = nlp["f"] * scale
        self._f = ca.Function("slsqp_f", [x, p], [f, ca.gradient(f, x)])
        self._g = ca.Function("slsqp_g", [x, p], [nlp["g"], ca.jacobian(nlp["g"], x)])
        lower, upper = data.lbg, data.ubg
        equal = np.isfinite(lower) & (lower == upper)
        self.equality = np.flatnonzero(equal)
        self.lower = np.flatnonzero(np.isfinite(lower) & ~equal)  # g - lbg >= 0
        self.upper = np.flatnonzero(np.isfinite(upper) & ~equal)  # ubg - g >= 0
        self._lbg, self._ubg = lower, upper
        self.p = np.zeros(p.numel())
        self._at: bytes | None = None
        self._g_value = self._g_jacobian = np.zeros(0)

    def objective(self, w: np.ndarray) -> tuple[float, np.ndarray]:
        """Return the scaled objective and its gradient at ``w``."""
        value, gradient = self._f(w, self.p)
        return float(value), np.asarray(gradient).ravel()

    def _constraints(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # keyed on the instance too: a solve of another p may start where the last one stopped
        key = w.tobytes() + self.p.tobytes()
        if key != self._at:  # scipy asks for the equalities, then the inequalities, at one point
            value, jacobian = self._g(w, self.p)
            self._g_value, self._g_jacobian = np.asarray(value).ravel(), np.asarray(ca.densify(jacobian))
            self._at = key
        return self._g_value, self._g_jacobian

    def scipy_constraints(self) -> list[dict[str, Any]]:
        """Return the constraints in ``scipy.optimize.minimize``'s dict form (eq, then ineq)."""
        eq, lo, up = self.equality, self.lower, self.upper

        def equality(w: np.ndarray) -> np.ndarray:
            return self._constraints(w)[0][eq] - self._lbg[eq]

        def inequality(w: np.ndarray) -> np.ndarray:
            g = self._constraints(w)[0]
            return np.concatenate((g[lo] - self._lbg[lo], self._ubg[up] - g[up]))

        def inequality_jacobian(w: np.ndarray) -> np.ndarray:
            jacobian = self._constraints(w)[1]
            return np.vstack((jacobian[lo], -jacobian[up]))

        constraints = []
        if eq.size:
            constraints.append({"type": "eq", "fun": equality, "jac": lambda w: self._constraints(w)[1][eq]})
        if lo.size or up.size:
            constraints.append({"type": "ineq", "fun": inequality, "jac": inequality_jacobian})
        return constraints


class SlsqpSolver(NlpSolver):
    """The NLP solved by scipy's SLSQP (dense SQP, BFGS Hessian); see the module doc."""

    name = "slsqp"
    plugin = "slsqp"  # no CasADi nlpsol of this name: the chain builds no plugin for it
    uses_duals = False  # SLSQP takes no multipliers as a start
    Options = SlsqpOptions
    OPTIONS = SLSQP_OPTIONS
    option_names = option_names(SLSQP_OPTIONS)
    tol: float  # set from SlsqpOptions

    def __init__(self, problem: Any, options: dict[str, Any] | None = None) -> None:
        super().__init__(problem, options)
        self._oracles: dict[tuple[str, bool], _Oracle] = {}

    def _oracle(self, variant: str, still_water: bool) -> _Oracle:
        """Return (built once, under the package's build lock) the functions of ``variant``."""
        key = (variant, still_water)
        oracle = self._oracles.get(key)
        if oracle is None:
            with BUILD_LOCK:  # builds CasADi Functions (uuv_ocp._concurrency)
                data = self.variants[variant]
                nlp = self._still_water_nlp(data) if still_water else dict(data.nlp)
                oracle = self._oracles[key] = _Oracle(nlp, self.objective_scale, data)
        return oracle

    def _attempt(
        self, variant: Variant, p: np.ndarray, warm_start: Iterate | None, stage: Stage = Stage.PLAIN
    ) -> Attempt:
        """One SLSQP run on ``variant`` from :meth:`_initial_point`, stopped at the deadline."""
        data = self.variants[variant]
        still_water = self._uses_still_water(p)
        oracle = self._oracle(variant, still_water)
        oracle.p = np.asarray(p, dtype=float)
        primal = np.clip(
            np.asarray(self._initial_point(variant, p, warm_start)[0], float), data.lbx, data.ubx
        )
        clock = self._clock

        def callback(_: np.ndarray) -> None:
            if watchdog.now() >= clock.at:
                raise StopIteration  # scipy >= 1.11: ends the run with the last iterate

        start = watchdog.now()
        try:
            with warnings.catch_warnings():  # "Values in x were outside bounds": clipped below
                warnings.simplefilter("ignore", RuntimeWarning)
                outcome = scipy.optimize.minimize(
                    oracle.objective,
                    primal,
                    jac=True,
                    method="SLSQP",
                    bounds=scipy.optimize.Bounds(data.lbx, data.ubx),
                    constraints=oracle.scipy_constraints(),
                    callback=callback,
                    options={"maxiter": self.max_iter or SLSQP_MAX_ITER, "ftol": self.tol},
                )
        except (ValueError, ArithmeticError, RuntimeError) as error:  # a NaN in the model, say
            reraise_interrupt(error)
            return self._record(
                variant, stage, still_water, primal, False, f"SLSQP failed: {error}", 0, 0, start
            )
        new_primal = np.clip(np.asarray(outcome.x, dtype=float), data.lbx, data.ubx)
        status = str(outcome.message)
        stopped = watchdog.now() >= clock.at and not outcome.success
        if stopped:
            status = f"stopped by the deadline ({status})"
        if not np.all(np.isfinite(new_primal)):
            # a NaN iterate is no plan and no warm start: the attempt's starting point stands
            return self._record(variant, stage, still_water, primal, False, f"{status}; NaN", 0, 0, start)
        success = bool(outcome.success) and not stopped
        if success and not self._feasible(variant, new_primal, p):
            success, status = False, f"{status}, but the judge finds the plan infeasible"
        iterations, evaluations = int(outcome.get("nit", 0)), int(outcome.get("nfev", 0))
        return self._record(
            variant, stage, still_water, new_primal, success, status, iterations, evaluations, start
        )

    def _feasible(self, variant: Variant, primal: np.ndarray, p: np.ndarray) -> bool:
        """Whether the judge finds the plan feasible within :data:`~uuv_ocp.judge.FEASIBILITY_TOLERANCE`.

        On the soft NLP the terminal residual may be as large as the largest terminal slack
        (the relaxation the result reports), no larger: slacks SLSQP left short of the
        residual are an infeasible point, not a relaxed plan.
        """
        iterate = self.plan_iterate(variant, primal, np.zeros(0), np.zeros(0), False)
        _, kinds = score_terms(self.problem, iterate.scaled_controls.ravel(), p, self.judge_terms)
        slacks = self.variants[variant].terminal_slack_index
        allowed = float(np.max(primal[slacks])) if variant.soft and slacks.size else 0.0
        terminal = kinds.pop("terminal")
        return max(kinds.values()) <= FEASIBILITY_TOLERANCE and terminal <= allowed + FEASIBILITY_TOLERANCE

    def _record(
        self,
        variant: Variant,
        stage: Stage,
        still_water: bool,
        primal: np.ndarray,
        success: bool,
        status: str,
        iterations: int,
        evaluations: int,
        start: float,
    ) -> Attempt:
        data = self.variants[variant]
        return Attempt(
            variant=variant,
            stage=stage,
            still_water=still_water,
            primal=primal,
            lam_g=np.zeros(data.lbg.size),
            lam_x=np.zeros(data.lbx.size),
            success=success,
            status=status,
            iterations=iterations,
            evaluations=evaluations,
            solver_time=watchdog.now() - start,
        )
