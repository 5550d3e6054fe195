"""Sensors as data: what a vehicle measures, how often, how noisily; the multi-rate schedule.

A :class:`Sensor` is a CasADi measurement function ``h(x)`` of the controller's state, a rate
(Hz), one noise standard deviation per output, and optional dropouts (a due sample that does not
arrive: a DVL losing bottom lock, a missed acoustic fix) and outliers (a sample whose noise is
``outlier_scale`` times larger: acoustic multipath).  :class:`Sensors` is a collection of them:
it says which sensors are due at a control step and draws their measurements of the true state.

Multi-rate schedule
    With control step ``dt`` and rate ``f``, a sensor samples at ``t0 + j / f`` (j = 0, 1, …)
    and reports at the first control instant at or after each sample time; a sample time in
    ``((k−1) dt, k dt]`` makes it due at step ``k`` (and every sensor is due at step 0).  With
    ``a = dt · f`` as an exact fraction (each of ``dt`` and ``f`` rounded to the nearest fraction
    with denominator ≤ 10⁶, so 0.1 s is exactly 1/10), the sensor is due at ``k`` iff
    ``⌊k a⌋ > ⌊(k−1) a⌋``: integer arithmetic on the step index, no drift over long runs.  A
    sensor faster than the control rate reports once per step (its latest sample).

Presets (:meth:`Sensors.auv`), figures of issue #26 and their sources
    ============  ==========  ===========================  ====================================
    sensor        rate (Hz)   σ                            source of the figure
    ============  ==========  ===========================  ====================================
    position      1           0.5 m (x, y)                 USBL: ≈ 0.1 % of slant range (0.5 m
                                                           at 500 m), Cerulean ROV Locator's
                                                           0.5 m range error at 110 m
    dvl           5           0.02 m/s (body u, v[, w]),   Water Linked DVL-A50: 1 % (0.1 %
                              5 % dropouts                 "performance") long-term accuracy,
                                                           i.e. 1-2 cm/s at 1-2 m/s
    attitude      10          0.5° (ψ; 6-DOF φ, θ, ψ)      issue #26's figure (AHRS class)
    gyro          10          0.1 °/s (r; 6-DOF p, q, r)   assumed (MEMS AHRS rate noise)
    depth         10          0.05 m (z, 6-DOF only)       issue #26's figure (pressure sensor)
    ============  ==========  ===========================  ====================================

    The sources are public pages (vivu.tv "How accurate is USBL?", docs.ceruleansonar.com
    "Accuracy Test: 110 Meter Slant Range", discuss.bluerobotics.com "DVL-A50 Accuracy"); the
    dropout rate and the gyro figure are assumptions of this package, not vendor data.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK

#: Largest denominator of the fractions ``dt`` and ``rate`` are rounded to (module doc).
SCHEDULE_DENOMINATOR = 1_000_000


@dataclass(frozen=True)
class Sensor:
    """One sensor: ``y = h(x) + v``, ``v ~ N(0, diag(std²))``, sampled at ``rate`` Hz.

    Parameters
    ----------
    name : str
        Label (unique in a :class:`Sensors`).
    function : casadi.Function
        ``h(x[nx]) -> y[m]``: the noise-free measurement of the controller's state.
    rate : float
        Sampling rate (Hz), > 0.
    std : sequence of float
        Noise standard deviation of each of the ``m`` outputs (their units), > 0.
    dropout : float
        Probability in [0, 1) that a due sample does not arrive.
    outlier_probability : float
        Probability in [0, 1) that an arrived sample is an outlier.
    outlier_scale : float
        Factor (>= 1) on the noise of an outlier.
    angular : sequence of bool, optional
        Which outputs are angles (rad): their innovations are wrapped into (−π, π].
    """

    name: str
    function: ca.Function
    rate: float
    std: tuple[float, ...]
    dropout: float = 0.0
    outlier_probability: float = 0.0
    outlier_scale: float = 10.0
    angular: tuple[bool, ...] = field(default=())

    def __post_init__(self) -> None:
        """Check every field (``ValueError`` names it)."""
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"sensor name must be a non-empty string, got {check.shown(self.name)}")
        function = self.function
        if (
            not isinstance(function, ca.Function)
            or function.n_in() != 1
            or function.n_out() != 1
            or function.size2_in(0) != 1
            or function.size2_out(0) != 1
        ):
            raise ValueError(
                f"sensor {self.name!r}: function must be a casadi.Function h(x) -> y of column "
                f"vectors, got {function!r}"
            )
        m = function.size1_out(0)
        set_field = object.__setattr__
        set_field(self, "rate", check.positive_float(f"sensor {self.name!r}: rate", self.rate))
        if isinstance(self.std, (int, float)) and not isinstance(self.std, bool):
            set_field(self, "std", (float(self.std),) * m)
        set_field(self, "std", check.vector(f"sensor {self.name!r}: std", self.std, m, positive=True))
        for name in ("dropout", "outlier_probability"):
            value = check.nonnegative_float(f"sensor {self.name!r}: {name}", getattr(self, name))
            if value >= 1.0:
                raise ValueError(f"sensor {self.name!r}: {name} must be a probability in [0, 1), got {value}")
            set_field(self, name, value)
        scale = check.finite_float(f"sensor {self.name!r}: outlier_scale", self.outlier_scale)
        if scale < 1.0:
            raise ValueError(f"sensor {self.name!r}: outlier_scale must be >= 1, got {scale}")
        set_field(self, "outlier_scale", scale)
        angular = tuple(self.angular) if self.angular else (False,) * m
        if len(angular) != m or not all(isinstance(a, (bool, np.bool_)) for a in angular):
            raise ValueError(
                f"sensor {self.name!r}: angular must be {m} booleans (one per output), got {self.angular!r}"
            )
        set_field(self, "angular", tuple(bool(a) for a in angular))

    @classmethod
    def of_states(
        cls,
        name: str,
        indices: Sequence[int],
        state_dim: int,
        rate: float,
        std: float | Sequence[float],
        **options: Any,
    ) -> Sensor:
        """Return a sensor that measures the states ``indices`` of a ``state_dim``-state vector."""
        state_dim = check.positive_int("state_dim", state_dim)
        chosen = list(indices)
        if not chosen or any(
            isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < state_dim
            for i in chosen
        ):
            raise ValueError(f"indices must be state indices in [0, {state_dim}), got {indices!r}")
        with BUILD_LOCK:  # CasADi Functions are built here (uuv_ocp._concurrency)
            x = ca.SX.sym("x", state_dim)
            function = ca.Function(f"h_{name}", [x], [x[chosen]], ["x"], ["y"])
        spread = (float(std),) * len(chosen) if isinstance(std, (int, float)) else tuple(std)
        return cls(name, function, rate, spread, **options)

    @property
    def size(self) -> int:
        """Number of outputs ``m``."""
        return int(self.function.size1_out(0))

    @property
    def state_dim(self) -> int:
        """Length of the state ``h`` takes."""
        return int(self.function.size1_in(0))

    def period(self, dt: float) -> Fraction:
        """``dt · rate`` as the exact fraction of the schedule (module doc)."""
        return Fraction(dt).limit_denominator(SCHEDULE_DENOMINATOR) * Fraction(self.rate).limit_denominator(
            SCHEDULE_DENOMINATOR
        )

    def due(self, step: int, dt: float) -> bool:
        """Whether the sensor reports at control step ``step`` (>= 0) of length ``dt`` (s)."""
        if step == 0:
            return True
        a = self.period(dt)
        return math.floor(step * a) > math.floor((step - 1) * a)


@dataclass(frozen=True)
class Measurement:
    """What the sensors reported at one control step.

    Attributes
    ----------
    step : int
        Control step index ``k``.
    sensors : tuple of int
        Indices (in the :class:`Sensors`) of the sensors that reported.
    values : numpy.ndarray
        Their outputs stacked in that order (each sensor's units).
    dropped : tuple of int
        Indices of the sensors that were due but did not report (dropouts).
    outliers : tuple of int
        Indices of the reported sensors whose sample was an outlier.
    """

    step: int
    sensors: tuple[int, ...]
    values: np.ndarray
    dropped: tuple[int, ...] = ()
    outliers: tuple[int, ...] = ()


@dataclass(frozen=True)
class Sensors:
    """A collection of :class:`Sensor` on one state; the schedule and the draws of a run."""

    items: tuple[Sensor, ...]

    def __init__(self, items: Iterable[Sensor]) -> None:
        """Check that ``items`` are sensors on one state with distinct names."""
        chosen = tuple(items) if not isinstance(items, Sensor) else (items,)
        if not chosen or not all(isinstance(s, Sensor) for s in chosen):
            raise ValueError(f"sensors must be a non-empty sequence of uuv_ocp.Sensor, got {items!r}")
        names = [s.name for s in chosen]
        if len(set(names)) != len(names):
            raise ValueError(f"sensors must have distinct names, got {names}")
        dims = {s.state_dim for s in chosen}
        if len(dims) != 1:
            raise ValueError(f"sensors must all measure one state, got state sizes {sorted(dims)}")
        object.__setattr__(self, "items", chosen)

    def __iter__(self) -> Any:
        """Iterate over the sensors."""
        return iter(self.items)

    def __len__(self) -> int:
        """Return the number of sensors."""
        return len(self.items)

    @property
    def names(self) -> tuple[str, ...]:
        """The sensors' names, in order."""
        return tuple(s.name for s in self.items)

    @property
    def state_dim(self) -> int:
        """Length of the state the sensors measure."""
        return self.items[0].state_dim

    @property
    def sizes(self) -> tuple[int, ...]:
        """Outputs per sensor."""
        return tuple(s.size for s in self.items)

    @property
    def offsets(self) -> tuple[int, ...]:
        """Where each sensor's outputs start in the stacked output of all sensors."""
        return tuple(int(o) for o in np.concatenate([[0], np.cumsum(self.sizes)[:-1]]))

    def rows(self, sensors: Sequence[int]) -> np.ndarray:
        """Rows of the stacked output of all sensors that ``sensors`` (indices) fill, in order."""
        offsets, sizes = self.offsets, self.sizes
        if not sensors:
            return np.zeros(0, dtype=int)
        return np.concatenate([np.arange(offsets[i], offsets[i] + sizes[i]) for i in sensors])

    def stacked(self) -> ca.Function:
        """``h_all(x) -> y`` stacking every sensor's output (what estimators linearise)."""
        with BUILD_LOCK:  # CasADi Functions are built here (uuv_ocp._concurrency)
            x = ca.SX.sym("x", self.state_dim)
            outputs = ca.vertcat(*[s.function(x) for s in self.items])
            return ca.Function("h_all", [x], [outputs], ["x"], ["y"])

    @property
    def std(self) -> np.ndarray:
        """Noise standard deviations of the stacked output."""
        return np.concatenate([s.std for s in self.items])

    @property
    def angular(self) -> np.ndarray:
        """Which rows of the stacked output are angles."""
        return np.concatenate([np.asarray(s.angular, dtype=bool) for s in self.items])

    def due(self, step: int, dt: float) -> tuple[int, ...]:
        """Return the indices of the sensors due at control step ``step`` (module doc: the schedule)."""
        step = check.positive_int("step", step, minimum=0)
        dt = check.positive_float("dt", dt)
        return tuple(i for i, s in enumerate(self.items) if s.due(step, dt))

    def measure(self, step: int, dt: float, state: object, rng: np.random.Generator) -> Measurement:
        """Draw the measurements of the sensors due at ``step`` from the true ``state``.

        Draws, per due sensor in order: one uniform for the dropout; if it reports, one uniform
        for an outlier and its ``m`` standard normals (a fixed order: equal seeds, equal runs).
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        x = check.finite_array("state", state, (self.state_dim,))
        reported: list[int] = []
        dropped: list[int] = []
        outliers: list[int] = []
        values: list[np.ndarray] = []
        for i in self.due(step, dt):
            sensor = self.items[i]
            if rng.random() < sensor.dropout:
                dropped.append(i)
                continue
            scale = 1.0
            if rng.random() < sensor.outlier_probability:
                scale = sensor.outlier_scale
                outliers.append(i)
            exact = np.asarray(sensor.function(x), dtype=float).ravel()
            values.append(exact + scale * np.asarray(sensor.std) * rng.standard_normal(sensor.size))
            reported.append(i)
        stacked = np.concatenate(values) if values else np.zeros(0)
        return Measurement(step, tuple(reported), stacked, tuple(dropped), tuple(outliers))

    # ----------------------------------------------------------------- presets
    @classmethod
    def auv(cls, vehicle: Any, *, dvl_dropout: float = 0.05) -> Sensors:
        """Return the issue's AUV sensor suite on ``vehicle``'s layout (module doc: figures, sources).

        Built from ``vehicle.layout`` (a :class:`~uuv_ocp.model.base.VehicleLayout`, or a vehicle
        that has one): a horizontal position fix, a DVL on the body linear velocities (the first
        ``len(positions)`` velocities), an attitude sensor on the angles, a gyro on the remaining
        (angular) velocities and, with three positions, a depth sensor on ``z``.
        """
        from uuv_ocp.model.base import VehicleLayout

        layout = vehicle if isinstance(vehicle, VehicleLayout) else getattr(vehicle, "layout", None)
        if not isinstance(layout, VehicleLayout):
            raise ValueError(
                f"vehicle must be a uuv_ocp vehicle (with a VehicleLayout) or a VehicleLayout, got "
                f"{type(vehicle).__name__}"
            )
        nx = layout.state_dim
        positions, velocities = layout.positions, layout.velocities
        linear = velocities[: len(positions)]
        rates = velocities[len(positions) :]
        angles = tuple(layout.angles)
        degree = math.pi / 180.0
        sensors = [
            Sensor.of_states("position", positions[:2], nx, 1.0, 0.5),
            Sensor.of_states("dvl", linear, nx, 5.0, 0.02, dropout=dvl_dropout),
            Sensor.of_states("attitude", angles, nx, 10.0, 0.5 * degree, angular=(True,) * len(angles)),
        ]
        if rates:
            sensors.append(Sensor.of_states("gyro", rates, nx, 10.0, 0.1 * degree))
        if len(positions) == 3:
            sensors.append(Sensor.of_states("depth", positions[2:], nx, 10.0, 0.05))
        return cls(sensors)
