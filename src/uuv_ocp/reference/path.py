"""Planar reference trajectories defined symbolically, with AD-derived pose and velocity.

A path ``(x_R(t), y_R(t))`` given as CasADi expressions of time defines the whole reference
state through the paper's Eq. (9):

    ψ_R = atan2(ẏ, ẋ),  u_R = √(ẋ² + ẏ²),  v_R = 0,  r_R = (ẋÿ − ẏẍ) / (ẋ² + ẏ²)

All derivatives come from CasADi's algorithmic differentiation, never by hand or by finite
differences.  The heading returned by :meth:`Reference.evaluate` is continuous in time: it is
unwrapped with increments predicted by integrating ``r_R`` (Simpson's rule), so circles and
spirals never jump by 2π.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.native.buffered import BufferedFunction

PathFunction = Callable[[ca.SX], object]

#: Speed (m/s) below which the heading of a path is undefined.
MIN_PATH_SPEED = 1e-6
#: Largest gap (s) between the samples used to unwrap the heading.
UNWRAP_STEP = 0.1


def _paper_catalogue() -> dict[str, tuple[PathFunction, float, float, str]]:
    """Name -> (y(t) with x = 0.5 t, t_start, t_end, formula) for the paper's s1..s10."""
    semicircle_margin = 1.5
    return {
        "s1": (lambda t: 0.1 * (0.5 * t) ** 2, 0.0, math.inf, "y = 0.1 (0.5t)^2"),
        "s2": (lambda t: 2.0 * ca.sin(0.5 * t), 0.0, math.inf, "y = 2 sin(0.5t)"),
        "s3": (
            lambda t: ca.sqrt(7.5**2 - (0.5 * t - 7.5) ** 2),
            semicircle_margin,
            30.0 - semicircle_margin,
            "y = sqrt(7.5^2 - (0.5t - 7.5)^2)",
        ),
        "s4": (lambda t: 0.5 * t + ca.sin(0.5 * t), 0.0, math.inf, "y = 0.5t + sin(0.5t)"),
        "s5": (lambda t: 0.5 * t + ca.cos(0.5 * t), 0.0, math.inf, "y = 0.5t + cos(0.5t)"),
        "s6": (lambda t: 0.5 * t - ca.sin(0.5 * t), 0.0, math.inf, "y = 0.5t - sin(0.5t)"),
        "s7": (lambda t: 0.5 * t - ca.cos(0.5 * t), 0.0, math.inf, "y = 0.5t - cos(0.5t)"),
        "s8": (lambda t: 0.5 * t * ca.sin(0.5 * t), 0.0, math.inf, "y = 0.5t sin(0.5t)"),
        "s9": (lambda t: 0.5 * t * ca.cos(0.5 * t), 0.0, math.inf, "y = 0.5t cos(0.5t)"),
        "s10": (lambda t: ca.log(0.5 * t + 1.0), 0.0, math.inf, "y = ln(0.5t + 1)"),
    }


PAPER_REFERENCES: tuple[str, ...] = tuple(_paper_catalogue())


