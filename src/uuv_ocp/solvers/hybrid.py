"""Metaheuristic warm start of an exact solver: ``"<swarm>+<exact>"``, e.g. ``"igwo+ipopt"``.

The swarm runs first on the condensed cost; its best control sequence, with the states of its
rollout through the same RK4 model, becomes the exact solver's initial guess.  The exact
solver's result is returned (``solver="igwo+ipopt"``), with the swarm's evaluations added and
its best fitness in ``details["swarm_fitness"]``.  In a closed loop the next swarm is centred
on the exact solver's shifted plan.

The exact stage keeps its terminal strategy across steps: the guess built from the swarm's
plan carries the incoming warm start's ``terminal_relaxed`` and NLP ``variant``, so after a
relaxed step a ``"sticky"`` exact backend starts with the soft NLP, as it does on its own.

Option ``candidates=k`` (default 1): the exact solver starts from the swarm's best k distinct
plans (``details["candidates"]`` of the swarm, see :class:`~uuv_ocp.solvers.swarm.SwarmSolver`:
the best plan, then the best plans evaluated during the run whose predicted state trajectories
are farther than ``candidate_distance`` — an RMS distance, each state over its spread in the
initial population, default 0.5 — from every plan already taken) and the best result is
returned: feasible first, then the cost (:func:`~uuv_ocp.solvers.multistart.rank_key`).
With ``keep_warm_start=True`` (default) the second of the k starts is the caller's warm start
itself — the shifted plan in a closed loop, the straight-line guess on an obstacle field, or
the exact solver's own cold guess when there is none — in place of the swarm's k-th plan: the
hybrid then never returns a worse plan than the plain exact solver would from the same guess
(without a ``deadline``, which may stop the second start; and for exact solvers that keep no
state between calls)
(measured on the obstacle fields of ``benchmarks/bench_nonconvex.py``, the straight line is the
best homotopy class in about half the instances and the swarms' plans often miss it).
``details["candidates"]`` lists each start's origin (``"swarm 0"``, ``"warm start"``,
``"swarm 1"``, ...), swarm fitness, cost, success and status, ``details["chosen"]`` the index
of the one returned.  With k > 1 the swarm half must accept the ``candidates`` and
``candidate_distance`` options (the built-in swarms do).

Option ``skip_swarm_class`` (default True): the class starts (option ``classes``, see
:mod:`~uuv_ocp.solvers.homotopy`) whose guess passes every obstacle on the side the exact solve
from the swarm's plan converged to (:func:`~uuv_ocp.solvers.homotopy.sides`) are not run: that
homotopy class is solved already (``details["skipped_starts"]`` lists them).  The nearest class
(the first, the caller's warm start pushed clear) always runs: skipping it too lost 4 of the
first 673 fields of the two benchmark runs, where the swarm's plan had converged to a worse
optimum of the same class.

Option ``initial_population`` (default ``"uniform"``: the swarm's own initial population):
with ``"classes"`` and the obstacles known (``geometry`` or a tracking problem's), a share
``class_share`` (default 0.5) of the swarm's initial particles are
:func:`~uuv_ocp.solvers.homotopy.class_seeds`: one per homotopy class of the warm start's path
(its controls fitted so the rollout follows the class path; box and rate bounds held by the
swarm's ``decode``), then seeded perturbations of them; the centre plan and the rest as
without it.  The swarm then compares the classes itself (``details["class_particles"]``
counts the seeded particles).  The swarm half must accept ``solve(..., initial=rows)``
(``takes_initial = True``; the built-in swarms do, MPPI does not).

The starts run one after the other.  Running them on threads was tried (each thread its own
exact backend) and removed: on 1 of 1000 benchmark fields the threaded answer differed from the
sequential one, unexplained (fatrop's attempts fork a worker process, and forking while another
thread runs copies only the forking thread), and on 2 cores it gained nothing (docs/solvers.md).

Without a ``deadline``, the exact backends on :class:`~uuv_ocp.solvers.nlp.NlpSolver` share
their cold retries across the starts (:class:`~uuv_ocp.solvers.nlp.ColdRetries`): a start whose
first attempt fails retries from the cold guess, the same attempt for every start, so it runs
once per solve (``details["cold_retries_reused"]`` counts the others; the result is unchanged).

Option ``deadline`` (seconds, finite > 0): the wall-time budget of the whole hybrid solve.  The
swarm gets :data:`SWARM_SHARE` (50 %) of it (it returns its best plan so far when that share is
used up; with ``initial_population="classes"`` at most what the seeding left, whose time is
``details["seeding_time"]``), the exact stage what is left when the swarm returns (built with
``deadline`` too, so its in-attempt stops are active; see :mod:`~uuv_ocp.solvers.nlp`); with
``candidates=k`` no further start begins after the deadline.  If the swarm leaves no time at
all, the exact stage does not start and the swarm's plan is returned (``success`` = the swarm's feasibility).
``details["deadline_hit"]`` says whether the hybrid's plan was late (the exact stage's own
flag, or no time left for it); ``details["swarm_deadline_hit"]`` whether the swarm's share
stopped the swarm.  Both halves must declare the ``time_limit`` capability
(``time_limited = True`` and ``solve(..., time_limit=seconds)``; the built-in backends do).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.solvers import homotopy, watchdog
from uuv_ocp.solvers.base import check_backend, takes_time_limit
from uuv_ocp.solvers.multistart import best_result, plan_guess
from uuv_ocp.solvers.nlp import ColdRetries
from uuv_ocp.solvers.options import (
    Option,
    among,
    boolean,
    declaration,
    mapping,
    one_of,
    option,
    optional,
    parse_options,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Iterate, SolveDetails, SolveResult

SWARM_SHARE = 0.5
"""Share of a hybrid's ``deadline`` given to its swarm; the exact stage gets the rest."""

