"""Derivative-free backends: IGWO, GWO, SSA, PSO on the condensed cost of the problem.

The swarm searches the scaled control sequence ``U ∈ [-1, 1]^{3N}``.  Its fitness is the
condensed objective ``J(U; p)`` of :mod:`uuv_ocp.transcription.condensed` (rollout of the **same** RK4
Function as the NLP) plus the exact penalty of what a box search cannot hold by construction::

    fitness(U) = J(U; p) + ρ_T Σ|x_N − x_R,N| (terminal="equality") + ρ_R Σ max(0, |Δz| − Δz_max)

with ``ρ_T = Weights.terminal_penalty`` and ``ρ_R = Weights.rate_penalty``.  The population is
evaluated in one call of the cost mapped over the population (``Function.map``), never in a
Python loop over individuals.  ``SolveResult.cost``/``max_violation`` come from
:func:`uuv_ocp.judge.score_parameters`, like every other backend.

Search coordinates (``search`` option).  The paper's IGWO update contracts positions toward the
origin of the search space (``w < 1`` multiplies the leaders' mean), which is a strong prior
toward whatever the origin means.  With ``search="deviation"`` (default) the swarm searches the
deviation ``δ = U − U_c`` from a centre plan ``U_c`` — the shifted previous plan in a closed
loop, otherwise the last applied control held over the horizon — in the box
``[-1 − U_c, 1 − U_c]`` (the same feasible set).  ``search="absolute"`` searches ``U`` itself.
With ``seed_warm_start=True`` (default) the centre itself (δ = 0) is one of the initial wolves,
the rest are uniform in the box.

Deadline (``deadline`` option, seconds).  The wall time since :meth:`SwarmSolver.solve` started
is checked after the initial population and after every iteration of the Python loop of
:func:`uuv_ocp.optimize.minimize` (``time_limit``); once exceeded the swarm returns its best
plan so far, which holds the box and the rate bound like every candidate, with
``details["deadline_hit"] = True`` and a status saying the deadline stopped it.  ``success``
keeps its meaning (feasible): a swarm is an anytime method.  The compiled all-C IGWO step runs
every iteration in one C call and cannot be stopped in the middle, so with a deadline IGWO runs
the Python loop on the same compiled batched fitness (the same random numbers: the same result
when the deadline is not reached; measured on s2, N = 20, 30 iterations of 20 wolves: 15.5 ms
per solve instead of 5.9 ms), except when the last search that used its whole budget took at
most half of the time left: then the C step runs (it is the faster of the two).  A search that
finishes its budget after the deadline also reports ``deadline_hit``.
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import FEASIBILITY_TOLERANCE, score_terms
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.runtime import (
    COMPILED_ENV,
    IgwoSetup,
    NativeIgwo,
    SearchBox,
    WarmEncoding,
    compiled_build,
    compiled_by_default,
    uses_pcg64,
)
from uuv_ocp.optimize import ALGORITHMS, ImprovedGreyWolf, MinimizeResult, minimize
from uuv_ocp.solvers.options import (
    AUTO,
    Check,
    Option,
    among,
    boolean,
    format_value,
    make_options_class,
    mapping,
    one_of,
    optional,
    parse_options,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Iterate, SolveDetails, SolveResult
from uuv_ocp.transcription.condensed import batched_fitness, encode
from uuv_ocp.transcription.condensed import (
    candidate_fitness as candidate_fitness,  # re-exported: its old home
)

SEARCH_MODES = ("deviation", "absolute")


def _usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _compiled_default(value: object) -> bool:
    """``compiled``: True/False, or ``"auto"`` = compiled wherever a C compiler exists.

    ``"auto"`` can be overridden by the environment (``UUV_OCP_COMPILED=0`` or ``1``), e.g. to
    keep a test suite on CasADi's virtual machine; the first compiled build of a problem takes
    ~20 s and is then cached on disk by content.
    """
    if value == "auto":
        return compiled_by_default("the swarm runs on CasADi's virtual machine", stacklevel=4)
    return check.boolean("options['compiled']", value)


CANDIDATE_METRICS = ("states", "controls")
CANDIDATE_DISTANCE = {"states": 0.5, "controls": 0.1}
"""Default ``candidate_distance`` per ``candidate_metric``: two plans of ``details["candidates"]``
differ by more than this root-mean-square distance.  ``"states"``: between the predicted state
trajectories (nodes 1..N), each state component divided by its standard deviation over the
first evaluated population (so unit-free: 0.5 is half the initial spread).  ``"controls"``:
between the search coordinates ``W ∈ [-1, 1]^{nu N}`` (``‖W_i − W_j‖ / sqrt(nu N)``: 0.1 is 5 %
of the coordinate range on average).  ``"states"`` is the default because plans in one
homotopy class can be far apart in ``W`` while paths in different classes can be close: on a
planar obstacle field (benchmarks/bench_nonconvex.py) the 6 best plans at ``W`` distance 0.2 all
passed the obstacles on the same side in 10 of 10 instances."""


PARALLELIZATIONS = ("serial", "thread")


def swarm_options(method: str) -> tuple[Option, ...]:
    """Options of the swarm backend ``method``: the population and iterations are its algorithm's."""
    check.choice("method", method, sorted(ALGORITHMS))
    algorithm = ALGORITHMS[method]
    per_metric = ", ".join(f'{d:g} for `candidate_metric="{m}"`' for m, d in CANDIDATE_DISTANCE.items())
    own = format_value(dict(algorithm.default_options))
    return (
        Option(
            "population",
            algorithm.default_population,
            "int >= 4",
            "individuals evaluated per iteration",
            meaning="the paper's budget",
        ),
        Option(
            "iterations",
            algorithm.default_iterations,
            "int >= 1",
            "iteration budget T (the schedules run over it)",
            meaning="the paper's budget",
        ),
        Option(
            "max_evaluations",
            None,
            "int >= `population` or `None`",
            "cap on the cost evaluations of one solve, initial population included",
            meaning="no cap",
        ),
        Option(
            "seed", 0, "int >= 0", "seed of `numpy.random.default_rng` when the caller passes no generator"
        ),
        Option(
            "search",
            "deviation",
            one_of(SEARCH_MODES),
            "search the deviation from a centre plan (the shifted previous plan) or the controls themselves",
        ),
        Option(
            "seed_warm_start", True, "`True` or `False`", "the centre plan is one of the initial individuals"
        ),
        Option(
            "parallelization",
            "serial",
            one_of(PARALLELIZATIONS),
            "CasADi `map` evaluation of the population's cost on the virtual machine",
        ),
        Option(
            "algorithm_options",
            None,
            "dict or `None`",
            "parameters of the algorithm, each replacing its default",
            meaning=f"the algorithm's defaults, `{own}`",
        ),
        Option(
            "compiled",
            "auto",
            '`"auto"`, `True` or `False`',
            "compiled SIMD fitness and, for IGWO, the all-C step (a problem's first build takes a while)",
            meaning=f"compiled wherever a C compiler exists, unless the environment sets `{COMPILED_ENV}=0`",
        ),
        Option(
            "rng_thread",
            AUTO,
            "`True` or `False`",
            "the all-C IGWO step shares its random draws with a second thread (the same numbers)",
            meaning=(
                "`True` on a machine with 2 or more usable CPUs, unless the build draws 8 numbers per "
                "step (AVX-512 IFMA)"
            ),
        ),
        Option(
            "deadline",
            None,
            "float > 0 or `None`",
            "wall-time budget of one solve; the best plan so far is returned when it is used up",
            unit="s",
            meaning="none",
        ),
        Option(
            "candidates",
            1,
            "int >= 1",
            'k > 1: up to k distinct good plans of the run in `details["candidates"]`',
        ),
        Option(
            "candidate_metric",
            "states",
            one_of(CANDIDATE_METRICS),
            "distance between candidates: predicted states (over their initial spread) or search coordinates",
        ),
        Option(
            "candidate_distance",
            AUTO,
            "float > 0",
            "RMS distance by which two candidates must differ",
            meaning=per_metric,
        ),
    )