@dataclass(frozen=True)
class Reference:
    """A planar reference path ``(x_R(t), y_R(t))`` and everything derived from it.

    Parameters
    ----------
    path_x, path_y : callable
        Functions of a CasADi ``SX`` time symbol ``t`` (s) returning the position (m).
    name : str
        Label used in tables and plots.
    t_start, t_end : float
        Time window (s) on which the path is valid; evaluation outside raises ``ValueError``.
    description : str
        Human-readable formula.
    """

    path_x: PathFunction
    path_y: PathFunction
    name: str = "reference"
    t_start: float = 0.0
    t_end: float = math.inf
    description: str = ""
    _function: ca.Function = field(init=False, repr=False, compare=False)
    _maps: dict = field(init=False, repr=False, compare=False, default_factory=dict)

    def __post_init__(self) -> None:
        if not callable(self.path_x):
            raise ValueError(f"path_x must be a callable of a casadi SX time symbol, got {self.path_x!r}")
        if not callable(self.path_y):
            raise ValueError(f"path_y must be a callable of a casadi SX time symbol, got {self.path_y!r}")
        t_start = check.finite_float("t_start", self.t_start)
        if isinstance(self.t_end, bool) or not isinstance(self.t_end, (int, float)):
            raise ValueError(f"t_end must be a number (s), got {self.t_end!r}")
        t_end = float(self.t_end)
        if not t_end > t_start:
            raise ValueError(f"t_end must be > t_start = {t_start}, got {self.t_end!r}")
        object.__setattr__(self, "t_start", t_start)
        object.__setattr__(self, "t_end", t_end)
        object.__setattr__(self, "_function", self._build_function())

    # ---------------------------------------------------------------- builders
    @classmethod
    def from_xy(
        cls,
        path_x: PathFunction,
        path_y: PathFunction,
        name: str = "reference",
        *,
        t_start: float = 0.0,
        t_end: float = math.inf,
        description: str = "",
    ) -> Reference:
        """Reference from two callables on a CasADi time symbol, e.g. ``lambda t: 2*ca.sin(t)``."""
        return cls(path_x, path_y, name, t_start, t_end, description)

    @classmethod
    def paper(cls, name: str) -> Reference:
        """One of the paper's ten references ``"s1"`` ... ``"s10"`` (all with ``x = 0.5 t``).

        ``s3`` is a semicircle of radius 7.5 m whose tangent is vertical (infinite speed) at
        t = 0 s and t = 30 s; it is valid on [1.5, 28.5] s, where the path speed stays below
        1.4 m/s.  See ``docs/references.md`` for how the paper's garbled formulas were read.
        """
        catalogue = _paper_catalogue()
        if name not in catalogue:
            raise ValueError(f"reference name must be one of {list(catalogue)}, got {name!r}")
        path_y, t_start, t_end, formula = catalogue[name]
        return cls(lambda t: 0.5 * t, path_y, name, t_start, t_end, f"x = 0.5t, {formula}")

    def _build_function(self) -> ca.Function:
        time = ca.SX.sym("t")
        try:
            position_x = ca.SX(self.path_x(time)) + 0 * time
            position_y = ca.SX(self.path_y(time)) + 0 * time
        except Exception as error:  # user callables may fail in many ways
            raise ValueError(
                f"path_x and path_y must accept a casadi SX symbol and return a scalar "
                f"expression; calling them failed with: {error}"
            ) from error
        for label, expression in (("path_x", position_x), ("path_y", position_y)):
            if expression.shape != (1, 1):
                raise ValueError(f"{label} must return a scalar expression, got shape {expression.shape}")
        velocity_x = ca.jacobian(position_x, time)
        velocity_y = ca.jacobian(position_y, time)
        acceleration_x = ca.jacobian(velocity_x, time)
        acceleration_y = ca.jacobian(velocity_y, time)
        speed_squared = velocity_x**2 + velocity_y**2
        heading = ca.atan2(velocity_y, velocity_x)
        yaw_rate = (velocity_x * acceleration_y - velocity_y * acceleration_x) / speed_squared
        outputs = ca.vertcat(position_x, position_y, heading, ca.sqrt(speed_squared), 0 * time, yaw_rate)
        # CasADi accepts letters, digits and single underscores in a Function name; the
        # reference's own name is a free label ("fast circle", "s-curve")
        label = "_".join(re.findall(r"[0-9A-Za-z]+", self.name))
        name = f"reference_{label}" if label else "reference"
        return ca.Function(name, [time], [outputs], ["t"], ["state"])

    # -------------------------------------------------------------- evaluation
    @property
    def function(self) -> ca.Function:
        """``t -> [x_R, y_R, ψ_R (wrapped), u_R, v_R, r_R]`` as a CasADi Function."""
        return self._function

    def _raw(self, times: np.ndarray) -> np.ndarray:
        size = times.size
        if size not in self._maps:  # CasADi would build a new map on every horzcat call
            self._maps[size] = BufferedFunction(self._function.map(size))
        (states,) = self._maps[size](times)
        return states.reshape(size, -1)

    def evaluate(self, times: object) -> np.ndarray:
        """Reference state at the given times, with a continuous heading.

        Parameters
        ----------
        times : array_like, shape (n,)
            Non-decreasing times (s) inside ``[t_start, t_end]``.

        Returns
        -------
        numpy.ndarray, shape (n, 6)
            ``[x_R, y_R, ψ_R, u_R, v_R, r_R]`` (m, m, rad, m/s, m/s, rad/s).  ``ψ_R`` at the
            first time lies in (−π, π]; later values are unwrapped.
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if times.ndim != 1 or times.size == 0:
            raise ValueError(f"times must be a non-empty 1-D array (s), got shape {times.shape}")
        if not np.all(np.isfinite(times)):
            raise ValueError(f"times must be finite, got {times!r}")
        if np.any(np.diff(times) < 0):
            raise ValueError("times must be non-decreasing")
        outside = (times < self.t_start - 1e-12) | (times > self.t_end + 1e-12)
        if np.any(outside):
            bad = times[outside][0]
            raise ValueError(
                f"reference {self.name!r} is defined on t in [{self.t_start}, {self.t_end}] s, got t = {bad}"
            )
        dense = _refined_grid(times)
        states = self._states_on_grid(dense)
        if states is None:
            raw = self._raw(dense)
            bad_rows = ~np.all(np.isfinite(raw), axis=1) | (raw[:, 3] < MIN_PATH_SPEED)
            raise ValueError(
                f"reference {self.name!r} has a vanishing or non-finite speed at t = "
                f"{dense[bad_rows][0]} s (speed {raw[bad_rows][0, 3]!r} m/s): its heading is "
                "undefined there"
            )
        if dense.size == times.size:
            return states
        return states[np.searchsorted(dense, times)]

    def evaluate_grid(self, times: np.ndarray) -> np.ndarray:
        """Fast :meth:`evaluate` for a grid the caller has already checked.

        ``times`` must be strictly increasing, inside the window, with gaps <= 0.1 s (the
        closed loop's reference windows).  Falls back to :meth:`evaluate` (and its error
        messages) if the speed vanishes or is not finite.
        """
        states = self._states_on_grid(times)
        return self.evaluate(times) if states is None else states

    def _states_on_grid(self, grid: np.ndarray) -> np.ndarray | None:
        """States with unwrapped heading on a fine increasing grid; ``None`` if the path speed
        vanishes or is not finite somewhere on it."""
        midpoints = 0.5 * (grid[:-1] + grid[1:])
        both = self._raw(np.concatenate([grid, midpoints]))  # one call for grid and midpoints
        states, mid_rate = both[: grid.size], both[grid.size :, 5]
        if not (np.all(np.isfinite(states)) and np.all(states[:, 3] >= MIN_PATH_SPEED)):
            return None
        states[:, 2] = _unwrapped_heading(grid, states[:, 2], states[:, 5], mid_rate)
        return states

    def initial_state(self, t0: float | None = None) -> np.ndarray:
        """State on the reference pose at ``t0`` (default ``t_start``), at rest: shape (6,)."""
        t0 = self.t_start if t0 is None else check.finite_float("t0", t0)
        state = self.evaluate([t0])[0]
        state[3:] = 0.0
        return state


def _unwrapped_heading(
    times: np.ndarray, wrapped: np.ndarray, rate: np.ndarray, mid_rate: np.ndarray
) -> np.ndarray:
    """Continuous heading from wrapped values and the yaw rate at nodes and midpoints.

    Each increment is the Simpson prediction ``∫ r dt`` corrected by the wrapped difference
    between the prediction and the observed change, ``Δ = pred + wrap(Δψ_wrapped − pred)``:
    exact as long as the prediction error stays below π.
    """
    if times.size < 2:
        return wrapped.copy()
    predicted = np.diff(times) / 6.0 * (rate[:-1] + 4.0 * mid_rate + rate[1:])
    mismatch = np.diff(wrapped) - predicted
    increments = predicted + (mismatch + np.pi) % (2.0 * np.pi) - np.pi
    return wrapped[0] + np.concatenate([[0.0], np.cumsum(increments)])


def _refined_grid(times: np.ndarray) -> np.ndarray:
    """``times`` plus extra points so that no gap exceeds ``UNWRAP_STEP``; sorted, unique."""
    gaps = np.diff(times)
    if np.all((gaps > 0) & (gaps <= UNWRAP_STEP)):
        return times  # already strictly increasing and fine enough
    unique = np.unique(times)
    if unique.size < 2:
        return unique
    gaps = np.diff(unique)
    pieces = np.maximum(1, np.ceil(gaps / UNWRAP_STEP).astype(int))
    if np.all(pieces == 1):
        return unique
    extra = [
        start + gap * np.arange(1, count) / count
        for start, gap, count in zip(unique[:-1], gaps, pieces, strict=True)
        if count > 1
    ]
    return np.unique(np.concatenate([unique, *extra]))