MIN_SWARM_TIME = 1e-6
"""Time limit (s) of a swarm the class seeding left no time: it returns its first population's best."""


CLASSES = 4
"""Default ``classes``: exact starts from the best four homotopy-class guesses (where known)."""

INITIAL_POPULATIONS = ("uniform", "classes")
"""Values of ``initial_population``: the swarm's own start, or a share seeded across the classes."""


def _nonnegative_int(label: str, value: Any) -> int:
    return check.positive_int(label, value, minimum=0)


def _share(label: str, value: Any) -> float:
    share = check.positive_float(label, value)
    if share >= 1.0:
        raise ValueError(f"{label} must be a share in (0, 1), got {value!r}")
    return share


def _callable(label: str, value: Any) -> Any:
    if not callable(value):
        raise ValueError(f"{label} must be a callable p -> Geometry, got {type(value).__name__}")
    return value


@dataclasses.dataclass(frozen=True)
class HybridOptions:
    """Options of every ``"<swarm>+<exact>"`` hybrid."""

    swarm: dict | None = option(
        None, "dict or `None`", "options of the swarm half", meaning="its defaults", check=optional(mapping)
    )
    exact: dict | None = option(
        None, "dict or `None`", "options of the exact half", meaning="its defaults", check=optional(mapping)
    )
    candidates: int = option(
        1,
        "int >= 1",
        "the exact half starts from the swarm's best k distinct plans; the best result is returned",
        check=positive_int,
    )
    keep_warm_start: bool = option(
        True,
        "bool",
        "candidates >= 2: the caller's warm start is the second start, in place of the swarm's k-th plan",
        check=boolean,
    )
    candidate_distance: float | None = option(
        None,
        "float > 0 or `None`",
        "passed to the swarm: RMS distance by which two candidate plans must differ",
        meaning="the swarm's default",
        check=optional(positive_float),
    )
    classes: int = option(
        CLASSES,
        "int >= 0",
        "further exact starts from the best homotopy-class guesses around the obstacles (0: none)",
        check=_nonnegative_int,
    )
    geometry: Any = option(
        None,
        "callable or `None`",
        "p -> homotopy.Geometry: the obstacles of an instance, for `classes`",
        meaning="a TrackingProblem's obstacles",
        check=optional(_callable),
    )
    skip_swarm_class: bool = option(
        True,
        "bool",
        "drop the class starts (but the nearest) whose guess passes every obstacle on the side the exact "
        "solve from the swarm's plan converged to (its homotopy class: solved already)",
        check=boolean,
    )
    initial_population: str = option(
        "uniform",
        one_of(INITIAL_POPULATIONS),
        '"classes": a share of the swarm\'s initial particles follow the homotopy-class paths '
        "(and seeded perturbations of them) where the obstacles are known; the rest as the swarm's own",
        check=among(INITIAL_POPULATIONS),
    )
    class_share: float = option(
        0.5,
        "float in (0, 1)",
        'initial_population="classes": share of the swarm\'s population seeded from the classes',
        check=_share,
    )
    deadline: float | None = option(
        None,
        "float > 0 or `None`",
        f"wall-time budget of the whole solve: {SWARM_SHARE:.0%} for the swarm, the rest for the exact half",
        unit="s",
        meaning="none",
        check=optional(positive_float),
    )


