"""Model predictive path integral control (MPPI) on the swarms' batched rollout and cost.

MPPI works in the swarms' search coordinates ``W ∈ [-1, 1]^{nu N}``
(:func:`uuv_ocp.transcription.condensed.decode`): ``z_k = lo_k + (w_k + 1)/2 · (hi_k − lo_k)``
with ``[lo_k, hi_k]`` the control box intersected with the rate window ``[z_{k−1} − r,
z_{k−1} + r]`` (``z_{−1}`` the last applied control).  Without rate bounds ``W`` are the scaled
controls themselves; with them ``w_k`` is the position of ``z_k`` in its rate window, i.e. a
clipped increment, so a perturbation of ``W`` is a perturbation of the increments and every
sample is a random walk clipped cumulatively.  Each iteration perturbs the nominal ``W̄``,
clips every sample into ``[-1, 1]`` (so it holds the box **and** the rate bound by
construction), evaluates all of them in one call of the same batched fitness the swarms use
(:mod:`uuv_ocp.solvers.swarm`: the problem's RK4 rollout, objective + exact L1 penalties of
the terminal equality, the rate excess and the hard constraints; compiled by default) and
replaces the nominal by the importance-weighted mean::

    W_i = clip(W̄ + ε_i, −1, 1),  ε_i,k ~ N(0, Σ)    (ε_i,k AR(1)-correlated over k by ``smoothing``)
    S_i = fitness(W_i; p),   w_i = exp(−(S_i − min_j S_j) / λ) / Σ_j exp(−(S_j − min_j S_j) / λ)
    W̄ ← Σ_i w_i W_i

``Σ`` (``noise``) is in the units of ``W`` (a fraction of the half-width of each control's
feasible interval at that stage), ``λ`` (``temperature``) in cost units.  Sample 0 is the
nominal itself (``ε_0 = 0``).  The mean is a convex combination of points of ``[-1, 1]^{nu N}``,
so it holds both bounds too.  With ``keep_best=True`` (default) the best sample evaluated
replaces the final mean when its fitness is lower (one extra fitness evaluation per solve).
The control-cost term ``γ W̄ᵀ Σ⁻¹ ε`` of information-theoretic MPPI is left out: it only
shifts the weights toward small controls, which the problem's own control cost already does.

Warm start: in a closed loop the nominal is the shifted previous plan (``warm_start``), else
the last applied control held over the horizon.  Randomness only through the generator passed
to :meth:`MppiSolver.solve` (``rng``; :class:`~uuv_ocp.control.NMPC` passes its own), or
``numpy.random.default_rng(seed)`` per solve.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import FEASIBILITY_TOLERANCE, score_terms
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.runtime import COMPILED_ENV, compiled_build
from uuv_ocp.optimize.mppi import importance_weights
from uuv_ocp.solvers.options import (
    AUTO,
    Check,
    among,
    boolean,
    declaration,
    one_of,
    option,
    optional,
    parse_options,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Iterate, SolveDetails, SolveResult
from uuv_ocp.solvers.swarm import (
    CANDIDATE_DISTANCE,
    CANDIDATE_METRICS,
    BufferedFitness,
    CandidateArchive,
    _compiled_choice,
    _compiled_default,
    candidate_archive,
    candidate_details,
)
from uuv_ocp.transcription.condensed import batched_fitness, candidate_fitness, encode

__all__ = ["MppiOptions", "MppiSolver"]


def _samples(label: str, value: Any) -> int:
    return check.positive_int(label, value, minimum=2)


def _nonnegative_int(label: str, value: Any) -> int:
    return check.positive_int(label, value, minimum=0)


def _smoothing(label: str, value: Any) -> float:
    number = check.nonnegative_float(label, value)
    if number >= 1.0:
        raise ValueError(f"{label} must be in [0, 1), got {check.shown(value)}")
    return number


def _noise(label: str, value: Any) -> float | tuple:
    """Accept a std > 0 for every control, one std > 0 per control, or a covariance (nu × nu, SPD)."""
    if isinstance(value, bool):
        raise ValueError(
            f"{label} must be a float > 0, a tuple of them or a covariance matrix, got {value!r}"
        )
    if isinstance(value, int | float | np.floating | np.integer):
        return check.positive_float(label, value)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = np.empty(0)
    expected = "a float > 0, a tuple of stds > 0 (one per control) or a covariance matrix (nu x nu, SPD)"
    if array.ndim == 1 and array.size and np.all(np.isfinite(array)) and np.all(array > 0):
        return tuple(float(v) for v in array)
    if array.ndim == 2 and array.shape[0] == array.shape[1] and array.size and np.all(np.isfinite(array)):
        if np.allclose(array, array.T):
            try:
                np.linalg.cholesky(array)
            except np.linalg.LinAlgError:
                pass
            else:
                return tuple(tuple(float(v) for v in row) for row in array)
    raise ValueError(f"{label} must be {expected}, got {check.shown(value)}")


def _or_auto(inner: Check) -> Check:
    def checked(label: str, value: Any) -> Any:
        return value if value is AUTO else inner(label, value)

    return checked


@dataclasses.dataclass(frozen=True)
class MppiOptions:
    """Options of the ``"mppi"`` backend (each validated here and by :func:`parse_options`)."""

    samples: int = option(
        256, "int >= 2", "control sequences sampled per iteration (the first is the nominal)", check=_samples
    )
    iterations: int = option(
        1,
        "int >= 1",
        "sample-and-average updates per solve",
        meaning="one update per control step, warm-started (real-time MPPI); raise it for a cold solve",
        check=positive_int,
    )
    temperature: float = option(
        10.0,
        "float > 0",
        "λ of the weights exp(−(S − min S)/λ); smaller = greedier",
        unit="cost",
        check=positive_float,
    )
    noise: Any = option(
        0.2,
        "float > 0, tuple of nu stds or nu x nu covariance",
        "std (or covariance) of the Gaussian perturbation of the search coordinates W, per stage",
        unit="W (feasible half-width)",
        check=_noise,
    )
    smoothing: float = option(
        0.5,
        "float in [0, 1)",
        "correlation of the perturbation between consecutive stages (AR(1) over the horizon)",
        check=_smoothing,
    )
    seed: int = option(
        0,
        "int >= 0",
        "seed of `numpy.random.default_rng` when the caller passes no generator",
        check=_nonnegative_int,
    )
    keep_best: bool = option(
        True,
        "`True` or `False`",
        "return the best sample evaluated if it beats the final mean",
        check=boolean,
    )
    compiled: Any = option(
        "auto",
        '`"auto"`, `True` or `False`',
        "the swarms' compiled SIMD batched fitness (a problem's first build takes a while)",
        meaning=f"compiled wherever a C compiler exists, unless the environment sets `{COMPILED_ENV}=0`",
        check=_compiled_choice,
    )
    deadline: float | None = option(
        None,
        "float > 0 or `None`",
        "wall-time budget of one solve, checked after every iteration",
        unit="s",
        meaning="none",
        check=optional(positive_float),
    )
    candidates: int = option(
        1,
        "int >= 1",
        'k > 1: up to k distinct good samples of the run in `details["candidates"]`',
        check=positive_int,
    )
    candidate_metric: str = option(
        "states",
        one_of(CANDIDATE_METRICS),
        "distance between candidates: predicted states (over their initial spread) or search coordinates",
        check=among(CANDIDATE_METRICS),
    )
    candidate_distance: Any = option(
        AUTO,
        "float > 0",
        "RMS distance by which two candidates must differ",
        meaning=", ".join(f'{d:g} for `candidate_metric="{m}"`' for m, d in CANDIDATE_DISTANCE.items()),
        check=_or_auto(positive_float),
    )

    def __post_init__(self) -> None:
        """Validate every field (also when the dataclass is built directly, not by the parser)."""
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            checker = field.metadata["option"].check
            if value is AUTO and field.default is AUTO:
                continue
            object.__setattr__(self, field.name, checker(f"MppiOptions.{field.name}", value))


MPPI_OPTIONS = declaration(MppiOptions)


class MppiSolver:
    """MPPI (see the module doc) as a backend of any problem with finite control bounds.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
        Every control needs finite box bounds (the samples are projected into them).
    options : dict, optional
        :class:`MppiOptions` by name.
    """

    name = "mppi"
    Options = MppiOptions
    OPTIONS = MPPI_OPTIONS
    time_limited = True  # solve(..., time_limit=)

    def __init__(self, problem: Transcribed, options: dict[str, Any] | None = None) -> None:
        settings = parse_options(MppiOptions, options, self.name)
        self.settings = settings
        self.problem = problem
        # the options as attributes (what tests/solvers/test_options.py reads back)
        self.samples: int = settings.samples
        self.iterations: int = settings.iterations
        self.temperature: float = settings.temperature
        self.noise: float | tuple = settings.noise
        self.smoothing: float = settings.smoothing
        self.seed: int = settings.seed
        self.keep_best: bool = settings.keep_best
        self.compiled: bool = _compiled_default(settings.compiled)
        self.deadline: float | None = settings.deadline
        self.candidates: int = settings.candidates
        self.candidate_metric: str = settings.candidate_metric
        distance = settings.candidate_distance
        self.candidate_distance: float = (
            CANDIDATE_DISTANCE[self.candidate_metric] if distance is AUTO else distance
        )
        spec = problem.spec()
        if not (np.all(np.isfinite(spec.lower)) and np.all(np.isfinite(spec.upper))):
            raise ValueError(
                f"solver {self.name!r} projects samples into a box: every control needs finite lower and "
                f"upper bounds, got lower={spec.lower}, upper={spec.upper}"
            )
        self._horizon, self._nu = spec.horizon, spec.control_size
        self._chol = self._noise_factor(settings.noise, self._nu)
        diagonal = np.count_nonzero(self._chol - np.diag(np.diag(self._chol))) == 0
        self._std: np.ndarray | None = np.diag(self._chol).copy() if diagonal else None
        self._decode = BufferedFunction(problem.build().decode)
        self._single = BufferedFunction(candidate_fitness(problem))
        self._score_terms: BufferedFunction | None = None
        self._rollout: BufferedFunction | None = None
        self.evaluation = "virtual machine"
        fitness = None
        if self.compiled:
            build = compiled_build(problem, self.samples)  # warns once if no compiler
            if build is not None:
                fitness = build["cost_batch"]
                self._score_terms = BufferedFunction(build["score_terms"])
                self._rollout = BufferedFunction(build["rollout"])
                self.evaluation = "compiled"
        if fitness is None:
            fitness = batched_fitness(problem, self.samples)
        self._evaluate = BufferedFitness(fitness, self.samples, problem.control_dim, problem.parameter_dim)

    @staticmethod
    def _noise_factor(noise: float | tuple, nu: int) -> np.ndarray:
        """Lower Cholesky factor ``L`` (nu, nu) of the per-stage covariance Σ = L Lᵀ."""
        if isinstance(noise, float):
            return noise * np.eye(nu)
        array = np.asarray(noise, dtype=float)
        if array.shape not in ((nu,), (nu, nu)):
            raise ValueError(
                f"options['noise'] of 'mppi' must have one std per control ({nu}) or be {nu} x {nu}, "
                f"got shape {array.shape}"
            )
        return np.diag(array) if array.ndim == 1 else np.linalg.cholesky(array)

    def _perturbations(self, generator: np.random.Generator) -> np.ndarray:
        """Noise (S, N nu): Gaussian with covariance Σ per stage, AR(1)-correlated over stages."""
        # stage-major (N, S, nu): each stage a contiguous block for the in-place AR(1) filter
        white = generator.standard_normal((self._horizon, self.samples, self._nu))
        if self.smoothing > 0.0:
            # stationary AR(1): every stage keeps the covariance Σ, neighbours correlate by β
            beta, gain = self.smoothing, math.sqrt(1.0 - self.smoothing**2)
            carried = np.empty_like(white[0])
            for k in range(1, self._horizon):
                np.multiply(white[k - 1], beta, out=carried)
                white[k] *= gain
                white[k] += carried
        if self._std is not None:  # a diagonal Σ scales each control (cheaper than the product with L)
            white *= self._std
        else:
            white = white @ self._chol.T
        noise = white.transpose(1, 0, 2).reshape(self.samples, -1)  # a copy, sample-major
        noise[0] = 0.0  # sample 0 is the nominal itself
        return noise

    def weights(self, values: np.ndarray) -> np.ndarray:
        """Return the importance weights of fitness ``values`` (S,): softmax of −values/λ, non-finite -> 0."""
        return importance_weights(values, self.temperature)

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
    ) -> SolveResult:
        """One MPPI solve (``iterations`` updates) of the instance with parameter vector ``p``.

        ``time_limit`` (seconds from the call) overrides the ``deadline`` option for this call.
        """
        start = time.perf_counter()
        limit = self.deadline if time_limit is None else check.positive_float("time_limit", time_limit)
        problem = self.problem
        generator = rng if rng is not None else np.random.default_rng(self.seed)
        previous = problem.previous_scaled(p)
        if warm_start is not None:
            plan = np.asarray(warm_start.scaled_controls, dtype=float)
        else:
            plan = np.tile(previous, (self._horizon, 1))
        nominal = encode(problem.spec(), plan, previous)  # projected onto the bounds first
        archive: CandidateArchive | None = None
        if self.candidates > 1:
            archive = candidate_archive(
                problem,
                self._decode,
                self._rollout,
                self.candidates,
                self.candidate_metric,
                self.candidate_distance,
                p,
            )
        best_w, best_value = None, np.inf
        history: list[float] = []
        done, deadline_hit = 0, False
        for _ in range(self.iterations):
            coordinates = self._perturbations(generator)
            coordinates += nominal
            np.clip(coordinates, -1.0, 1.0, out=coordinates)
            values = self._evaluate(coordinates, p)
            if archive is not None:
                archive.add(coordinates, values)
            index = int(np.argmin(np.where(np.isfinite(values), values, np.inf)))
            if values[index] < best_value:
                best_w, best_value = coordinates[index].copy(), float(values[index])
            history.append(best_value)
            nominal = self.weights(values) @ coordinates  # a convex combination: inside [-1, 1]
            done += 1
            if limit is not None and time.perf_counter() - start > limit and done < self.iterations:
                deadline_hit = True
                break
        mean_w = np.clip(nominal, -1.0, 1.0)  # rounding only
        mean_value = float(self._single(mean_w, p)[0][0])
        evaluations = done * self.samples + 1
        chosen_w, chosen_value, chosen = mean_w, mean_value, "mean"
        if self.keep_best and best_w is not None and best_value < mean_value:
            chosen_w, chosen_value, chosen = best_w, best_value, "best sample"
        (scaled,) = self._decode(chosen_w, p)
        cost, kinds = score_terms(problem, scaled, p, self._score_terms)
        feasible = max(kinds["bound"], kinds["rate"], kinds["constraint"]) <= FEASIBILITY_TOLERANCE
        states = problem.rollout_scaled(scaled, p, self._rollout)
        searched = time.perf_counter() - start
        late = limit is not None and searched > limit
        message = f"{done} MPPI iterations of {self.samples} samples; returned the {chosen}"
        if deadline_hit:
            message = (
                f"deadline: {limit:g} s reached after {done} of {self.iterations} iterations; " + message
            )
        elif late:
            message = f"deadline: {limit:g} s exceeded by the full budget; " + message
        details: dict[str, Any] = {
            "fitness": chosen_value,
            "mean_fitness": mean_value,
            "best_sample_fitness": best_value,
            "returned": chosen,
            "violations": kinds,
            "deadline_hit": deadline_hit or late,
            "evaluation": self.evaluation,
        }
        if archive is not None:
            details.update(
                candidate_details(problem, self._decode, archive, chosen_w, chosen_value, self.candidates, p)
            )
        return SolveResult(
            solver=self.name,
            controls=problem.controls_from_scaled(scaled),
            states=states,
            cost=cost,
            max_violation=max(kinds.values()),
            success=bool(np.isfinite(chosen_value)) and feasible,
            status=message,
            solve_time=time.perf_counter() - start,
            iterations=done,
            evaluations=evaluations,
            terminal_relaxed=problem.soft_terminal_available and kinds["terminal"] > FEASIBILITY_TOLERANCE,
            iterate=Iterate(scaled_controls=scaled.reshape(self._horizon, self._nu), states=states),
            history=np.asarray(history),
            details=SolveDetails.of(details),
        )
