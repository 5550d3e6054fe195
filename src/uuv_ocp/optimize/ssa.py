"""Sparrow search algorithm (``ssa``): :class:`SparrowSearch`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from uuv_ocp.optimize.loop import PopulationAlgorithm

__all__ = ["SparrowSearch"]


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
        """Set every sparrow's memory to its initial position."""
        self.memory = positions.copy()
        self.memory_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Move producers, scroungers and danger-aware sparrows from the ranked memory."""
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
        """Greedy selection: a sparrow keeps its new position only if it is better."""
        better = costs < self.memory_costs
        self.memory[better] = positions[better]
        self.memory_costs[better] = costs[better]

    def final_population(self) -> np.ndarray:
        """Return the sparrows' memories (best positions), not the last proposals."""
        return self.memory.copy()