HYBRID_OPTIONS: tuple[Option, ...] = declaration(HybridOptions)
"""Rows of :class:`HybridOptions` (the docs' table)."""


class HybridSolver:
    """Run ``first`` (a swarm), then ``second`` (an exact solver) from the swarm's best plan.

    Options: ``{"swarm": {...}, "exact": {...}}`` passed to the two backends, ``candidates``
    (int >= 1, default 1), ``keep_warm_start`` (bool, default True), ``candidate_distance``
    (float > 0, passed to the swarm) and ``deadline`` (seconds, see the module doc).
    """

    def __init__(
        self,
        name: str,
        first: Any,
        second: Any,
        candidates: int = 1,
        problem: Transcribed | None = None,
        deadline: float | None = None,
        keep_warm_start: bool = True,
        classes: int = 0,
        geometry: homotopy.GeometryProvider | None = None,
        skip_swarm_class: bool = False,
        initial_population: str = "uniform",
        class_share: float = 0.5,
    ) -> None:
        self.name = name
        self.first = first
        self.second = second
        self.candidates = candidates
        self.deadline = deadline
        self.keep_warm_start = keep_warm_start
        self.classes = classes
        self.geometry = geometry
        self.skip_swarm_class = skip_swarm_class
        self.initial_population = initial_population
        self.class_share = class_share
        self._fit: homotopy.PathFit | None = None  # built on the first solve with "classes"
        self.problem = problem if problem is not None else getattr(first, "problem", None)
        self._decode: BufferedFunction | None = None

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
    ) -> SolveResult:
        """Swarm, then exact solve warm-started on the swarm's plan."""
        start = watchdog.now()
        deadline = self.deadline
        seeded: dict[str, Any] = {}
        seeding_time = None
        if self.initial_population == "classes":
            initial = self._class_seeds(p, warm_start, rng)
            seeding_time = watchdog.now() - start
            if initial is not None:
                seeded["initial"] = initial
        if deadline is None:
            swarm = self.first.solve(p, warm_start, rng, **seeded)
        else:
            # the seeding counts against the deadline: the swarm gets its share of what is left
            left = deadline - (watchdog.now() - start)
            limit = max(min(SWARM_SHARE * deadline, left), MIN_SWARM_TIME)
            swarm = self.first.solve(p, warm_start, rng, time_limit=limit, **seeded)

        retries = ColdRetries()

        def exact_solve(guess: Iterate | None) -> SolveResult | None:
            """Run the exact stage from ``guess`` in what is left of the deadline (None: nothing left)."""
            backend = self.second
            if deadline is None:
                share = getattr(backend, "share_cold_retries", None)
                if share is None:
                    return backend.solve(p, guess)
                share(retries)  # every start's cold retry is one attempt: run it once
                try:
                    return backend.solve(p, guess)
                finally:
                    share(None)
            remaining = deadline - (watchdog.now() - start)
            return None if remaining <= 0.0 else backend.solve(p, guess, time_limit=remaining)

        # the exact stage's terminal strategy (sticky soft start after a relaxed step) carries on
        relaxed = warm_start.terminal_relaxed if warm_start is not None else False
        variant = warm_start.variant if warm_start is not None else "hard"
        guess = Iterate(
            scaled_controls=swarm.iterate.scaled_controls,
            states=swarm.iterate.states,
            variant=variant,
            terminal_relaxed=relaxed,
        )
        plans = swarm.details.get("candidates") if self.candidates > 1 else None
        first_exact = exact_solve(guess)
        if first_exact is None:  # the swarm used up the whole deadline: no exact stage
            used = (
                "the swarm"
                if seeding_time is None
                else f"the class seeding ({seeding_time:.3g} s) and the swarm"
            )
            extra = {} if seeding_time is None else {"seeding_time": seeding_time}
            return dataclasses.replace(
                swarm,
                solver=self.name,
                status=f"deadline: {deadline:g} s used up by {used}, no exact stage; {swarm.status}",
                solve_time=watchdog.now() - start,
                details=swarm.details.replace(
                    deadline_hit=True,
                    swarm_deadline_hit=bool(swarm.details.get("deadline_hit", False)),
                    **extra,
                ),
            )
        results = [first_exact]
        starts, skipped = self._starts(p, warm_start, swarm, plans, first_exact)
        if not starts:
            exact = first_exact
            details = dict(exact.details)
            iterations, evaluations = exact.iterations, exact.evaluations
        else:
            origins = ["swarm 0"] + [origin for origin, _, _ in starts]
            fitness = [swarm.details.get("fitness")] + [f for _, _, f in starts]
            for _, start_guess, _ in starts:
                result = exact_solve(start_guess)
                if result is None:  # no start begins after the deadline
                    break
                results.append(result)
            chosen = best_result(results)
            exact = results[chosen]
            details = dict(exact.details)
            details["candidates"] = [
                {
                    "start": origins[i],
                    "swarm_fitness": fitness[i],
                    "cost": r.cost,
                    "max_violation": r.max_violation,
                    "success": r.success,
                    "status": r.status,
                    "iterations": r.iterations,
                    "time": r.solve_time,
                }
                for i, r in enumerate(results)
            ]
            details["chosen"] = chosen
            details["class_starts"] = sum(origin.startswith("class") for origin in origins[: len(results)])
            iterations = sum(r.iterations for r in results)
            evaluations = sum(r.evaluations for r in results)
        if skipped:
            details["skipped_starts"] = skipped
        if "initial" in seeded:
            details["class_particles"] = len(seeded["initial"])
        if seeding_time is not None:
            details["seeding_time"] = seeding_time
        if retries.reused:
            details["cold_retries_reused"] = retries.reused
        details.update(
            {
                "swarm_fitness": swarm.details.get("fitness"),
                "swarm_cost": swarm.cost,
                "swarm_evaluation": swarm.details.get("evaluation"),
            }
        )
        if deadline is not None:
            late = any(r.details.get("deadline_hit", False) for r in results)
            details["deadline_hit"] = bool(late or watchdog.now() - start > deadline)
            details["swarm_deadline_hit"] = bool(swarm.details.get("deadline_hit", False))
        return dataclasses.replace(
            exact,
            solver=self.name,
            solve_time=watchdog.now() - start,
            iterations=iterations,
            evaluations=evaluations + swarm.evaluations,
            history=swarm.history,
            details=SolveDetails.of(details),
        )

    def _class_seeds(
        self, p: np.ndarray, warm_start: Iterate | None, rng: np.random.Generator | None
    ) -> np.ndarray | None:
        """Return the swarm's initial particles across the classes (None: no obstacle known or in the way).

        ``class_share`` of the swarm's population, one below it at most (the centre plan
        stays); the perturbations draw from ``rng`` before the swarm does (the swarm's own
        ``seed`` without one), so the run is seeded as a whole.
        """
        problem = self.problem
        if problem is None:
            return None
        geometry = homotopy.geometry_of(problem, p, self.geometry)
        if geometry is None:
            return None
        population = int(getattr(self.first, "population", 0))
        size = min(int(self.class_share * population), population - 1)
        if size < 1:
            return None

        def fit() -> homotopy.PathFit:  # built only when a class path exists (0.4 s for RexROV)
            if self._fit is None or self._fit.position != geometry.position:
                self._fit = homotopy.PathFit(problem, geometry.position)
            return self._fit

        generator = rng if rng is not None else np.random.default_rng(getattr(self.first, "seed", 0))
        rows, _ = homotopy.class_seeds(problem, p, warm_start, geometry, fit, size, generator)
        return rows if len(rows) else None

    def _starts(
        self,
        p: np.ndarray,
        warm_start: Iterate | None,
        swarm: SolveResult,
        plans: Any,
        first: SolveResult | None = None,
    ) -> tuple[list[tuple[str, Iterate | None, float | None]], list[str]]:
        """List the exact half's starts after the swarm's plan: ``([(origin, guess, fitness)], skipped)``.

        The caller's warm start (``keep_warm_start`` with ``candidates >= 2``),
        the swarm's next distinct plans (``candidates``), then the ``classes`` best homotopy-class
        guesses (:mod:`~uuv_ocp.solvers.homotopy`) when the obstacles are known; with
        ``skip_swarm_class``, minus the class guesses in the homotopy class of ``first`` (the
        exact solve from the swarm's plan, when it succeeded), whose labels are ``skipped``.
        """
        out: list[tuple[str, Iterate | None, float | None]] = []
        classes: list[tuple[str, Iterate]] = []
        skipped: list[str] = []
        if self.classes > 0 and self.problem is not None:
            geometry = homotopy.geometry_of(self.problem, p, self.geometry)
            if geometry is not None:
                classes = homotopy.class_guesses(self.problem, p, warm_start, geometry)[: self.classes]
            if geometry is not None and classes and self.skip_swarm_class and first and first.success:
                # a start in the class the swarm's plan already converged in would find (on the
                # obstacle benchmark: nearly always) that same local optimum again; not so for
                # the nearest class, which found a better optimum of that class on 4 of 673 fields
                columns = list(geometry.position)
                solved = homotopy.sides(np.asarray(first.states)[:, columns], geometry.discs)
                kept = classes[:1]  # the nearest class (the straight start pushed clear) always runs
                for label, guess in classes[1:]:
                    assert guess.states is not None
                    if homotopy.sides(np.asarray(guess.states)[:, columns], geometry.discs) == solved:
                        skipped.append(label)
                    else:
                        kept.append((label, guess))
                classes = kept
        # the class guesses replace the straight start: the nearest one is it, pushed clear
        # (on the obstacle benchmark keeping it too cost 40 % more time for no better cost)
        if self.keep_warm_start and plans:  # None: the exact solver's own cold guess
            out.append(("warm start", warm_start, None))
        if plans:
            problem = self.problem
            if problem is None:
                raise ValueError(f"{self.name}: candidates > 1 needs the problem (pass problem=)")
            if self._decode is None:
                self._decode = BufferedFunction(problem.build().decode)
            fitness = list(swarm.details.get("candidate_fitness", []))
            for i, plan in enumerate(plans[1 : self.candidates - int(self.keep_warm_start)], start=1):
                guess = plan_guess(problem, plan, p, warm_start, self._decode)
                out.append((f"swarm {i}", guess, fitness[i] if i < len(fitness) else None))
        out += [(label, guess, None) for label, guess in classes]
        return out, skipped


