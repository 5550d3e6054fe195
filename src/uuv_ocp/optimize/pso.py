"""Particle swarm optimisation with constriction (``pso``): :class:`ParticleSwarm`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from uuv_ocp.optimize.loop import PopulationAlgorithm

__all__ = ["ParticleSwarm"]


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
        """Draw the initial velocities and set the personal bests."""
        target = self.lower + rng.random((self.population, self.dim)) * self.width
        self.velocity = np.clip(0.5 * (target - positions), -self.v_max, self.v_max)
        self.pbest = positions.copy()
        self.pbest_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Constricted velocity update; zero the velocity components that leave the box."""
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
        """Update the personal bests that improved."""
        better = costs < self.pbest_costs
        self.pbest[better] = positions[better]
        self.pbest_costs[better] = costs[better]
