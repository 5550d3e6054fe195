"""The loop every population optimiser shares, its result type and the box checks.

Every algorithm is a small subclass of :class:`PopulationAlgorithm` that implements only its
update rule (``initialize``/``propose``/``accept``); the shared loop in
:meth:`PopulationAlgorithm.run` owns initialisation in the box, evaluation, boundary handling
(clip to the box), best-so-far tracking, the history and the evaluation budget.  Adding an
algorithm means one new module with the subclass and one entry in
:data:`uuv_ocp.optimize.minimize.ALGORITHMS`.

Random-number layout (contract for a C port)
--------------------------------------------
All randomness comes from one ``numpy.random.Generator`` created by
``numpy.random.default_rng(seed)``.  The draws happen in this fixed order:

1. Initialisation: ``rng.random((population - k, dim))`` for the ``population - k``
   individuals that are not user seeds (``k = len(initial_population)``), mapped to the box as
   ``lower + u * (upper - lower)``; seeds occupy rows ``0 .. k-1``, random rows follow.
   Then the algorithm's own initial draws (only ``pso``: ``rng.random((population, dim))`` for
   the initial velocities).
2. Once per iteration, *before* the single call of ``fun``:

   * ``gwo``:  ``draws = rng.random((6, population, dim))`` -- one block, C order, i.e. the
     element ``draws[k, i, j]`` is uniform number ``(k * population + i) * dim + j`` of
     the iteration.  Planes: ``0 -> r1 of A1``, ``1 -> r2 of C1`` (leader alpha),
     ``2 -> r1 of A2``, ``3 -> r2 of C2`` (beta), ``4 -> r1 of A3``, ``5 -> r2 of C3`` (delta).
   * ``igwo``: ``draws = rng.random((8, population, dim))``, planes ``0..5`` exactly as ``gwo``,
     plane ``6 -> r1`` of the personal-best (memory) term, plane ``7 -> r2`` of the global-best
     term.
   * ``pso``:  ``draws = rng.random((2, population, dim))``; plane 0 -> cognitive ``r1``,
     plane 1 -> social ``r2``.
   * ``mppi``: ``rng.standard_normal((population, dim))``, the cloud around the mean (row 0 is
     replaced by the mean itself).
   * ``ssa``:  see :class:`uuv_ocp.optimize.ssa.SparrowSearch` (not meant for the C port; fixed
     order all the same).

The grey-wolf updates are the pure functions :func:`uuv_ocp.optimize.gwo.gwo_update` and
:func:`uuv_ocp.optimize.igwo.igwo_update`: fed the same positions, leaders, scalars and
``draws`` a C implementation reproduces them up to floating-point rounding (operation order is
spelled out in their docstrings).
"""

from __future__ import annotations

import math
import numbers
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "MinimizeResult",
    "Objective",
    "PopulationAlgorithm",
    "validate_bounds",
]

#: A vectorised objective: ``fun(X)`` with ``X`` of shape ``(population, dim)`` returns
#: ``(population,)`` costs.
Objective = Callable[[np.ndarray], Any]


# --------------------------------------------------------------------------------------------
# Result type
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, repr=False)
class MinimizeResult:
    """Outcome of :func:`uuv_ocp.optimize.minimize`.

    Attributes
    ----------
    x : numpy.ndarray, shape (dim,)
        Best point found (inside the box); if no finite cost was ever seen, the first point of
        the initial population.
    fun : float
        Cost at ``x`` (``inf`` if no finite cost was ever seen).
    history : numpy.ndarray, shape (iterations + 1,)
        Best-so-far cost after the initial population and after every iteration;
        non-increasing.
    evaluations : int
        Number of individual cost evaluations (rows passed to ``fun``), initial population
        included.
    iterations : int
        Iterations actually run (fewer than requested if ``max_evaluations`` or ``time_limit``
        stopped the run).
    method : str
        Algorithm name.
    population : numpy.ndarray, shape (population, dim)
        Positions of the final population (for warm starts).
    message : str
        Why the run stopped, or that the objective never returned a finite value.
    success : bool
        ``True`` iff a finite best cost was found (read-only property derived from ``fun``,
        so it cannot disagree with it).
    deadline_hit : bool
        Whether ``time_limit`` stopped the run before its iteration budget (``x`` is then the
        best point found so far).
    """

    x: np.ndarray
    fun: float
    history: np.ndarray
    evaluations: int
    iterations: int
    method: str
    population: np.ndarray
    message: str
    deadline_hit: bool = False

    @property
    def success(self) -> bool:
        """Whether a finite best cost was found."""
        return bool(math.isfinite(self.fun))

    def __repr__(self) -> str:
        """Return a one-line summary without the arrays' contents."""
        return (
            f"MinimizeResult(method={self.method!r}, fun={self.fun!r}, success={self.success}, "
            f"evaluations={self.evaluations}, iterations={self.iterations}, "
            f"message={self.message!r}, x.shape={np.shape(self.x)})"
        )


