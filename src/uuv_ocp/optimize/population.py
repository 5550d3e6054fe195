"""Vectorised population optimisers sharing one loop: ``igwo``, ``gwo``, ``ssa``, ``pso``.

The front door is :func:`minimize` (scipy-like: one function, one result type).  The objective
is *vectorised*: ``fun(X)`` receives the whole population ``X`` of shape ``(population, dim)``
and returns ``(population,)`` costs, and it is called exactly once per iteration (plus once for
the initial population).  This is what lets the NMPC map a compiled CasADi cost over the
population instead of looping over individuals in Python.

Every algorithm is a small subclass of :class:`PopulationAlgorithm` that implements only its
update rule (``initialize``/``propose``/``accept``); the shared loop in
:meth:`PopulationAlgorithm.run` owns initialisation in the box, evaluation, boundary handling
(clip to the box), best-so-far tracking, the history and the evaluation budget.  Adding an
algorithm touches this file only: write the subclass and add it to :data:`ALGORITHMS`.

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
   * ``ssa``:  see :class:`SparrowSearch` (not meant for the C port; fixed order all the same).

The grey-wolf updates are the pure functions :func:`gwo_update` and :func:`igwo_update`: fed
the same positions, leaders, scalars and ``draws`` a C implementation reproduces them up to
floating-point rounding (operation order is spelled out in their docstrings).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from uuv_ocp._validation import choice, positive_int

__all__ = [
    "ALGORITHMS",
    "CONVERGENCE_FACTORS",
    "GreyWolf",
    "ImprovedGreyWolf",
    "MinimizeResult",
    "PAPER_CONVERGENCE_LABELS",
    "ParticleSwarm",
    "PopulationAlgorithm",
    "SparrowSearch",
    "available_methods",
    "convergence_factor",
    "gwo_update",
    "igwo_update",
    "minimize",
]

Objective = Callable[[np.ndarray], Any]

# --------------------------------------------------------------------------------------------
# Convergence factor a(t) of the grey-wolf family (paper Figure 5)
# --------------------------------------------------------------------------------------------


def _linear(s: np.ndarray) -> np.ndarray:
    return 1.0 - s


def _cosine(s: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.cos(np.pi * s))


def _faster(s: np.ndarray) -> np.ndarray:
    return 1.0 - s * s


def _slower(s: np.ndarray) -> np.ndarray:
    return (1.0 - s) * (1.0 - s)


#: Normalised decay shapes ``g(s)``, ``s = t/T``, with ``g(0) = 1`` and ``g(1) = 0``; the factor
#: is ``a = a_final + (a_initial - a_final) g(t/T)``.
CONVERGENCE_FACTORS: Mapping[str, Callable[[np.ndarray], np.ndarray]] = {
    "linear": _linear,  # GWO: a = 2 - 2 t/T
    "cosine": _cosine,  # IGWO (paper): a = a_f + (a_i - a_f)(1 + cos(pi t/T))/2
    "faster": _faster,  # decays gradually faster: a = 2 (1 - (t/T)^2)
    "slower": _slower,  # decays gradually slower: a = 2 (1 - t/T)^2
}

#: Curve names used in the paper's Figure 5 for each ``kind``.
PAPER_CONVERGENCE_LABELS: Mapping[str, str] = {
    "linear": "linear_a",
    "faster": "non_linear_a_1",
    "slower": "non_linear_a_2",
    "cosine": "non_linear_a_3",
}


def convergence_factor(
    iteration: float | np.ndarray,
    iterations: int,
    kind: str = "linear",
    *,
    a_initial: float = 2.0,
    a_final: float = 0.0,
) -> float | np.ndarray:
    """Convergence factor ``a(t)`` of the grey-wolf optimisers.

    Parameters
    ----------
    iteration : float or numpy.ndarray
        Current iteration ``t`` (0-based); arrays are evaluated element-wise.
    iterations : int
        Iteration budget ``T`` (>= 1).
    kind : {"linear", "cosine", "faster", "slower"}
        ``"linear"``: ``a = a_i - (a_i - a_f) t/T`` (GWO, Mirjalili et al. 2014);
        ``"cosine"``: ``a = a_f + ½ (a_i - a_f)(1 + cos(π t/T))`` (IGWO, the paper's §3.3.1);
        ``"faster"``: ``a = a_f + (a_i - a_f)(1 - (t/T)²)`` (the paper's ``non_linear_a_1``);
        ``"slower"``: ``a = a_f + (a_i - a_f)(1 - t/T)²`` (the paper's ``non_linear_a_2``).
    a_initial, a_final : float
        Values at ``t = 0`` and ``t = T`` (paper: 2 and 0).

    Returns
    -------
    float or numpy.ndarray
        ``a(t)``; a float for scalar ``iteration``.
    """
    iterations = positive_int("iterations", iterations, 1)
    if kind not in CONVERGENCE_FACTORS:
        raise ValueError(f"kind must be one of {sorted(CONVERGENCE_FACTORS)}, got {kind!r}")
    s = np.asarray(iteration, dtype=float) / float(iterations)
    value = a_final + (a_initial - a_final) * CONVERGENCE_FACTORS[kind](s)
    return float(value) if np.ndim(value) == 0 else value


# --------------------------------------------------------------------------------------------
# Pure grey-wolf updates (the part a C port reproduces)
# --------------------------------------------------------------------------------------------


def gwo_update(
    positions: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    delta: np.ndarray,
    a: float,
    draws: np.ndarray,
) -> np.ndarray:
    """Mean of the three leader moves ``(X1 + X2 + X3) / 3`` (Mirjalili et al. 2014).

    For leader ``L_k`` (``k = 1, 2, 3`` for α, β, δ), element-wise::

        A_k = 2 a r1_k - a            r1_k = draws[2(k-1)]
        C_k = 2 r2_k                  r2_k = draws[2(k-1) + 1]
        X_k = L_k - A_k |C_k L_k - X|

    and the result is ``((X1 + X2) + X3) / 3`` (summed in that order).  No clipping here.

    Parameters
    ----------
    positions : numpy.ndarray, shape (n, d)
        Current positions ``X``.
    alpha, beta, delta : numpy.ndarray, shape (d,)
        The three leaders.
    a : float
        Convergence factor ``a(t)``.
    draws : numpy.ndarray, shape (>= 6, n, d)
        Uniform numbers in ``[0, 1)``; planes 0..5 as in the module docstring.

    Returns
    -------
    numpy.ndarray, shape (n, d)
        Unclipped new positions.
    """
    moves = []
    for k, leader in enumerate((alpha, beta, delta)):
        A = 2.0 * a * draws[2 * k] - a
        C = 2.0 * draws[2 * k + 1]
        moves.append(leader - A * np.abs(C * leader - positions))
    return (moves[0] + moves[1] + moves[2]) / 3.0


def igwo_update(
    positions: np.ndarray,
    pbest: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    delta: np.ndarray,
    gbest: np.ndarray,
    a: float,
    w: float,
    draws: np.ndarray,
    c1: float = 0.5,
    c2: float = 0.5,
    anchor: np.ndarray | None = None,
) -> np.ndarray:
    """Memory-guided IGWO position update (paper §3.3.1).

    Element-wise, with ``G = gwo_update(positions, alpha, beta, delta, a, draws)``::

        X(t+1) = w G + c1 r1 (X_pbest - X) + c2 r2 (X_gbest - X)
               = ((w * G) + ((c1 * r1) * (pbest - X))) + ((c2 * r2) * (gbest - X))

    with ``r1 = draws[6]``, ``r2 = draws[7]`` (the right-hand form fixes the evaluation order).
    No clipping here.

    The inertia ``w < 1`` scales positions toward the *origin*: if all wolves sat on the
    optimum ``x*`` the update would return ``w x*``, so the paper's rule only settles on optima
    at 0 (fine for scaled controls near zero, poor for shifted optima); GWO's ``|C L - X|`` is
    origin-dependent too.  ``anchor`` (not in the paper; ``None`` = paper) evaluates the whole
    update in coordinates centred on ``anchor``: every position argument minus ``anchor``, the
    result plus ``anchor`` (see the ``frame`` option of :class:`ImprovedGreyWolf`).

    Parameters
    ----------
    positions : numpy.ndarray, shape (n, d)
        Current positions ``X``.
    pbest : numpy.ndarray, shape (n, d)
        Personal best position of every wolf.
    alpha, beta, delta : numpy.ndarray, shape (d,)
        The three leaders.
    gbest : numpy.ndarray, shape (d,)
        Global best position so far.
    a, w : float
        Convergence factor ``a(t)`` and inertia weight ``w(t)``.
    draws : numpy.ndarray, shape (8, n, d)
        Uniform numbers in ``[0, 1)``; layout in the module docstring.
    c1, c2 : float
        Individual and global learning factors (paper: 0.5 and 0.5).

    Returns
    -------
    numpy.ndarray, shape (n, d)
        Unclipped new positions.
    """
    if anchor is not None:
        centred = [v - anchor for v in (positions, pbest, alpha, beta, delta, gbest)]
        return anchor + igwo_update(*centred, a, w, draws, c1, c2)
    grey = gwo_update(positions, alpha, beta, delta, a, draws)
    return (w * grey + (c1 * draws[6]) * (pbest - positions)) + (c2 * draws[7]) * (gbest - positions)


# --------------------------------------------------------------------------------------------
# Result type
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MinimizeResult:
    """Outcome of :func:`minimize`.

    Attributes
    ----------
    x : numpy.ndarray, shape (dim,)
        Best point found (inside the box).
    fun : float
        Cost at ``x`` (``inf`` if no finite cost was ever seen).
    history : numpy.ndarray, shape (iterations + 1,)
        Best-so-far cost after the initial population and after every iteration;
        non-increasing.
    evaluations : int
        Number of individual cost evaluations (rows passed to ``fun``), initial population
        included.
    iterations : int
        Iterations actually run (fewer than requested if ``max_evaluations`` stopped the run).
    method : str
        Algorithm name.
    population : numpy.ndarray, shape (population, dim)
        Positions of the final population (for warm starts).
    message : str
        Why the run stopped.
    """

    x: np.ndarray
    fun: float
    history: np.ndarray
    evaluations: int
    iterations: int
    method: str
    population: np.ndarray
    message: str


# --------------------------------------------------------------------------------------------
# The shared loop
# --------------------------------------------------------------------------------------------


class PopulationAlgorithm:
    """Base class: the loop every population optimiser shares.

    Subclasses set the class attributes and implement :meth:`initialize`, :meth:`propose` and
    :meth:`accept`.  Positions returned by :meth:`propose` are clipped to the box by the loop
    before evaluation.

    Parameters
    ----------
    lower, upper : numpy.ndarray, shape (dim,)
        Box bounds (validated by :func:`minimize`).
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
        costs = np.asarray(fun(positions.copy()), dtype=float)
        if costs.shape != (positions.shape[0],):
            costs = costs.reshape(-1) if costs.size == positions.shape[0] else costs
        if costs.shape != (positions.shape[0],):
            raise ValueError(
                f"fun must return {positions.shape[0]} costs of shape ({positions.shape[0]},) "
                f"for a population of shape {positions.shape}, got shape {np.shape(costs)}"
            )
        return np.where(np.isfinite(costs), costs, np.inf)

    def run(
        self,
        fun: Objective,
        rng: np.random.Generator,
        initial_population: np.ndarray | None = None,
        max_evaluations: int | None = None,
    ) -> MinimizeResult:
        """Run the optimiser (inputs already validated by :func:`minimize`)."""
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
        for t in range(self.iterations):
            if max_evaluations is not None and evaluations + n > max_evaluations:
                message = (
                    f"stopped after {done} iterations: another iteration would exceed "
                    f"max_evaluations={max_evaluations}"
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
        return MinimizeResult(
            x=best_x,
            fun=best_f,
            history=np.asarray(history, dtype=float),
            evaluations=evaluations,
            iterations=done,
            method=self.name,
            population=self.final_population(),
            message=message,
        )


# --------------------------------------------------------------------------------------------
# Algorithms
# --------------------------------------------------------------------------------------------


class GreyWolf(PopulationAlgorithm):
    """Grey wolf optimiser (Mirjalili, Mirjalili & Lewis 2014), memoryless.

    ``a`` decays linearly 2 -> 0 (``a(t)`` evaluated at ``t = 0 .. T-1``); ``A = 2 a r1 - a``,
    ``C = 2 r2``; ``X(t+1) = (X1 + X2 + X3)/3`` (:func:`gwo_update`).  The leaders α, β, δ are
    the three best points seen so far (best three of the previous leaders and the newly
    evaluated wolves, as in the authors' reference code); positions are *not* greedily
    selected, so wolves may move to worse points.

    Options: ``a_initial`` (2), ``a_final`` (0), ``convergence`` (``"linear"``; any kind of
    :func:`convergence_factor`).
    """

    name = "gwo"
    default_population = 30
    default_iterations = 40
    default_options: ClassVar[Mapping[str, Any]] = {
        "a_initial": 2.0,
        "a_final": 0.0,
        "convergence": "linear",
    }
    n_draws: ClassVar[int] = 6

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        choice("options['convergence']", self.options["convergence"], sorted(CONVERGENCE_FACTORS))

    def _a(self, t: int) -> float:
        return float(
            convergence_factor(
                t,
                self.iterations,
                self.options["convergence"],
                a_initial=self.options["a_initial"],
                a_final=self.options["a_final"],
            )
        )

    def _update_leaders(self, positions: np.ndarray, costs: np.ndarray) -> None:
        pool_x = np.vstack([self.leaders, positions])
        pool_f = np.concatenate([self.leader_costs, costs])
        top = np.argsort(pool_f, kind="stable")[:3]
        self.leaders = pool_x[top].copy()
        self.leader_costs = pool_f[top].copy()

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        self.leaders = np.empty((0, self.dim))
        self.leader_costs = np.empty(0)
        self._update_leaders(positions, costs)

    def _draws(self, rng: np.random.Generator) -> np.ndarray:
        return rng.random((self.n_draws, self.population, self.dim))

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        draws = self._draws(rng)
        alpha, beta, delta = self.leaders
        return gwo_update(self.positions, alpha, beta, delta, self._a(iteration), draws)

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        self._update_leaders(positions, costs)


class ImprovedGreyWolf(GreyWolf):
    """IGWO of the paper (§3.3.1): cosine convergence factor plus a memory-guided update.

    Reading of the garbled text (the equations around the paper's Eqs. 12-18; the extracted PDF
    lost the operators, e.g. ``a = 1 2 a i n i t i a l a f i n a l + c o s π × t M a x i t e r``):

    * convergence factor: ``a(t) = a_final + ½ (a_initial - a_final)(1 + cos(π t/T))`` with
      ``a_initial = 2``, ``a_final = 0`` (so ``a(0) = 2``, ``a(T/2) = 1``, ``a(T) = 0``;
      the surviving tokens "½ ... a_initial a_final + cos(π t / Maxiter)" only make sense with
      ``a_final`` added outside, which reduces to ``1 + cos(π t/T)`` for the paper's values);
    * ``X1, X2, X3`` the usual GWO moves toward α, β, δ (paper's GWO equations);
    * memory update ``X(t+1) = w (X1 + X2 + X3)/3 + c1 r1 (X_pbest - X) + c2 r2 (X_gbest - X)``
      with ``c1 = c2 = 0.5`` and ``r1, r2 ~ U[0, 1]`` drawn per element;
    * inertia ``w(t) = (T - t)/T · (w_initial - w_final) + w_final``, ``w: 0.9 -> 0.1``.

    ``t`` runs over ``0 .. T-1`` for the ``T`` updates.  ``X_pbest`` is each wolf's best
    position so far (kept per wolf), ``X_gbest`` the best point found so far (= α).  Leaders as
    in :class:`GreyWolf`.  The update is the pure function :func:`igwo_update`.

    Options: ``a_initial`` (2), ``a_final`` (0), ``convergence`` (``"cosine"``),
    ``w_initial`` (0.9), ``w_final`` (0.1), ``c1`` (0.5), ``c2`` (0.5), ``frame``
    (``"origin"`` = paper; ``"alpha"`` computes each update in coordinates centred on the
    current α wolf -- an extension, not in the paper, that removes the paper rule's pull toward
    0, see :func:`igwo_update`).
    """

    name = "igwo"
    default_population = 20
    default_iterations = 30
    default_options: ClassVar[Mapping[str, Any]] = {
        "a_initial": 2.0,
        "a_final": 0.0,
        "convergence": "cosine",
        "w_initial": 0.9,
        "w_final": 0.1,
        "c1": 0.5,
        "c2": 0.5,
        "frame": "origin",
    }
    n_draws: ClassVar[int] = 8

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        choice("options['frame']", self.options["frame"], ["alpha", "origin"])

    def _w(self, t: int) -> float:
        T = self.iterations
        w0, w1 = self.options["w_initial"], self.options["w_final"]
        return (T - t) / T * (w0 - w1) + w1

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        super().initialize(positions, costs, rng)
        self.pbest = positions.copy()
        self.pbest_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        draws = self._draws(rng)
        alpha, beta, delta = self.leaders
        return igwo_update(
            self.positions,
            self.pbest,
            alpha,
            beta,
            delta,
            alpha,
            self._a(iteration),
            self._w(iteration),
            draws,
            self.options["c1"],
            self.options["c2"],
            alpha if self.options["frame"] == "alpha" else None,
        )

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        super().accept(positions, costs)
        better = costs < self.pbest_costs
        self.pbest[better] = positions[better]
        self.pbest_costs[better] = costs[better]


class SparrowSearch(PopulationAlgorithm):
    """Sparrow search algorithm (Xue & Shen 2020), one evaluation of the swarm per iteration.

    The swarm is the memory ``P`` of every sparrow's best position (greedy: a sparrow keeps
    its new position only if it is better, as in the authors' reference code).  Each
    iteration, with sparrows ranked ``i = 1 .. n`` by cost (best first), ``X_best``/``X_worst``
    the best/worst memory and ``T`` the iteration budget:

    * producers (best ``round(producers · n)``): if the alarm ``R2 ~ U[0,1] < ST``,
      ``X_i · exp(-i / (r_i T))`` with ``r_i ~ U(0,1]`` (wide search), else ``X_i + Q_i L``
      with ``Q_i ~ N(0,1)`` and ``L`` a row of ones;
    * scroungers: for ``i > n/2`` (starving) ``Q_i exp((X_worst - X_i)/i²)``, else
      ``X_best + (|X_i - X_best| · A⁺) L`` with ``A`` a random ±1 row and
      ``A⁺ = Aᵀ (A Aᵀ)⁻¹`` (so every coordinate moves by ``mean(A ∘ |X_i - X_best|)``);
    * danger-aware sparrows (a random ``round(scouts · n)`` of the swarm, whose move replaces
      the one above): if ``f_i > f_best``, ``X_best + β ∘ |X_i - X_best|`` with
      ``β ~ N(0,1)`` per element, else ``X_i + K |X_i - X_worst| / ((f_i - f_worst) + ε)``
      with ``K ~ U[-1,1]``.

    Differences from the authors' MATLAB code, needed for one evaluation per iteration: the
    scroungers follow the best memory of the *previous* iteration instead of the best producer
    just evaluated, and danger-aware sparrows are not evaluated twice.  Differences from
    mealpy's ``OriginalSSA``: the producer factor is ``exp(-i/(r T))`` as in the paper (mealpy
    uses ``exp(+(i)/(r T))``), danger-aware sparrows are 10 % of the swarm (mealpy applies the
    danger step to 90 %), and out-of-box moves are clipped, not re-sampled.  Note that the
    producer and starving-scrounger moves contract toward the origin, so SSA favours problems
    whose optimum is near 0 (true for scaled MPC controls around a zero input).

    Random draws per iteration, in this order: ``R2`` (1), ``r`` (producers), ``Q`` (producers),
    ``A`` signs ``rng.random((n_scroungers, dim))``, ``Q`` (scroungers), the danger-aware subset
    ``rng.permutation(n)``, ``β`` ``rng.standard_normal((n_scouts, dim))``, ``K`` (scouts).

    Options: ``producers`` (0.2), ``scouts`` (0.1), ``safety_threshold`` (0.8).
    """

    name = "ssa"
    default_population = 50
    default_iterations = 80
    default_options: ClassVar[Mapping[str, Any]] = {
        "producers": 0.2,
        "scouts": 0.1,
        "safety_threshold": 0.8,
    }
    eps: ClassVar[float] = 1e-50

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for key in ("producers", "scouts"):
            if not 0.0 < self.options[key] < 1.0:
                raise ValueError(f"options[{key!r}] must be in (0, 1), got {self.options[key]!r}")
        n = self.population
        self.n_producers = min(n - 1, max(1, round(self.options["producers"] * n)))
        self.n_scouts = min(n, max(1, round(self.options["scouts"] * n)))

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        self.memory = positions.copy()
        self.memory_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        n, d, n_p = self.population, self.dim, self.n_producers
        order = np.argsort(self.memory_costs, kind="stable")
        ranked = self.memory[order]
        ranked_f = self.memory_costs[order]
        best, worst = ranked[0], ranked[-1]
        f_best, f_worst = ranked_f[0], ranked_f[-1]
        rank = np.arange(1, n + 1, dtype=float)[:, None]

        alarm = rng.random()
        r = 1.0 - rng.random(n_p)  # (0, 1]
        q_producer = rng.standard_normal(n_p)
        signs = np.where(rng.random((n - n_p, d)) < 0.5, -1.0, 1.0)
        q_scrounger = rng.standard_normal(n - n_p)
        scouts = rng.permutation(n)[: self.n_scouts]
        beta = rng.standard_normal((self.n_scouts, d))
        k = rng.uniform(-1.0, 1.0, self.n_scouts)

        new = np.empty_like(ranked)
        producers = ranked[:n_p]
        if alarm < self.options["safety_threshold"]:
            new[:n_p] = producers * np.exp(-rank[:n_p] / (r[:, None] * self.iterations))
        else:
            new[:n_p] = producers + q_producer[:, None]
        scroungers = ranked[n_p:]
        starving = rank[n_p:, 0] > n / 2.0
        with np.errstate(over="ignore", invalid="ignore"):
            hungry = q_scrounger[:, None] * np.exp((worst - scroungers) / rank[n_p:] ** 2)
        shift = np.mean(signs * np.abs(scroungers - best), axis=1, keepdims=True)
        new[n_p:] = np.where(starving[:, None], hungry, best + shift)

        # danger-aware sparrows, indexed by rank
        at_risk = ranked_f[scouts] > f_best
        safe_move = best + beta * np.abs(ranked[scouts] - best)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            denom = (ranked_f[scouts] - f_worst) + self.eps
            edge_move = ranked[scouts] + k[:, None] * np.abs(ranked[scouts] - worst) / denom[:, None]
        edge_move = np.where(np.isfinite(edge_move), edge_move, ranked[scouts])
        new[scouts] = np.where(at_risk[:, None], safe_move, edge_move)

        self._order = order
        proposal = np.empty_like(new)
        proposal[order] = new
        return proposal

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        better = costs < self.memory_costs
        self.memory[better] = positions[better]
        self.memory_costs[better] = costs[better]

    def final_population(self) -> np.ndarray:
        return self.memory.copy()


class ParticleSwarm(PopulationAlgorithm):
    """Global-best PSO with Clerc–Kennedy constriction.

    ``v ← χ (v + c1 r1 (p_i - x) + c2 r2 (g - x))``, ``x ← x + v`` with ``c1 = c2 = 2.05``,
    ``φ = c1 + c2``, ``χ = 2 / |2 - φ - sqrt(φ² - 4φ)| ≈ 0.7298``; velocities clamped to
    ``± velocity_clamp · (upper - lower)``; positions clipped to the box and the velocity
    component that hit a wall set to zero.  Initial velocities ``(U(box) - x)/2``.

    Options: ``c1`` (2.05), ``c2`` (2.05), ``velocity_clamp`` (1.0, fraction of the box width).
    """

    name = "pso"
    default_population = 30
    default_iterations = 40
    default_options: ClassVar[Mapping[str, Any]] = {
        "c1": 2.05,
        "c2": 2.05,
        "velocity_clamp": 1.0,
    }

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        phi = self.options["c1"] + self.options["c2"]
        if phi <= 4.0:
            raise ValueError(f"options c1 + c2 must be > 4 for constriction, got {phi!r}")
        self.chi = 2.0 / abs(2.0 - phi - math.sqrt(phi * phi - 4.0 * phi))
        self.v_max = self.options["velocity_clamp"] * self.width

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        target = self.lower + rng.random((self.population, self.dim)) * self.width
        self.velocity = np.clip(0.5 * (target - positions), -self.v_max, self.v_max)
        self.pbest = positions.copy()
        self.pbest_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        draws = rng.random((2, self.population, self.dim))
        g = self.pbest[int(np.argmin(self.pbest_costs))]
        x = self.positions
        v = self.chi * (
            self.velocity
            + self.options["c1"] * draws[0] * (self.pbest - x)
            + self.options["c2"] * draws[1] * (g - x)
        )
        self.velocity = np.clip(v, -self.v_max, self.v_max)
        proposal = x + self.velocity
        hit = (proposal < self.lower) | (proposal > self.upper)
        self.velocity[hit] = 0.0
        return proposal

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        better = costs < self.pbest_costs
        self.pbest[better] = positions[better]
        self.pbest_costs[better] = costs[better]


#: Registry name -> algorithm class.
ALGORITHMS: Mapping[str, type[PopulationAlgorithm]] = {
    cls.name: cls for cls in (ImprovedGreyWolf, GreyWolf, SparrowSearch, ParticleSwarm)
}


def available_methods() -> list[str]:
    """Sorted names accepted by :func:`minimize` (``method=``)."""
    return sorted(ALGORITHMS)


# --------------------------------------------------------------------------------------------
# Front door
# --------------------------------------------------------------------------------------------


def _bounds(lower: object, upper: object) -> tuple[np.ndarray, np.ndarray]:
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
            f"lower must be < upper element-wise, got lower[{bad}]={lo[bad]!r} >= upper[{bad}]={up[bad]!r}"
        )
    return lo, up


def minimize(
    fun: Objective,
    lower: object,
    upper: object,
    method: str = "igwo",
    *,
    population: int | None = None,
    iterations: int | None = None,
    max_evaluations: int | None = None,
    seed: int | np.random.Generator | None = None,
    initial_population: object = None,
    options: Mapping[str, Any] | None = None,
) -> MinimizeResult:
    """Minimise a vectorised objective over a box with a population optimiser.

    Parameters
    ----------
    fun : callable
        ``fun(X) -> costs`` with ``X`` of shape ``(population, dim)`` and costs of shape
        ``(population,)``.  Called once for the initial population and once per iteration;
        non-finite costs are treated as ``+inf``.
    lower, upper : array_like, shape (dim,), or scalar
        Box bounds, finite, ``lower < upper``.  One of them may be a scalar broadcast to the
        other's shape; two arrays must have equal shapes.
    method : {"igwo", "gwo", "ssa", "pso"}
        Algorithm, see :func:`available_methods`.
    population : int, optional
        Population size (>= 4).  Default per method as in the paper: igwo 20, gwo 30,
        ssa 50, pso 30.
    iterations : int, optional
        Iteration budget ``T`` (>= 1); also sets the schedules (``a(t)``, ``w(t)``).
        Default: igwo 30, gwo 40, ssa 80, pso 40.
    max_evaluations : int, optional
        Stop before an iteration that would exceed this many evaluations (the initial
        population counts); must be >= ``population``.
    seed : int, numpy.random.Generator or None
        All randomness goes through ``numpy.random.default_rng(seed)``; the same int seed
        gives bit-identical results.
    initial_population : array_like, shape (k, dim), optional
        ``k <= population`` starting points placed first (clipped to the box), e.g. a
        shifted previous plan; the remaining individuals are uniform in the box.
    options : mapping, optional
        Algorithm parameters, see each algorithm class.

    Returns
    -------
    MinimizeResult

    Raises
    ------
    ValueError
        On any invalid argument; the message names the parameter, the expected range and the
        value received.
    """
    if not callable(fun):
        raise ValueError(f"fun must be callable, got {fun!r}")
    if method not in ALGORITHMS:
        raise ValueError(f"method must be one of {available_methods()}, got {method!r}")
    cls = ALGORITHMS[method]
    lo, up = _bounds(lower, upper)
    dim = lo.shape[0]
    n = cls.default_population if population is None else positive_int("population", population, 4)
    T = cls.default_iterations if iterations is None else positive_int("iterations", iterations, 1)
    if max_evaluations is not None:
        if isinstance(max_evaluations, bool) or not isinstance(max_evaluations, numbers.Integral):
            raise ValueError(
                f"max_evaluations must be an integer >= population ({n}) or None, got {max_evaluations!r}"
            )
        if max_evaluations < n:
            raise ValueError(
                f"max_evaluations must be an integer >= population ({n}), got {max_evaluations!r}"
            )
        max_evaluations = int(max_evaluations)
    seeds = None
    if initial_population is not None:
        try:
            seeds = np.array(initial_population, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"initial_population must be a real array of shape (k, {dim}) with "
                f"1 <= k <= population ({n}), got {initial_population!r}"
            ) from error
        if seeds.ndim != 2 or seeds.shape[1] != dim or not 1 <= seeds.shape[0] <= n:
            raise ValueError(
                f"initial_population must have shape (k, {dim}) with 1 <= k <= population "
                f"({n}), got shape {seeds.shape}"
            )
        if not np.all(np.isfinite(seeds)):
            raise ValueError("initial_population must be finite (no NaN or inf)")
    if isinstance(seed, bool):
        raise ValueError(f"seed must be an int, a numpy.random.Generator or None, got {seed!r}")
    try:
        rng = np.random.default_rng(seed)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"seed must be an int >= 0, a numpy.random.Generator or None, got {seed!r}"
        ) from error
    algorithm = cls(lo, up, n, T, options)
    return algorithm.run(fun, rng, seeds, max_evaluations)
