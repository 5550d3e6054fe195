"""Multi-start exact solver: ``"multistart-<exact>"``, e.g. ``"multistart-ipopt"``.

The strongest plain alternative to a metaheuristic warm start: the exact backend solved from
``K`` initial guesses (option ``starts``, default 8), the best result returned.  The guesses,
in this order (the first ``K`` are used):

1. ``"default"``: the caller's warm start (a closed loop's shifted plan, with its duals and
   terminal strategy), or the problem's own cold guess when there is none — what the plain
   exact backend would solve;
2. ``"held"``: the last applied control held over the horizon, with the states of its rollout;
3. ``"+50% <control>[i]"`` / ``"-50% <control>[i]"`` for every control component ``i``: that
   component constant at the middle of the upper (lower) half of its box (scaled ``±0.5``),
   the others held — on a planar problem with obstacles, the lateral ones steer the path left
   and right of everything;
4. ``"random j"``: random plans in the box: ``min(N, 4)`` knots uniform in the box,
   interpolated linearly over the horizon (smooth, so each one is a path of its own rather
   than noise), from the caller's ``rng`` (a closed loop's generator) or
   ``numpy.random.default_rng(seed)`` per solve (option ``seed``, default 0).

Every plan is projected on the control box and the rate bound (the decode map of
:mod:`uuv_ocp.transcription.condensed`) and carries the warm start's terminal strategy
(``terminal_relaxed`` and the NLP variant, so a sticky soft start is kept).  Each start is an
independent solve of the exact backend (its own fallbacks included); the result is the best
by :func:`rank_key` — feasible (``success``) first, then a relaxed terminal last, then the
cost from :func:`uuv_ocp.score` — with ``solve_time``, ``iterations`` and ``evaluations`` summed
over the starts and ``details["starts"]`` listing every start's label, cost, violation,
success, status and time.

Option ``deadline`` (seconds, finite > 0): the wall-time budget of the whole multi-start solve.
Each start gets what is left of it (``solve(..., time_limit=)``; the exact backend is built with
``deadline`` too, so its in-attempt stops are active), no start begins after it, and the best
result of the starts that ran is returned — a plan that a start finished in time stays usable,
so ``success`` is the chosen start's own.  ``details["deadline_hit"]`` says whether the deadline
stopped a start or kept one from starting, or the solve outlasted it;
``details["starts_skipped"]`` counts the starts that did not begin.

Naming: ``multistart-<name>`` exists for every backend registered with ``kind="exact"``
(plug-ins included) and is resolved by the registry like a hybrid name.  It is not itself
registered as an exact backend, so ``"<swarm>+multistart-<exact>"`` hybrids are not offered.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.solvers import watchdog
from uuv_ocp.solvers.base import check_backend, takes_time_limit
from uuv_ocp.solvers.options import (
    Option,
    declaration,
    mapping,
    option,
    optional,
    parse_options,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Iterate, SolveDetails, SolveResult
from uuv_ocp.transcription.condensed import encode

DEFAULT_STARTS = 8
STRUCTURED_LEVEL = 0.5  # scaled control of the "±50 %" starts
RANDOM_KNOTS = 4


def _seed(label: str, value: object) -> int:
    return check.positive_int(label, value, minimum=0)


@dataclasses.dataclass(frozen=True)
class MultistartOptions:
    """Options of every ``"multistart-<exact>"`` backend."""

    starts: int = option(
        DEFAULT_STARTS,
        "int >= 1",
        "number of initial guesses K (the first K of the list above)",
        check=positive_int,
    )
    seed: int = option(
        0, "int >= 0", "seed of the random starts when the caller passes no generator", check=_seed
    )
    exact: dict | None = option(
        None,
        "dict or `None`",
        "options of the exact backend",
        meaning="its defaults",
        check=optional(mapping),
    )
    deadline: float | None = option(
        None,
        "float > 0 or `None`",
        "wall-time budget of the whole solve; no start begins after it",
        unit="s",
        meaning="none",
        check=optional(positive_float),
    )


MULTISTART_OPTIONS: tuple[Option, ...] = declaration(MultistartOptions)
"""Rows of :class:`MultistartOptions` (the docs' table)."""


def rank_key(result: SolveResult) -> tuple[int, int, float]:
    """Sort key of results of one instance: feasible first, relaxed terminal later, then cost.

    Infeasible results (``success=False``) rank after every feasible one, among themselves by
    their largest violation.
    """
    if not result.success:
        violation = result.max_violation if np.isfinite(result.max_violation) else np.inf
        return (1, 1, float(violation))
    cost = result.cost if np.isfinite(result.cost) else np.inf
    return (0, int(result.terminal_relaxed), float(cost))


def best_result(results: Sequence[SolveResult]) -> int:
    """Index of the best of ``results`` by :func:`rank_key` (the first of equals)."""
    if not results:
        raise ValueError("best_result needs at least one result")
    keys = [rank_key(result) for result in results]
    return min(range(len(keys)), key=keys.__getitem__)


def plan_guess(
    problem: Transcribed,
    scaled: np.ndarray,
    p: np.ndarray,
    warm_start: Iterate | None = None,
    decode: BufferedFunction | None = None,
) -> Iterate:
    """Build an exact solver's initial guess from a scaled plan (N, nu): the plan and its rollout.

    The plan is projected on the box and the rate bound first; the warm start's terminal
    strategy (``terminal_relaxed``, ``variant``) is carried over.
    """
    spec = problem.spec()
    coordinates = encode(spec, scaled, problem.previous_scaled(p))
    (flat,) = (decode or BufferedFunction(problem.build().decode))(coordinates, p)
    states = problem.rollout_scaled(flat, p)
    return Iterate(
        scaled_controls=flat.reshape(spec.horizon, spec.control_size),
        states=states,
        variant=warm_start.variant if warm_start is not None else "hard",
        terminal_relaxed=warm_start.terminal_relaxed if warm_start is not None else False,
    )


class MultistartSolver:
    """Solve with ``exact`` from several guesses and keep the best (see the module notes).

    Parameters
    ----------
    name : str
        Registered name, ``"multistart-<exact>"``.
    problem : Ocp or TrackingProblem
    exact : backend
        The exact backend instance (built once, reused by every start).
    starts : int
        Number of starts K >= 1 (default 8).
    seed : int
        Seed of the random starts when the caller passes no generator (default 0).
    deadline : float or None
        Wall-time budget of a solve in seconds (see the module notes).
    """

    def __init__(
        self,
        name: str,
        problem: Transcribed,
        exact: Any,
        starts: int,
        seed: int,
        deadline: float | None = None,
    ) -> None:
        self.name = name
        self.deadline = deadline
        self.problem = problem
        self.exact = exact
        self.starts = starts
        self.seed = seed
        self._decode = BufferedFunction(problem.build().decode)
        spec = problem.spec()
        if not (np.all(np.isfinite(spec.lower)) and np.all(np.isfinite(spec.upper))):
            self._boxed = False  # no box: the ±50 % and random starts have no meaning
        else:
            self._boxed = True

    def guesses(
        self, p: np.ndarray, warm_start: Iterate | None, rng: np.random.Generator | None
    ) -> list[tuple[str, Iterate | None]]:
        """Return the labelled initial guesses of one solve (the first ``starts`` of the list)."""
        problem, spec = self.problem, self.problem.spec()
        n, nu = spec.horizon, spec.control_size
        previous = problem.previous_scaled(p)
        out: list[tuple[str, Iterate | None]] = [("default", warm_start)]

        def add(label: str, plan: np.ndarray) -> None:
            if len(out) < self.starts:
                out.append((label, plan_guess(problem, plan, p, warm_start, self._decode)))

        add("held", np.tile(previous, (n, 1)))
        names = [f"u[{i}]" for i in range(nu)]
        names = _component_names(problem, nu) or names
        if self._boxed:
            for i in range(nu):
                for sign, text in ((1.0, "+50%"), (-1.0, "-50%")):
                    plan = np.tile(previous, (n, 1))
                    plan[:, i] = sign * STRUCTURED_LEVEL
                    add(f"{text} {names[i]}", plan)
            generator = rng if rng is not None else np.random.default_rng(self.seed)
            knots = min(n, RANDOM_KNOTS)
            j = 0
            while len(out) < self.starts:
                values = generator.uniform(spec.scaled_lower, spec.scaled_upper, size=(knots, nu))
                where = np.linspace(0.0, 1.0, knots)
                grid = np.linspace(0.0, 1.0, n)
                plan = np.column_stack([np.interp(grid, where, values[:, i]) for i in range(nu)])
                add(f"random {j}", plan)
                j += 1
        return out[: self.starts]

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
    ) -> SolveResult:
        """Solve from every start; return the best (feasible first, then cost)."""
        start = watchdog.now()
        results: list[SolveResult] = []
        rows: list[dict[str, Any]] = []
        deadline = self.deadline
        guesses = self.guesses(p, warm_start, rng)
        for label, guess in guesses:
            if deadline is None:
                result = self.exact.solve(p, guess)
            else:
                remaining = deadline - (watchdog.now() - start)
                if remaining <= 0.0 and results:  # no start begins after the deadline
                    break
                result = self.exact.solve(p, guess, time_limit=max(remaining, 1e-9))
            results.append(result)
            rows.append(
                {
                    "start": label,
                    "cost": result.cost,
                    "max_violation": result.max_violation,
                    "success": result.success,
                    "terminal_relaxed": result.terminal_relaxed,
                    "status": result.status,
                    "time": result.solve_time,
                }
            )
        chosen = best_result(results)
        best = results[chosen]
        details = dict(best.details)
        details.update({"starts": rows, "chosen": rows[chosen]["start"]})
        if deadline is not None:
            skipped = len(guesses) - len(results)
            stopped = any(r.details.get("deadline_hit", False) for r in results)
            late = watchdog.now() - start > deadline
            details.update({"deadline_hit": bool(stopped or skipped or late), "starts_skipped": skipped})
        return dataclasses.replace(
            best,
            solver=self.name,
            solve_time=watchdog.now() - start,
            iterations=sum(r.iterations for r in results),
            evaluations=sum(r.evaluations for r in results),
            details=SolveDetails.of(details),
        )


