"""Grey wolf optimiser (``gwo``): the pure update :func:`gwo_update` and :class:`GreyWolf`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from uuv_ocp._validation import choice
from uuv_ocp.optimize.loop import PopulationAlgorithm
from uuv_ocp.optimize.schedules import CONVERGENCE_FACTORS, convergence_factor

__all__ = ["GreyWolf", "gwo_update"]


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
        Uniform numbers in ``[0, 1)``; planes 0..5 as in :mod:`uuv_ocp.optimize.loop`.

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


class GreyWolf(PopulationAlgorithm):
    """Grey wolf optimiser (Mirjalili, Mirjalili & Lewis 2014), memoryless.

    ``a`` decays linearly 2 -> 0 (``a(t)`` evaluated at ``t = 0 .. T-1``); ``A = 2 a r1 - a``,
    ``C = 2 r2``; ``X(t+1) = (X1 + X2 + X3)/3`` (:func:`gwo_update`).  The leaders α, β, δ are
    the three best points seen so far (best three of the previous leaders and the newly
    evaluated wolves, as in the authors' reference code).  By default (``selection="none"``,
    the original) positions are *not* greedily selected, so wolves may move to worse points.

    ``selection="greedy"`` is the variant mealpy ships as ``OriginalGWO`` (mealpy 3.0): a wolf
    keeps its previous position when the new one is not better, so the pack moves from each
    wolf's best point so far.  On problems whose optimum sits where the leaders pull (the
    origin of Griewank, sphere, Rastrigin) it converges by orders of magnitude further at the
    same budget; docs/benchmarks.md "GWO: original and greedy" has the measurement.

    Options: ``a_initial`` (2), ``a_final`` (0), ``convergence`` (``"linear"``; any kind of
    :func:`uuv_ocp.optimize.schedules.convergence_factor`), ``selection`` (``"none"`` or
    ``"greedy"``).
    """

    name = "gwo"
    default_population = 30
    default_iterations = 40
    default_options: ClassVar[Mapping[str, Any]] = {
        "a_initial": 2.0,
        "a_final": 0.0,
        "convergence": "linear",
        "selection": "none",
    }
    n_draws: ClassVar[int] = 6
    leaders: np.ndarray  # (3, dim): alpha, beta, delta
    leader_costs: np.ndarray  # (3,)
    wolf_costs: np.ndarray  # (population,): cost at each wolf's current position
    previous: np.ndarray  # (population, dim): positions before the last proposal

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        choice("options['convergence']", self.options["convergence"], sorted(CONVERGENCE_FACTORS))
        if "selection" in self.options:  # IGWO, a subclass, keeps the paper's update without it
            choice("options['selection']", self.options["selection"], ["greedy", "none"])

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
        """Take the three best initial wolves as the leaders α, β, δ."""
        self.leaders = np.empty((0, self.dim))
        self.leader_costs = np.empty(0)
        self.wolf_costs = costs.copy()
        self._update_leaders(positions, costs)

    def _draws(self, rng: np.random.Generator) -> np.ndarray:
        return rng.random((self.n_draws, self.population, self.dim))

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Move every wolf toward the leaders (:func:`gwo_update`, draws of the iteration)."""
        draws = self._draws(rng)
        self.previous = self.positions
        alpha, beta, delta = self.leaders
        return gwo_update(self.positions, alpha, beta, delta, self._a(iteration), draws)

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        """Keep the best three of the previous leaders and the evaluated wolves.

        With ``selection="greedy"`` a wolf whose new cost is not lower returns to its previous
        position (ties keep the old one, as mealpy's ``get_better_agent``).
        """
        self._update_leaders(positions, costs)
        if self.options.get("selection") == "greedy":
            better = costs < self.wolf_costs
            self.positions = np.where(better[:, None], positions, self.previous)
            self.wolf_costs = np.where(better, costs, self.wolf_costs)
        else:
            self.wolf_costs = costs.copy()