# --------------------------------------------------------------------------------------------
# Bound handling
# --------------------------------------------------------------------------------------------


def validate_bounds(lower: object, upper: object) -> tuple[np.ndarray, np.ndarray]:
    """Check box bounds and return them as two float arrays of shape ``(dim,)``.

    Parameters
    ----------
    lower, upper : array_like, shape (dim,), or scalar
        Finite bounds with ``lower < upper`` element-wise.  One of them may be a scalar,
        broadcast to the other's shape; two arrays must have equal shapes.

    Returns
    -------
    lower, upper : numpy.ndarray, shape (dim,)
        Fresh float copies.

    Raises
    ------
    ValueError
        Naming ``lower`` and/or ``upper``, what was expected and what came.
    """
    arrays = []
    for name, value in (("lower", lower), ("upper", upper)):
        try:
            arrays.append(np.asarray(value, dtype=float))
        except (TypeError, ValueError) as error:
            raise ValueError(f"{name} must be a real scalar or 1-D array, got {value!r}") from error
    lo, up = arrays
    if lo.ndim == 0 and up.ndim == 0:
        raise ValueError(
            "lower and upper: at least one must be a 1-D array of shape (dim,) to fix the "
            f"dimension, got scalars {lower!r} and {upper!r}"
        )
    for name, array in (("lower", lo), ("upper", up)):
        if array.ndim > 1 or (array.ndim == 1 and array.shape[0] < 1):
            raise ValueError(f"{name} must be a scalar or a 1-D array with dim >= 1, got shape {array.shape}")
    if lo.ndim == 1 and up.ndim == 1 and lo.shape != up.shape:
        raise ValueError(f"lower and upper must have equal shapes, got {lo.shape} and {up.shape}")
    lo, up = np.broadcast_arrays(lo, up)
    lo, up = lo.astype(float, copy=True), up.astype(float, copy=True)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(up))):
        raise ValueError(f"lower and upper must be finite, got {lower!r} and {upper!r}")
    if np.any(lo >= up):
        bad = int(np.argmax(lo >= up))
        raise ValueError(
            f"lower must be < upper element-wise, got lower[{bad}]={float(lo[bad]):g} "
            f">= upper[{bad}]={float(up[bad]):g}"
        )
    return lo, up


# --------------------------------------------------------------------------------------------
# The shared loop
# --------------------------------------------------------------------------------------------