def _at_least_four(label: str, value: object) -> int:
    return check.positive_int(label, value, minimum=4)


def _nonnegative_int(label: str, value: object) -> int:
    return check.positive_int(label, value, minimum=0)


def _compiled_choice(label: str, value: object) -> object:
    if isinstance(value, str) and value == "auto":
        return value
    return check.boolean(label, value)


def _or_auto(inner: Check) -> Check:
    def checked(label: str, value: Any) -> Any:
        return value if value is AUTO else inner(label, value)

    return checked


_SWARM_CHECKS: dict[str, Check] = {
    "population": _at_least_four,
    "iterations": positive_int,
    "max_evaluations": optional(positive_int),  # and >= population, checked with it
    "seed": _nonnegative_int,
    "search": among(SEARCH_MODES),
    "seed_warm_start": boolean,
    "parallelization": among(PARALLELIZATIONS),
    "algorithm_options": optional(mapping),  # and each entry, by the algorithm itself
    "compiled": _compiled_choice,
    "rng_thread": _or_auto(boolean),
    "deadline": optional(positive_float),
    "candidates": positive_int,
    "candidate_metric": among(CANDIDATE_METRICS),
    "candidate_distance": _or_auto(positive_float),
}


@functools.cache
def swarm_options_class(method: str) -> type:
    """Return the frozen options dataclass of the swarm backend ``method`` (its :func:`swarm_options`)."""
    return make_options_class(f"{method.upper()}Options", swarm_options(method), _SWARM_CHECKS)


