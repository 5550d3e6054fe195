"""Keep-out zones in the horizontal plane: circles, ellipses, and moving obstacles.

An obstacle is a region the vehicle's horizontal position must stay out of, enlarged by a
safety ``margin`` (the vehicle's radius, m).  It enters an optimal-control problem as the smooth
path constraint ``clearance(p) >= 0`` on nodes 1..N:

* circle of radius ``r`` at ``c``: ``clearance = ‖p − c‖² − (r + margin)²`` (m²);
* ellipse with half-axes ``(a, b)`` turned by ``angle``: ``clearance = (ξ/(a + m))² +
  (η/(b + m))² − 1`` with ``(ξ, η) = R(angle)ᵀ (p − c)`` (dimensionless);

exact solvers hold it as a hard constraint, derivative-free solvers see its violation as the
exact penalty ``constraint_penalty · Σ max(0, −clearance)``, and :func:`uuv_ocp.score` reports
it.  A moving obstacle's centre is a function of time (another vehicle on a known path); it
enters as a stagewise parameter sampled at the nodes ``t0 + k dt``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check

CentrePath = Callable[[ca.SX], object]
KINDS = ("circle", "ellipse")


@dataclass(frozen=True)
class Obstacle:
    """A circular or elliptical keep-out zone, fixed or moving.

    Parameters
    ----------
    kind : {"circle", "ellipse"}
    centre : tuple of 2 floats, or callable
        Centre (m), or a function of a CasADi time symbol ``t`` (s) returning ``(x, y)`` (m).
    axes : tuple of 2 floats
        Half-axes (m), both equal to the radius for a circle, > 0.
    angle : float
        Rotation of the first axis from the x axis (rad).
    margin : float
        Safety margin added to the axes (the vehicle's radius, m), >= 0.
    name : str
        Label.

    Use the constructors :meth:`circle`, :meth:`ellipse` and :meth:`moving`.
    """

    kind: str
    centre: tuple[float, float] | CentrePath
    axes: tuple[float, float]
    angle: float = 0.0
    margin: float = 0.0
    name: str = "obstacle"
    _path: ca.Function | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Check the fields; a callable centre is compiled into a CasADi function of time."""
        check.choice("kind", self.kind, KINDS)
        axes = check.vector("axes", self.axes, 2, positive=True)
        if self.kind == "circle" and axes[0] != axes[1]:
            raise ValueError(f"a circle has equal axes, got {axes}")
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "angle", check.finite_float("angle", self.angle))
        object.__setattr__(self, "margin", check.nonnegative_float("margin", self.margin))
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a string, got {self.name!r}")
        if callable(self.centre):
            object.__setattr__(self, "_path", _centre_function(self.centre))
        else:
            object.__setattr__(self, "centre", check.vector("centre", self.centre, 2))

    # ------------------------------------------------------------ constructors
    @classmethod
    def circle(cls, centre: object, radius: float, *, margin: float = 0.0, name: str = "circle") -> Obstacle:
        """Make a circle of ``radius`` (m) at ``centre`` (m, or a function of time for a moving one)."""
        radius = check.positive_float("radius", radius)
        return cls("circle", centre, (radius, radius), 0.0, margin, name)  # type: ignore[arg-type]

    @classmethod
    def ellipse(
        cls, centre: object, axes: object, angle: float = 0.0, *, margin: float = 0.0, name: str = "ellipse"
    ) -> Obstacle:
        """Make an ellipse with half-axes ``axes`` (m) turned by ``angle`` (rad) at ``centre``."""
        return cls("ellipse", centre, axes, angle, margin, name)  # type: ignore[arg-type]

    @classmethod
    def moving(
        cls, path: CentrePath, radius: float, *, margin: float = 0.0, name: str = "moving"
    ) -> Obstacle:
        """Make a circle whose centre follows ``path(t) -> (x, y)`` (CasADi expressions of ``t``)."""
        if not callable(path):
            raise ValueError(f"path must be a function of time t returning (x, y), got {path!r}")
        return cls.circle(path, radius, margin=margin, name=name)

    # ------------------------------------------------------------- geometry
    @property
    def is_moving(self) -> bool:
        """Whether the centre is a function of time."""
        return self._path is not None

    @property
    def radius(self) -> float:
        """Radius (m) of a circle (the larger half-axis of an ellipse)."""
        return float(max(self.axes))

    def centre_at(self, times: object) -> np.ndarray:
        """Centre (m) at the given times (s): shape (n, 2)."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if self._path is None:
            return np.tile(np.asarray(self.centre, dtype=float), (times.size, 1))
        values = np.array(self._path.map(times.size)(times.reshape(1, -1))).T
        if not np.all(np.isfinite(values)):
            raise ValueError(f"obstacle {self.name!r}: the centre path is not finite at some t in {times}")
        return values

    def clearance(self, position: ca.SX, centre: ca.SX | None = None) -> ca.SX:
        """Smooth clearance (>= 0 outside) of ``position`` (2,) from the enlarged obstacle."""
        c: ca.SX | ca.DM
        if centre is not None:
            c = centre
        elif callable(self.centre):
            raise ValueError(
                f"obstacle {self.name!r} moves: pass its centre at the node (a stagewise parameter)"
            )
        else:
            c = ca.DM(self.centre)
        offset = position[:2] - c
        if self.kind == "circle":
            return ca.sumsqr(offset) - (self.axes[0] + self.margin) ** 2
        cos_a, sin_a = math.cos(self.angle), math.sin(self.angle)
        xi = cos_a * offset[0] + sin_a * offset[1]
        eta = -sin_a * offset[0] + cos_a * offset[1]
        return (xi / (self.axes[0] + self.margin)) ** 2 + (eta / (self.axes[1] + self.margin)) ** 2 - 1.0

    def signed_distance(self, positions: object, times: object = 0.0, *, margin: bool = True) -> np.ndarray:
        """Euclidean distance (m) from each position to the enlarged boundary; < 0 inside.

        Exact for circles; for ellipses the distance along the ray from the centre (a bound
        that has the same sign as the true distance and is exact on the axes).  With
        ``margin=False`` the distance to the obstacle itself (its axes without the safety
        margin): < 0 is a collision of the vehicle's reference point.
        """
        extra = self.margin if margin else 0.0
        points = np.atleast_2d(np.asarray(positions, dtype=float))[:, :2]
        centres = self.centre_at(np.broadcast_to(np.asarray(times, dtype=float), (points.shape[0],)))
        offset = points - centres
        if self.kind == "circle":
            return np.linalg.norm(offset, axis=1) - (self.axes[0] + extra)
        cos_a, sin_a = math.cos(self.angle), math.sin(self.angle)
        xi = cos_a * offset[:, 0] + sin_a * offset[:, 1]
        eta = -sin_a * offset[:, 0] + cos_a * offset[:, 1]
        a, b = self.axes[0] + extra, self.axes[1] + extra
        norm = np.hypot(xi, eta)
        scaled = np.sqrt((xi / a) ** 2 + (eta / b) ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            boundary = np.where(scaled > 0, norm / scaled, min(a, b))
        return norm - boundary


def closest_approach(obstacles: Sequence[Obstacle], run: Any, *, margin: bool = True) -> float:
    """Smallest signed distance (m) of a closed-loop run to any of ``obstacles``.

    Over every plant integration step when the run recorded them
    (``simulate(..., record_substeps=True)``: between control instants the path may cut an
    obstacle's edge that the controller only constrains at its nodes), else over the control
    instants.  ``margin=True``: to the enlarged obstacles (< 0: the safety margin was
    entered); ``margin=False``: to the obstacles themselves (< 0: a collision).
    """
    if not obstacles or not all(isinstance(o, Obstacle) for o in obstacles):
        raise ValueError(f"obstacles must be a non-empty list of uuv_ocp.Obstacle, got {obstacles!r}")
    if not all(hasattr(run, name) for name in ("t", "states", "substep_t", "substep_states")):
        raise ValueError(f"run must be a uuv_ocp.ClosedLoopResult, got {type(run).__name__}")
    sampled = run.substep_t.size > 0
    times = run.substep_t if sampled else run.t
    states = run.substep_states if sampled else run.states
    return min(float(np.min(o.signed_distance(states, times, margin=margin))) for o in obstacles)


def _centre_function(path: CentrePath) -> ca.Function:
    time = ca.SX.sym("t")
    try:
        value: Any = path(time)  # the user's (x, y): iterated and checked below
        centre = ca.vertcat(*[ca.SX(v) + 0 * time for v in value])
    except Exception as error:  # user callables may fail in many ways
        raise ValueError(
            f"centre must be (x, y) or a function of a casadi SX time symbol t returning (x, y); calling "
            f"it failed with: {error}"
        ) from error
    if centre.shape != (2, 1):
        raise ValueError(f"centre path must return 2 values (x, y), got shape {centre.shape}")
    return ca.Function("obstacle_centre", [time], [centre], ["t"], ["centre"])


def check_obstacles(obstacles: object) -> tuple[Obstacle, ...]:
    """Validate a sequence of obstacles."""
    if obstacles is None:
        return ()
    if isinstance(obstacles, Obstacle) or not isinstance(obstacles, (list, tuple)):
        raise ValueError(f"obstacles must be a list of uuv_ocp.Obstacle, got {obstacles!r}")
    for item in obstacles:
        if not isinstance(item, Obstacle):
            raise ValueError(f"obstacles must contain uuv_ocp.Obstacle objects, got {item!r}")
    return tuple(obstacles)
