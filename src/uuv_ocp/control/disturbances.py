"""Ocean current and measurement noise for closed-loop simulation.

The current follows uuv_simulator's model: speed and horizontal direction are each a
first-order Gauss–Markov process that decays toward its mean, driven by Gaussian noise scaled
with √dt and clamped to ``[min, max]``:

    s_{k+1} = clamp(s_k − μ (s_k − s̄) dt + σ √dt w_k, s_min, s_max),  w_k ~ N(0, 1)

The inertial current velocity is ``V_c = s [cos β, sin β]`` with direction β (rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uuv_ocp import _validation as check


@dataclass(frozen=True)
class GaussMarkov:
    """First-order Gauss–Markov process with clamping.

    Parameters
    ----------
    mean : float
        Value the process decays toward.
    noise : float
        Noise intensity σ (units of the value per √s), >= 0.
    decay : float
        Decay rate μ (1/s), >= 0.
    minimum, maximum : float
        Clamp bounds, ``minimum <= mean <= maximum``.
    """

    mean: float
    noise: float = 0.0
    decay: float = 0.0
    minimum: float = -math.inf
    maximum: float = math.inf

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        object.__setattr__(self, "mean", check.finite_float("mean", self.mean))
        object.__setattr__(self, "noise", check.nonnegative_float("noise", self.noise))
        object.__setattr__(self, "decay", check.nonnegative_float("decay", self.decay))
        if not self.minimum <= self.mean <= self.maximum:
            bounds = f"[{self.minimum}, {self.maximum}]"
            raise ValueError(f"mean must lie in [minimum, maximum] = {bounds}, got {self.mean}")

    def sample(self, steps: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Path of ``steps + 1`` values starting at the mean, with step ``dt`` (s)."""
        values = np.empty(steps + 1)
        values[0] = self.mean
        draws = rng.standard_normal(steps) if self.noise > 0 else np.zeros(steps)
        root_dt = math.sqrt(dt)
        for k in range(steps):
            step = values[k] - self.decay * (values[k] - self.mean) * dt + self.noise * root_dt * draws[k]
            values[k + 1] = min(max(step, self.minimum), self.maximum)
        return values


@dataclass(frozen=True)
class Current:
    """Horizontal ocean current.

    Parameters
    ----------
    speed : float
        Mean speed (m/s), >= 0.
    direction : float
        Mean direction (rad) of the flow in the inertial frame (0 = +x).
    speed_noise, direction_noise : float
        Gauss–Markov noise intensities (m/s/√s, rad/√s), >= 0.
    decay : float
        Gauss–Markov decay rate μ (1/s) of both processes, >= 0.
    max_speed : float
        Upper clamp of the speed (m/s).
    """

    speed: float = 0.0
    direction: float = 0.0
    speed_noise: float = 0.0
    direction_noise: float = 0.0
    decay: float = 0.1
    max_speed: float = 2.0

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        object.__setattr__(self, "speed", check.nonnegative_float("speed", self.speed))
        object.__setattr__(self, "direction", check.finite_float("direction", self.direction))
        object.__setattr__(self, "speed_noise", check.nonnegative_float("speed_noise", self.speed_noise))
        object.__setattr__(
            self,
            "direction_noise",
            check.nonnegative_float("direction_noise", self.direction_noise),
        )
        object.__setattr__(self, "decay", check.nonnegative_float("decay", self.decay))
        object.__setattr__(self, "max_speed", check.positive_float("max_speed", self.max_speed))
        if self.speed > self.max_speed:
            raise ValueError(f"speed must be <= max_speed = {self.max_speed} m/s, got {self.speed}")

    def sample(self, steps: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Inertial current velocity ``(steps + 1, 2)`` (m/s) on a grid of step ``dt`` (s)."""
        speed = GaussMarkov(self.speed, self.speed_noise, self.decay, 0.0, self.max_speed)
        direction = GaussMarkov(self.direction, self.direction_noise, self.decay)
        speeds = speed.sample(steps, dt, rng)
        directions = direction.sample(steps, dt, rng)
        return np.column_stack([speeds * np.cos(directions), speeds * np.sin(directions)])


@dataclass(frozen=True)
class MeasurementNoise:
    """Zero-mean Gaussian noise on the state the controller sees.

    Parameters
    ----------
    std : tuple of floats
        Standard deviations, one per state (3-DOF: m, m, rad, m/s, m/s, rad/s), >= 0.
    """

    std: tuple[float, ...] = (0.0,) * 6

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        length = len(self.std) if isinstance(self.std, (tuple, list, np.ndarray)) else 6
        object.__setattr__(self, "std", check.vector("std", self.std, length, nonnegative=True))

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One noise vector, one entry per state."""
        return rng.standard_normal(len(self.std)) * np.asarray(self.std)
