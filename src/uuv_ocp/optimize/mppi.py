"""Model predictive path integral updates for a static objective (``mppi``): :class:`PathIntegral`.

MPPI (Williams et al., "Information theoretic MPC for model-based reinforcement learning",
ICRA 2017) moves a nominal plan to the importance-weighted mean of Gaussian perturbations of
it, the weights ``w_i ∝ exp(−(J_i − min J)/λ)``.  For an objective without dynamics the same
update is a Gaussian evolution strategy with soft-max weights; :func:`importance_weights` is
the one implementation of the weights, shared with the receding-horizon solver
:class:`uuv_ocp.solvers.mppi.MppiSolver`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from uuv_ocp.optimize.loop import PopulationAlgorithm

__all__ = ["PathIntegral", "importance_weights"]

_SCALES = ("median", "none")


def importance_weights(values: np.ndarray, temperature: float) -> np.ndarray:
    """Return the MPPI weights of the costs ``values``: the soft-max of ``−values/temperature``.

    Parameters
    ----------
    values : numpy.ndarray, shape (S,)
        Costs of the samples; non-finite costs get weight 0.
    temperature : float
        λ > 0, in the units of ``values``.

    Returns
    -------
    numpy.ndarray, shape (S,)
        Non-negative weights summing to 1 (uniform when no cost is finite).
    """
    finite = np.isfinite(values)
    if not np.any(finite):
        return np.full(values.shape, 1.0 / values.size)
    # shifted by the smallest cost, so the largest weight is exp(0) and nothing underflows to 0/0
    shifted = np.where(finite, values - np.min(values[finite]), np.inf)
    weights = np.exp(-shifted / temperature)
    return weights / np.sum(weights)


class PathIntegral(PopulationAlgorithm):
    """MPPI on a box: a Gaussian cloud around a mean that moves to its weighted average.

    Each iteration draws ``μ + σ_t ε`` (``ε ~ N(0, I)``, one row per individual; row 0 is the
    mean itself, so the cloud always scores its own centre), clips it to the box (the loop) and
    moves the mean to ``Σ w_i x_i`` with :func:`importance_weights`: a convex combination of
    points in the box, so the mean holds the bounds by construction.  The first mean is the
    best point of the uniform initial population.

    The noise shrinks geometrically from ``noise`` to ``final_noise`` (fractions of the box
    width, per coordinate) over the iteration budget: the fixed noise of receding-horizon MPPI
    would stop a static search at the noise's resolution.  With ``scale="median"`` (default)
    the temperature is relative, ``λ = temperature · (median J − min J)`` over the finite costs
    of the iteration, so the weights do not depend on the objective's units; ``scale="none"``
    takes ``temperature`` as λ itself (the textbook update, in the objective's units).

    Options: ``noise`` (0.2), ``final_noise`` (0.001), ``temperature`` (0.3),
    ``scale`` ("median").
    """

    name = "mppi"
    default_population = 40
    default_iterations = 50
    default_options: ClassVar[Mapping[str, Any]] = {
        "noise": 0.2,
        "final_noise": 0.001,
        "temperature": 0.3,
        "scale": "median",
    }

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for key in ("noise", "final_noise", "temperature"):
            if self.options[key] <= 0.0:
                raise ValueError(f"options[{key!r}] of 'mppi' must be > 0, got {self.options[key]!r}")
        if self.options["final_noise"] > self.options["noise"]:
            raise ValueError(
                f"options['final_noise'] of 'mppi' must be <= options['noise'] "
                f"({self.options['noise']!r}), got {self.options['final_noise']!r}"
            )
        if self.options["scale"] not in _SCALES:
            raise ValueError(
                f"options['scale'] of 'mppi' must be one of {_SCALES}, got {self.options['scale']!r}"
            )

    def noise_at(self, iteration: int) -> np.ndarray:
        """Per-coordinate standard deviation ``σ_t`` (box units) at 0-based ``iteration``."""
        start, end = self.options["noise"], self.options["final_noise"]
        fraction = iteration / max(self.iterations - 1, 1)
        return start * (end / start) ** fraction * self.width

    def temperature(self, costs: np.ndarray) -> float:
        """λ for the costs of one iteration (see the class docstring)."""
        if self.options["scale"] == "none":
            return float(self.options["temperature"])
        finite = costs[np.isfinite(costs)]
        spread = float(np.median(finite) - np.min(finite)) if finite.size else 0.0
        if not (spread > 0.0 and math.isfinite(spread)):
            # half the cloud or more ties at the best cost: the full spread keeps λ in the
            # objective's scale (unit-free); 1 only when every finite cost is the same
            spread = float(np.max(finite) - np.min(finite)) if finite.size else 0.0
        return self.options["temperature"] * (spread if spread > 0.0 and math.isfinite(spread) else 1.0)

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        """Start the mean at the best point of the initial population."""
        self.mean = positions[int(np.argmin(costs))].copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Gaussian cloud around the mean (row 0: the mean itself)."""
        cloud = self.mean + self.noise_at(iteration) * rng.standard_normal((self.population, self.dim))
        cloud[0] = self.mean
        return cloud

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        """Move the mean to the importance-weighted average of the evaluated (clipped) cloud."""
        self.mean = importance_weights(costs, self.temperature(costs)) @ positions