class PopulationAlgorithm:
    """Base class: the loop every population optimiser shares.

    Subclasses set the class attributes and implement :meth:`initialize`, :meth:`propose` and
    :meth:`accept`.  Positions returned by :meth:`propose` are clipped to the box by the loop
    before evaluation.  Non-finite costs (NaN, ``±inf``) are replaced by ``+inf`` before the
    algorithm sees them, so they rank last.

    Parameters
    ----------
    lower, upper : numpy.ndarray, shape (dim,)
        Box bounds (validated by :func:`validate_bounds`).
    population, iterations : int
        Population size and iteration budget ``T``.
    options : mapping or None
        Algorithm parameters; keys must be in ``default_options``.
    """

    name: ClassVar[str] = ""
    default_population: ClassVar[int] = 20
    default_iterations: ClassVar[int] = 30
    default_options: ClassVar[Mapping[str, Any]] = {}

    def __init__(
        self,
        lower: np.ndarray,
        upper: np.ndarray,
        population: int,
        iterations: int,
        options: Mapping[str, Any] | None = None,
    ) -> None:
        self.lower = lower
        self.upper = upper
        self.width = upper - lower
        self.dim = lower.shape[0]
        self.population = population
        self.iterations = iterations
        self.options = self._merge_options(options)

    @classmethod
    def _merge_options(cls, options: Mapping[str, Any] | None) -> dict[str, Any]:
        merged = dict(cls.default_options)
        if options is None:
            return merged
        if not isinstance(options, Mapping):
            raise ValueError(f"options must be a mapping or None, got {options!r}")
        for key, value in options.items():
            if key not in merged:
                raise ValueError(
                    f"options: unknown option {key!r} for method {cls.name!r}; "
                    f"valid options are {sorted(merged)}"
                )
            default = merged[key]
            if isinstance(default, str):
                merged[key] = value
            elif (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not (math.isfinite(float(value)))
            ):
                raise ValueError(f"options[{key!r}] must be a finite real number, got {value!r}")
            else:
                merged[key] = float(value)
        return merged

    # -- hooks ---------------------------------------------------------------------------------

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        """Set the algorithm state from the evaluated initial population."""
        raise NotImplementedError

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Return the (unclipped) positions to evaluate at 0-based ``iteration``."""
        raise NotImplementedError

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        """Update the state with the evaluated (clipped) ``positions``."""
        raise NotImplementedError

    def final_population(self) -> np.ndarray:
        """Positions reported as :attr:`MinimizeResult.population`."""
        return self.positions.copy()

    # -- the loop ------------------------------------------------------------------------------

    def _evaluate(self, fun: Objective, positions: np.ndarray) -> np.ndarray:
        n = positions.shape[0]
        raw = fun(positions.copy())
        try:
            costs = np.asarray(raw, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"fun must return {n} real costs of shape ({n},) for a population of shape "
                f"{positions.shape}, got {type(raw).__name__} {raw!r:.200}"
            ) from error
        if costs.shape != (n,):
            costs = costs.reshape(-1) if costs.size == n else costs
        if costs.shape != (n,):
            raise ValueError(
                f"fun must return {n} costs of shape ({n},) "
                f"for a population of shape {positions.shape}, got shape {np.shape(costs)}"
            )
        return np.where(np.isfinite(costs), costs, np.inf)

    def run(
        self,
        fun: Objective,
        rng: np.random.Generator,
        initial_population: np.ndarray | None = None,
        max_evaluations: int | None = None,
        time_limit: float | None = None,
    ) -> MinimizeResult:
        """Run the optimiser (inputs already validated by :func:`uuv_ocp.optimize.minimize`).

        Parameters
        ----------
        fun : callable
            Vectorised objective, see :data:`Objective`.
        rng : numpy.random.Generator
            The only source of randomness (draw order in the module docstring).
        initial_population : numpy.ndarray, shape (k, dim), optional
            Seeds placed first (clipped to the box).
        max_evaluations : int, optional
            Stop before an iteration that would exceed this many evaluations.
        time_limit : float, optional
            Wall-clock seconds from the start of this call: checked after the initial
            population and after each iteration (an evaluation of ``fun`` is never
            interrupted); once exceeded, no further iteration starts and the best point so far
            is returned with ``deadline_hit=True``.

        Returns
        -------
        MinimizeResult
        """
        started = time.perf_counter()
        n = self.population
        seeds = np.empty((0, self.dim)) if initial_population is None else initial_population
        uniform = rng.random((n - seeds.shape[0], self.dim))
        positions = np.vstack([np.clip(seeds, self.lower, self.upper), self.lower + uniform * self.width])
        costs = self._evaluate(fun, positions)
        evaluations = n
        self.positions = positions
        self.initialize(positions, costs, rng)

        i_best = int(np.argmin(costs))
        best_x, best_f = positions[i_best].copy(), float(costs[i_best])
        history = [best_f]
        message = f"reached the iteration budget ({self.iterations})"
        done = 0
        deadline_hit = False
        for t in range(self.iterations):
            if max_evaluations is not None and evaluations + n > max_evaluations:
                message = (
                    f"stopped after {done} iterations: another iteration would exceed "
                    f"max_evaluations={max_evaluations}"
                )
                break
            if time_limit is not None and time.perf_counter() - started >= time_limit:
                deadline_hit = True
                message = (
                    f"stopped by the deadline: time_limit={time_limit:g} s exceeded after {done} of "
                    f"{self.iterations} iterations; x is the best point so far"
                )
                break
            positions = np.clip(self.propose(t, rng), self.lower, self.upper)
            costs = self._evaluate(fun, positions)
            evaluations += n
            self.positions = positions
            self.accept(positions, costs)
            i_best = int(np.argmin(costs))
            if costs[i_best] < best_f:
                best_x, best_f = positions[i_best].copy(), float(costs[i_best])
            history.append(best_f)
            done += 1
        if not math.isfinite(best_f):
            message = (
                f"fun returned no finite value (only NaN or inf) in all {evaluations} evaluations; "
                f"x is the first point of the initial population ({message})"
            )
        return MinimizeResult(
            x=best_x,
            fun=best_f,
            history=np.asarray(history, dtype=float),
            evaluations=evaluations,
            iterations=done,
            method=self.name,
            population=self.final_population(),
            message=message,
            deadline_hit=deadline_hit,
        )