def _component_names(problem: Transcribed, nu: int) -> list[str] | None:
    """``name[i]`` labels of the scalar controls of an Ocp (``None`` if unknown)."""
    ocp = getattr(problem, "ocp", problem)
    controls = getattr(ocp, "_controls", None)
    if not controls:
        return None
    labels = [d.name if d.size == 1 else f"{d.name}[{i}]" for d in controls for i in range(d.size)]
    return labels if len(labels) == nu else None


def multistart_factory(name: str, exact: Callable) -> Callable:
    """Registry factory for ``"multistart-<exact>"``.

    Options: ``starts`` (int >= 1, default 8), ``seed`` (int >= 0, default 0), ``exact``
    (a dict passed to the exact backend) and ``deadline`` (seconds, see the module notes).
    """

    def factory(problem: Transcribed, options: dict[str, Any] | None = None) -> MultistartSolver:
        settings = parse_options(MultistartOptions, options, name)
        starts, seed, exact_options = settings.starts, settings.seed, settings.exact
        deadline = settings.deadline
        if deadline is not None:
            # built with the deadline: the exact backend's in-attempt stops (iteration callback)
            exact_options = {"deadline": deadline, **(exact_options or {})}
        backend = exact(problem, exact_options)
        check_backend(backend, name.removeprefix("multistart-"))
        if deadline is not None and not takes_time_limit(backend):
            raise ValueError(
                f"options['deadline'] of {name!r} needs an exact backend that accepts "
                f"solve(..., time_limit=seconds) (time_limited = True); {type(backend).__name__} does not"
            )
        return MultistartSolver(name, problem, backend, starts, seed, deadline)

    factory.Options = MultistartOptions  # type: ignore[attr-defined]  # what parse_options reads
    factory.OPTIONS = MULTISTART_OPTIONS  # type: ignore[attr-defined]  # the declaration the docs read
    return factory