class BufferedFitness:
    """Zero-copy population fitness (:class:`uuv_ocp.native.buffered.BufferedFunction`).

    ``candidates`` (population, dim) in row-major order are the (dim, population) column-major
    nonzeros the mapped Function takes.
    """

    def __init__(self, function: ca.Function, population: int, dim: int, parameter_dim: int) -> None:
        if function.size_in(0) != (dim, population) or function.nnz_in(1) != parameter_dim:
            raise ValueError(
                f"function must take U ({dim} x {population}) and p ({parameter_dim}), got "
                f"{function.size_in(0)} and {function.size_in(1)}"
            )
        self.function = function
        self._call = BufferedFunction(function)

    def __call__(self, candidates: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Fitness of ``candidates`` (population, dim) for parameters ``p``: (population,)."""
        return self._call(candidates.ravel(), p)[0]  # row-major rows = the matrix's columns


class CandidateArchive:
    """The best ``size`` mutually distinct candidates evaluated in a run (``candidates`` option).

    Updated with every evaluated population: the archive and the new points are sorted by
    fitness and taken greedily, each kept if the RMS distance of its features
    (``features(points) -> (n, m)``, default the points themselves) to those of every point
    already kept exceeds ``distance``.  Non-finite fitness never enters; when the archive is
    full only points better than its worst are considered (their features are computed only
    then).
    """

    def __init__(
        self, size: int, distance: float, features: Callable[[np.ndarray], np.ndarray] | None = None
    ) -> None:
        self.size = size
        self.distance = distance
        self.features = features
        self.points = np.empty((0, 0))
        self.values = np.empty(0)
        self.keys = np.empty((0, 0))  # features of the kept points

    @staticmethod
    def distances(keys: np.ndarray, key: np.ndarray) -> np.ndarray:
        """RMS distances of the feature vector ``key`` to the rows of ``keys``."""
        return np.sqrt(np.mean((keys - key) ** 2, axis=1))

    def add(self, points: np.ndarray, values: np.ndarray) -> None:
        """Offer a population ``points`` (n, dim) with its fitness ``values`` (n,)."""
        values = np.asarray(values, dtype=float).ravel()
        keep = np.isfinite(values)
        if self.values.size == self.size:
            keep &= values < self.values[-1]  # only a point better than the worst kept can enter
        if not np.any(keep):
            return
        fresh = np.asarray(points[keep], dtype=float)
        keys = fresh if self.features is None else np.asarray(self.features(fresh), dtype=float)
        empty = self.values.size == 0
        pool = fresh if empty else np.vstack([self.points, fresh])
        pool_keys = keys if empty else np.vstack([self.keys, keys])
        pool_values = np.concatenate([self.values, values[keep]])
        chosen: list[int] = []
        for i in np.argsort(pool_values, kind="stable"):
            if not chosen or np.all(self.distances(pool_keys[chosen], pool_keys[i]) > self.distance):
                chosen.append(int(i))
                if len(chosen) == self.size:
                    break
        self.points, self.values, self.keys = pool[chosen], pool_values[chosen], pool_keys[chosen]


def candidate_archive(
    problem: Transcribed,
    decode: BufferedFunction,
    rollout: BufferedFunction | None,
    size: int,
    metric: str,
    distance: float,
    p: np.ndarray,
) -> CandidateArchive:
    """Return the archive of a ``candidates`` option over search coordinates ``W``, by ``metric``.

    ``"controls"``: the coordinates themselves; ``"states"``: the predicted states on nodes
    1..N, each component over its spread in the first population offered (unit-free).
    Shared by the swarms and MPPI (both evaluate populations of ``W``).
    """
    if metric == "controls":
        return CandidateArchive(size, distance)
    scale: list[np.ndarray] = []

    def features(points: np.ndarray) -> np.ndarray:
        """Predicted states on nodes 1..N, each component over its initial spread."""
        states = np.array(
            [problem.rollout_scaled(decode(w, p)[0], p, rollout)[1:] for w in points]
        )  # (n, N, nx)
        if not scale:  # the first call sees the initial population
            spread = states.std(axis=(0, 1))
            scale.append(np.where(spread > 1e-12, spread, 1.0))
        return (states / scale[0]).reshape(points.shape[0], -1)

    return CandidateArchive(size, distance, features)


def candidate_details(
    problem: Transcribed,
    decode: BufferedFunction,
    archive: CandidateArchive,
    best: np.ndarray,
    best_fitness: float,
    size: int,
    p: np.ndarray,
) -> dict[str, Any]:
    """Return ``candidates`` (scaled plans (N, nu), best first) and ``candidate_fitness`` of a run."""
    chosen, fitness = [best], [best_fitness]
    # the archive's first point is the best evaluated one (the same as best up to ties)
    start = 1 if archive.values.size and archive.values[0] <= best_fitness else 0
    for point, value in zip(archive.points[start:], archive.values[start:], strict=True):
        if len(chosen) == size:
            break
        chosen.append(point)
        fitness.append(float(value))
    shape = (problem.spec().horizon, problem.spec().control_size)
    plans = [decode(w, p)[0].reshape(shape) for w in chosen]
    return {"candidates": plans, "candidate_fitness": fitness}


class SwarmSolver:
    """A population optimiser from :mod:`uuv_ocp.optimize` as a backend for any bounded problem.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
        Every control needs finite box bounds (the search box).
    options : dict, optional
        The options of :func:`swarm_options` ``(method)`` (name, default, values and meaning
        of each; rendered as a table in docs/solvers.md).  Why some of them are what they are:

        ``candidates`` k > 1 adds ``details["candidates"]``: at most k scaled control plans
        (N, nu), the best plan first, then the best candidates evaluated during the run that
        are farther than ``candidate_distance`` from every plan taken before (a
        :class:`CandidateArchive`), with their fitness in ``details["candidate_fitness"]``.
        The whole run, not the final population: IGWO's and GWO's final wolves lie within
        ~0.03 RMS of each other in ``W`` (measured on a planar obstacle problem), PSO's
        particles ~0.45.  The archive needs every population, so IGWO then runs the Python
        loop on the same compiled fitness, like with a deadline; the ``"states"`` metric rolls
        out each point that may enter the archive; k = 1 costs nothing.
        ``candidate_distance`` defaults per metric to :data:`CANDIDATE_DISTANCE`.

        ``rng_thread``: the all-C IGWO step shares the drawing of its random numbers with a
        second thread running up to four iterations ahead — the same numbers; the step draws
        what the thread has not started itself, so a late thread never stalls the step; False
        keeps the step on one thread: better for the tail latency on a machine whose other
        CPUs are busy, e.g. inside a process pool, see docs/codegen.md.  ``"auto"`` (default):
        the thread with two or more usable CPUs, unless the build draws eight numbers per step
        (AVX-512 IFMA, ``NativeIgwo.draw_lanes``), where the step alone is faster.  ``compiled``: see
        docs/codegen.md; ``deadline``: see the module doc.
    method : str
        ``"igwo"``, ``"gwo"``, ``"ssa"`` or ``"pso"``.
    """

    time_limited = True  # solve(..., time_limit=) (the Backend protocol's capability)
    takes_initial = True  # solve(..., initial=W rows): a hybrid's initial_population="classes"

    def __init__(self, problem: Transcribed, options: dict[str, Any] | None = None, *, method: str) -> None:
        check.choice("method", method, sorted(ALGORITHMS))
        algorithm = ALGORITHMS[method]
        self.OPTIONS = swarm_options(method)
        self.settings: Any = parse_options(swarm_options_class(method), options, method)
        settings: Any = self.settings
        self.name = method
        self.problem = problem
        self.method = method
        self.population, self.iterations = settings.population, settings.iterations
        self.max_evaluations = settings.max_evaluations
        if self.max_evaluations is not None:
            label = f"options['max_evaluations'] of {method!r}"
            self.max_evaluations = check.positive_int(label, self.max_evaluations, minimum=self.population)
        self.seed, self.search = settings.seed, settings.search
        self.seed_warm_start, self.parallelization = settings.seed_warm_start, settings.parallelization
        self.algorithm_options = settings.algorithm_options
        self.compiled = _compiled_default(settings.compiled)
        self.deadline, self.candidates = settings.deadline, settings.candidates
        self.candidate_metric = settings.candidate_metric
        distance = settings.candidate_distance
        self.candidate_distance = CANDIDATE_DISTANCE[self.candidate_metric] if distance is AUTO else distance
        # validate algorithm options now, before any solve (the constructor checks them)
        algorithm(-np.ones(1), np.ones(1), self.population, self.iterations, self.algorithm_options)
        spec = problem.spec()
        if not (np.all(np.isfinite(spec.lower)) and np.all(np.isfinite(spec.upper))):
            raise ValueError(
                f"solver {method!r} searches a box: every control needs finite lower and upper bounds, "
                f"got lower={spec.lower}, upper={spec.upper}"
            )
        # the search box of the decode coordinates (box and rate bounds held by construction)
        self._lower = -np.ones(spec.control_size * spec.horizon)
        self._upper = np.ones(spec.control_size * spec.horizon)
        self._decode = BufferedFunction(problem.build().decode)
        self.native: NativeIgwo | None = None  # the all-C IGWO step, when compiled and compatible
        self._score_terms: BufferedFunction | None = None  # compiled twins when compiled=True
        self._rollout: BufferedFunction | None = None
        self._schedules: tuple[np.ndarray, np.ndarray] | None = None  # IGWO's a(t), w(t) for the C step
        self._full_search_seconds: float | None = None  # last search that used the whole budget
        self._cold_center: tuple[bytes, np.ndarray] | None = None  # (previous control, its centre)
        self._cold_box: tuple[bytes, SearchBox] | None = None  # (raw u_prev, the C solve's box)
        self._u_prev = spec.layout.u_prev
        self._soft_terminal = problem.soft_terminal_available  # fixed once built: ~5 µs a read
        self.fitness = self._fitness_function()
        # the whole default solve in one C call (solve_pcg64) where the build finishes in C
        self._setup: IgwoSetup | None = None
        if self.native is not None and self.native.finishes and self.native.direct_pcg64:
            steps = ImprovedGreyWolf(
                self._lower, self._upper, self.population, self.iterations, self.algorithm_options
            )
            self._schedules = (
                np.array([steps._a(t) for t in range(self.iterations)]),
                np.array([steps._w(t) for t in range(self.iterations)]),
            )
            c1, c2 = steps.options["c1"], steps.options["c2"]
            rate = spec.rate_step_bound
            start = spec.layout.u_prev.start or 0
            encoding = (
                WarmEncoding(
                    horizon=spec.horizon,
                    u_prev=start,
                    centre=spec.control_centre,
                    scale=spec.control_scale,
                    scaled_lower=spec.scaled_lower,
                    scaled_upper=spec.scaled_upper,
                    rate=rate,
                    rate_bounded=bool(spec.lifted and np.any(np.isfinite(rate))),
                    deviation=self.search == "deviation",
                    seed_warm=self.seed_warm_start,
                )
                # a warm plan's box in C needs u_prev as one run of p (a slice of step 1)
                if spec.layout.u_prev.step in (None, 1)
                and spec.layout.u_prev.stop - start == spec.control_size
                else None
            )
            self._setup = self.native.setup(*self._schedules, c1, c2, self._lower, self._upper, encoding)
        # auto: a second thread only where it pays, with two CPUs and the scalar draws (with the
        # 8-lane IFMA draws the step alone is faster: the blocks' trip between cores costs more)
        vector_draws = self.native is not None and self.native.draw_lanes > 1
        self.rng_thread = (
            _usable_cpus() >= 2 and not vector_draws if settings.rng_thread is AUTO else settings.rng_thread
        )
        # what evaluates the population (details["evaluation"] says per solve what really ran)
        self.evaluation = (
            "compiled C step"
            if self.native is not None
            else "compiled"
            if self._rollout
            else "virtual machine"
        )
        self._evaluate = BufferedFitness(
            self.fitness, self.population, problem.control_dim, problem.parameter_dim
        )

    def _fitness_function(self) -> ca.Function:
        if self.compiled:
            build = compiled_build(self.problem, self.population)  # warns once if no compiler
            if build is not None:
                if self.method == "igwo" and self._native_compatible():
                    self.native = NativeIgwo(build)
                self._score_terms = BufferedFunction(build["score_terms"])
                self._rollout = BufferedFunction(build["rollout"])
                return build["cost_batch"]
        return batched_fitness(self.problem, self.population, self.parallelization)

    def _native_compatible(self) -> bool:
        options = dict(ALGORITHMS["igwo"].default_options)
        options.update(self.algorithm_options or {})
        return (
            options["frame"] == "origin"
            and options["convergence"] == "cosine"
            and self.max_evaluations is None
        )

    def _center(self, p: np.ndarray, warm_start: Iterate | None) -> np.ndarray:
        """Search coordinates of the warm plan, or of the last control held over the horizon."""
        problem = self.problem
        spec = problem.spec()
        previous = problem.previous_scaled(p)
        if warm_start is not None:
            return encode(spec, np.asarray(warm_start.scaled_controls, dtype=float), previous)
        # a cold centre depends on the last control only: one cached entry saves ~30 µs of
        # encode per solve at a fixed state (a benchmark, the repeated cold starts of a loop)
        key, cached = previous.tobytes(), self._cold_center  # one read: solves may run in threads
        if cached is not None and cached[0] == key:
            return cached[1]
        center = encode(spec, np.tile(previous, (spec.horizon, 1)), previous)
        center.setflags(write=False)  # shared between solves: read only
        self._cold_center = (key, center)
        return center

    @staticmethod
    def _initial_rows(initial: object, width: int) -> np.ndarray:
        """Return ``initial`` as a finite float array of shape (k, ``width``) (``ValueError`` names it)."""
        return check.finite_array("initial", initial, (None, width))

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
        initial: np.ndarray | None = None,
    ) -> SolveResult:
        """One swarm solve of the instance with parameter vector ``p``.

        ``time_limit`` (seconds from the call) overrides the ``deadline`` option for this call
        (a hybrid gives its swarm a share of its own deadline).  ``initial`` (k, nu N): further
        initial individuals in the search coordinates ``W`` (clipped into ``[-1, 1]``), placed
        after the centre plan (``seed_warm_start``); the rest of the population is uniform as
        without it (a hybrid's ``initial_population="classes"``).
        """
        start = time.perf_counter()
        limit = self.deadline if time_limit is None else check.positive_float("time_limit", time_limit)
        if (
            self._setup is not None
            and self.native is not None  # a test may take the C step away: the Python loop runs
            and self.candidates == 1
            and (rng is None or uses_pcg64(rng))
            and self._native_fits(limit, start)
        ):
            return self._solve_in_c(p, warm_start, rng, initial, start, limit)
        problem = self.problem
        center = self._center(p, warm_start)
        offset = center if self.search == "deviation" else np.zeros_like(center)
        lower, upper = self._lower - offset, self._upper - offset
        seeds = None
        if self.seed_warm_start and (warm_start is not None or self.search == "deviation"):
            seeds = (center - offset)[None, :]
        rows = None if initial is None else self._initial_rows(initial, center.size)
        if rows is not None and len(rows):
            # checked before the clip: a clip broadcasts a wrong width and keeps NaN rows
            extra = np.clip(rows, self._lower, self._upper) - offset
            seeds = extra if seeds is None else np.vstack([seeds, extra])
            if seeds.shape[0] > self.population:
                raise ValueError(
                    f"initial must leave room in the population ({self.population}) beside the centre "
                    f"plan, got {len(rows)} rows"
                )
        evaluate = self._evaluate
        archive = self._candidate_archive(p) if self.candidates > 1 else None

        def objective(candidates: np.ndarray) -> np.ndarray:
            # minimize() always passes whole populations: one call of the mapped cost
            values = evaluate(candidates + offset, p)
            if archive is not None:
                archive.add(candidates + offset, values)
            return values

        # the candidates option needs every population: the Python loop on the same fitness
        evaluation = "compiled" if self._rollout is not None else "virtual machine"
        if self.native is not None and archive is None and self._native_fits(limit, start):
            outcome = self._native_minimize(p, offset, lower, upper, seeds, rng)
            evaluation = "compiled C step"
        else:  # with a deadline the Python loop, which can stop between iterations
            remaining = None if limit is None else max(limit - (time.perf_counter() - start), 1e-12)
            outcome = minimize(
                objective,
                lower,
                upper,
                self.method,
                population=self.population,
                iterations=self.iterations,
                max_evaluations=self.max_evaluations,
                seed=rng if rng is not None else self.seed,
                initial_population=seeds,
                options=self.algorithm_options,
                time_limit=remaining,
            )
        searched = time.perf_counter() - start
        if not outcome.deadline_hit:
            self._full_search_seconds = searched
        late = limit is not None and searched > limit  # stopped by the deadline, or finished after it
        (scaled,) = self._decode(np.clip(outcome.x + offset, self._lower, self._upper), p)
        cost, kinds = score_terms(problem, scaled, p, self._score_terms)
        tolerance = FEASIBILITY_TOLERANCE
        feasible = max(kinds["bound"], kinds["rate"], kinds["constraint"]) <= tolerance
        violation = max(kinds.values())
        states = problem.rollout_scaled(scaled, p, self._rollout)
        controls = problem.controls_from_scaled(scaled)
        iterate = Iterate(
            scaled_controls=scaled.reshape(problem.spec().horizon, -1),
            states=states,
        )
        return SolveResult(
            solver=self.name,
            controls=controls,
            states=states,
            cost=cost,
            max_violation=violation,
            success=bool(np.isfinite(outcome.fun)) and feasible,
            status=(
                f"deadline: {limit:g} s reached after {outcome.iterations} of {self.iterations} "
                "iterations; best plan so far"
                if outcome.deadline_hit
                else f"deadline: {limit:g} s exceeded by the full budget; {outcome.message}"
                if late
                else outcome.message
            ),
            solve_time=time.perf_counter() - start,
            iterations=outcome.iterations,
            evaluations=outcome.evaluations,
            terminal_relaxed=kinds["terminal"] > tolerance and problem.soft_terminal_available,
            iterate=iterate,
            history=outcome.history,
            details=SolveDetails.of(
                {
                    "fitness": outcome.fun,
                    "violations": kinds,
                    "deadline_hit": outcome.deadline_hit or late,
                    "evaluation": evaluation,
                    **self._candidate_details(archive, outcome, offset, p),
                }
            ),
        )

    def _search_box(self, p: np.ndarray, warm_start: Iterate | None, initial: np.ndarray | None) -> SearchBox:
        """Return the C solve's box: what :meth:`solve` computes before the step, kept for cold starts.

        A cold start's box depends only on the last applied control in ``p`` (its raw bytes
        are the key: one read of the cache, solves may run in threads).
        """
        cold = warm_start is None and initial is None
        if cold:
            key, cached = p[self._u_prev].tobytes(), self._cold_box
            if cached is not None and cached[0] == key:
                return cached[1]
        center = self._center(p, warm_start)
        offset = center if self.search == "deviation" else np.zeros_like(center)
        seeds = np.empty((0, center.size))
        if self.seed_warm_start and (warm_start is not None or self.search == "deviation"):
            seeds = (center - offset)[None, :]
        rows = None if initial is None else self._initial_rows(initial, center.size)
        if rows is not None and len(rows):
            # checked before the clip: a clip broadcasts a wrong width and keeps NaN rows
            seeds = np.vstack([seeds, np.clip(rows, self._lower, self._upper) - offset])
            if seeds.shape[0] > self.population:
                raise ValueError(
                    f"initial must leave room in the population ({self.population}) beside the centre "
                    f"plan, got {len(rows)} rows"
                )
        assert self.native is not None, "only called where the all-C step was built"
        box = self.native.search_box(offset, self._lower, self._upper, seeds)
        if cold:
            self._cold_box = (key, box)
        return box

    def _solve_in_c(
        self,
        p: np.ndarray,
        warm_start: Iterate | None,
        rng: np.random.Generator | None,
        initial: np.ndarray | None,
        start: float,
        limit: float | None,
    ) -> SolveResult:
        """:meth:`solve` as one C call (:meth:`NativeIgwo.solve_pcg64`): the same result, bit for bit.

        The initial wolves, the step, the decode, score and rollout of the best plan run in C;
        here only the result is assembled from the call's record (views of one array).
        """
        native, setup = self.native, self._setup
        assert native is not None and setup is not None, "only called where the C solve was set up"
        generator = rng if rng is not None else np.random.default_rng(self.seed)
        plan = None if warm_start is None or initial is not None else warm_start.scaled_controls
        if plan is not None and setup.warm and np.size(plan) == native.dim:
            # the centre plan and the box made in C: encode's numpy costs ~40 us a solve
            record = native.solve_pcg64_warm(setup, p, plan, generator, int(self.rng_thread))
        else:
            box = self._search_box(p, warm_start, initial)
            record = native.solve_pcg64(setup, p, box, generator, int(self.rng_thread))
        searched = time.perf_counter() - start
        self._full_search_seconds = searched
        fun = float(record[setup.fun])
        objective, terminal, rate, bound, other = (record[part] for part in setup.score)
        # ndarray methods, as judge.score_terms: the same maxima (NaN included)
        kinds = {
            "terminal": float(np.abs(terminal).max()),
            "rate": float(rate.max()),
            "bound": float(bound.max()),
            "constraint": float(other.max()),
        }
        problem = self.problem
        scaled = record[setup.scaled]
        horizon = scaled.size // problem.control_size
        states = record[setup.states].reshape(horizon + 1, -1)
        message = f"reached the iteration budget ({self.iterations}) in the compiled C step"
        late_blocks = int(record[setup.late])
        if late_blocks:
            message += (
                f"; the random-number thread was late with {late_blocks} of "
                f"{self.iterations - 1} blocks, drawn by the step itself"
            )
        if limit is not None and searched > limit:
            message = f"deadline: {limit:g} s exceeded by the full budget; {message}"
        tolerance = FEASIBILITY_TOLERANCE
        feasible = max(kinds["bound"], kinds["rate"], kinds["constraint"]) <= tolerance
        return SolveResult(
            solver=self.name,
            controls=problem.controls_from_scaled(scaled),
            states=states,
            cost=float(objective[0]),
            max_violation=max(kinds.values()),
            success=math.isfinite(fun) and feasible,
            status=message,
            solve_time=time.perf_counter() - start,
            iterations=self.iterations,
            evaluations=self.population * (self.iterations + 1),
            terminal_relaxed=kinds["terminal"] > tolerance and self._soft_terminal,
            iterate=Iterate(scaled_controls=scaled.reshape(horizon, -1), states=states),
            history=record[setup.history],
            details=SolveDetails(
                deadline_hit=limit is not None and searched > limit,
                extra={"fitness": fun, "violations": kinds, "evaluation": "compiled C step"},
            ),
        )

    def _candidate_archive(self, p: np.ndarray) -> CandidateArchive:
        """Make the archive of the ``candidates`` option, with the features of ``candidate_metric``."""
        return candidate_archive(
            self.problem,
            self._decode,
            self._rollout,
            self.candidates,
            self.candidate_metric,
            self.candidate_distance,
            p,
        )

    def _candidate_details(
        self, archive: CandidateArchive | None, outcome: MinimizeResult, offset: np.ndarray, p: np.ndarray
    ) -> dict[str, Any]:
        """``candidates`` and ``candidate_fitness`` of the ``candidates`` option (``{}`` for k = 1)."""
        if archive is None:
            return {}
        best = np.clip(outcome.x + offset, self._lower, self._upper)
        return candidate_details(
            self.problem, self._decode, archive, best, float(outcome.fun), self.candidates, p
        )

    def _native_fits(self, limit: float | None, start: float) -> bool:
        """Whether the all-C step (one uninterruptible call) may run under the deadline ``limit``.

        Only when the last search that used the whole budget (either path; the C step is the
        faster) took at most half of what is left: the two paths draw the same random numbers,
        so the choice never changes a result that the deadline does not stop.
        """
        if limit is None:
            return True
        full = self._full_search_seconds
        return full is not None and 2.0 * full <= limit - (time.perf_counter() - start)

    def _native_minimize(self, p, offset, lower, upper, seeds, rng) -> MinimizeResult:
        """Run the all-C IGWO step with exactly the random draws the Python loop would use."""
        generator = rng if rng is not None else np.random.default_rng(self.seed)
        algorithm = ImprovedGreyWolf(lower, upper, self.population, self.iterations, self.algorithm_options)
        seeds = np.empty((0, lower.size)) if seeds is None else seeds
        uniform = generator.random((self.population - seeds.shape[0], lower.size))
        positions = np.vstack([np.clip(seeds, lower, upper), lower + uniform * algorithm.width])
        if uses_pcg64(generator):
            draws = generator  # drawn inside the C step, the same numbers in the same order
        else:
            draws = generator.random((self.iterations, 8, self.population, lower.size))
        if self._schedules is None:
            steps = range(self.iterations)
            self._schedules = (
                np.array([algorithm._a(t) for t in steps]),
                np.array([algorithm._w(t) for t in steps]),
            )
        a, w = self._schedules
        options = algorithm.options
        native = self.native
        assert native is not None, "only called where the all-C step was built"
        # every array here is the solver's own, float64 and of the build's shapes: no re-checks
        c1, c2, threads = options["c1"], options["c2"], int(self.rng_thread)
        out = native._run(p, offset, lower, upper, positions, draws, a, w, c1, c2, threads)
        message = f"reached the iteration budget ({self.iterations}) in the compiled C step"
        if out["late_blocks"]:
            message += (
                f"; the random-number thread was late with {out['late_blocks']} of "
                f"{self.iterations - 1} blocks, drawn by the step itself"
            )
        return MinimizeResult(
            x=out["x"],
            fun=out["fun"],
            history=out["history"],
            evaluations=self.population * (self.iterations + 1),
            iterations=self.iterations,
            method="igwo",
            population=out["population"],
            message=message,
        )


def swarm_factory(method: str):
    """Return the registry's factory ``(problem, options) -> SwarmSolver`` for ``method``."""

    def factory(problem: Transcribed, options: dict[str, Any] | None = None) -> SwarmSolver:
        return SwarmSolver(problem, options, method=method)

    factory.__name__ = f"{method}_factory"
    factory.Options = swarm_options_class(method)  # type: ignore[attr-defined]  # what parse_options reads
    factory.OPTIONS = swarm_options(method)  # type: ignore[attr-defined]  # the declaration the docs read
    return factory