def hybrid_factory(name: str, first: Callable, second: Callable) -> Callable:
    """Registry factory for ``"<first>+<second>"``."""
    swarm_name, _, exact_name = name.partition("+")

    def factory(problem: Transcribed, options: dict[str, Any] | None = None) -> HybridSolver:
        settings = parse_options(HybridOptions, options, name)
        swarm_options, exact_options = settings.swarm, settings.exact
        candidates, keep = settings.candidates, settings.keep_warm_start
        distance, deadline = settings.candidate_distance, settings.deadline
        if deadline is not None:
            # built with the deadline: the exact stage's in-attempt stops (iteration callback)
            exact_options = {"deadline": deadline, **(exact_options or {})}
        if candidates > 1 or distance is not None:
            swarm_options = dict(swarm_options or {})
            swarm_options["candidates"] = candidates
            if distance is not None:
                swarm_options["candidate_distance"] = distance
        hybrid = HybridSolver(
            name,
            first(problem, swarm_options),
            second(problem, exact_options),
            candidates,
            problem,
            deadline,
            keep,
            settings.classes,
            settings.geometry,
            settings.skip_swarm_class,
            settings.initial_population,
            settings.class_share,
        )
        if settings.initial_population == "classes" and not getattr(hybrid.first, "takes_initial", False):
            raise ValueError(
                f"options['initial_population'] of {name!r}: 'classes' needs a swarm half that accepts "
                f"solve(..., initial=rows) (takes_initial = True); {type(hybrid.first).__name__} does not"
            )
        for label, half in ((swarm_name, hybrid.first), (exact_name, hybrid.second)):
            check_backend(half, label)
            if deadline is not None and not takes_time_limit(half):
                raise ValueError(
                    f"options['deadline'] of {name!r} needs both halves to accept "
                    f"solve(..., time_limit=seconds) (time_limited = True); {type(half).__name__} does not"
                )
        return hybrid

    factory.Options = HybridOptions  # type: ignore[attr-defined]  # what parse_options reads
    factory.OPTIONS = HYBRID_OPTIONS  # type: ignore[attr-defined]  # the declaration the docs read
    return factory
