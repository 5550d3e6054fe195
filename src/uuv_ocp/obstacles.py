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
from uuv_ocp._concurrency import BUILD_LOCK

CentrePath = Callable[[ca.SX], object]
#: Window (s) over which :func:`centre_motion` samples a moving obstacle on an endless reference.
MOTION_WINDOW = 3600.0
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

    def clearance(self, position: ca.SX, centre: ca.SX | None = None, tolerance: float = 0.0) -> ca.SX:
        """Smooth clearance (>= 0 outside) of ``position`` (2,) from the enlarged obstacle.

        ``tolerance`` (m, >= 0, :func:`between_nodes`) keeps the position that much further out:
        a circle's radius ``r + margin + tolerance``; an ellipse scaled about its centre by
        ``1 + tolerance / b'`` (``b'`` its smaller enlarged half-axis), which contains every
        point within ``tolerance`` of the enlarged ellipse.
        """
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
        tolerance = check.nonnegative_float("tolerance", tolerance)
        if self.kind == "circle":
            return ca.sumsqr(offset) - (self.axes[0] + self.margin + tolerance) ** 2
        cos_a, sin_a = math.cos(self.angle), math.sin(self.angle)
        xi = cos_a * offset[0] + sin_a * offset[1]
        eta = -sin_a * offset[0] + cos_a * offset[1]
        scale = 1.0 + tolerance / (min(self.axes) + self.margin)
        a, b = self.axes[0] + self.margin, self.axes[1] + self.margin
        return (xi / a) ** 2 + (eta / b) ** 2 - scale**2

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


def between_nodes(obstacle: Obstacle, dt: float, speed: float, acceleration: float = 0.0) -> float:
    """Tolerance (m) at the nodes that keeps a path out of ``obstacle`` between them too.

    A controller holds ``obstacle.clearance(p_k) >= 0`` at its nodes only, ``dt`` apart; in
    between the vehicle may cut into the enlarged obstacle.  If every node keeps
    ``obstacle.clearance(p_k, tolerance=δ) >= 0`` with the ``δ`` returned here, every point
    of a path between two such nodes whose speed is at most ``speed`` and whose acceleration
    is at most ``acceleration`` (relative to the obstacle's centre) stays out of the enlarged
    obstacle (``clearance >= 0``).

    Derivation.  Let ``p(t)``, ``0 <= t <= dt``, join two nodes ``A`` and ``B``.

    1. *Chord length*: ``L = ‖B − A‖ <= ∫‖ṗ‖ <= v dt``.
    2. *Distance from the chord*: ``e(t) = p(t) − ((1 − t/dt) A + (t/dt) B)`` vanishes at both
       ends and has ``ë = p̈``, so ``e(t) = −∫ G(t, τ) p̈(τ) dτ`` with Green's function
       ``G >= 0``, ``∫ G dτ = t (dt − t) / 2``: ``‖e(t)‖ <= a t (dt − t) / 2 <= a dt² / 8``.
    3. *Depth of a chord in a disc* of radius ``ρ`` with both ends outside it: the point of
       the chord nearest the centre, at distance ``h``, has both ends at least
       ``√(ρ² − h²)`` away on either side, so ``L >= 2 √(ρ² − h²)``: the chord enters the
       disc at most ``d(ρ, L) = ρ − √(ρ² − L²/4)`` deep (``ρ`` when ``L >= 2ρ``).
    4. *Convex obstacle*: the nodes are kept out of the tightened set ``K'`` (a circle of
       radius ``R + δ``; an ellipse scaled by ``s = 1 + δ/b``, half-axes ``a >= b``).  The
       smallest radius of curvature of ``K'`` is ``ρ' = s b²/a`` (``R + δ`` for a circle), so
       a disc of radius ``ρ'`` rolls freely inside ``K'`` (Blaschke): a chord point ``m``
       at depth ``d`` in ``K'`` is at depth ``d`` in the disc tangent at the boundary point
       nearest ``m``, whose outside holds the chord's ends, so ``d <= d(ρ', L)`` by 3. — as
       long as ``d <= ρ'``.  Always, the ball of radius ``d`` about ``m`` lies in ``K'`` and
       both ends lie outside it, so ``d <= L/2``: for ``L < 2ρ'`` this gives ``d < ρ'`` and
       the disc's bound holds; for ``L >= 2ρ'`` the depth bound is ``L/2`` (a flat
       ellipse's tip, whose interior reaches much deeper than ``ρ'``).
    5. *Containment*: ``K'`` contains every point within ``(s − 1) b = δ`` of the enlarged
       obstacle ``K`` (compare the support functions: ``s h_K(u) >= h_K(u) + (s − 1) b``);
       so a point of ``K`` lies at depth ``>= δ`` in ``K'``.  A path point is within
       ``a dt²/8`` (2.) of a chord point at depth ``<= d(ρ', L)`` (3., 4.); it is outside
       ``K`` whenever ``δ >= d(ρ', v dt) + a dt²/8`` (``v dt / 2 + a dt²/8`` when
       ``v dt >= 2ρ'``).

    For a circle of enlarged radius ``R`` the least such ``δ`` is closed-form,
    ``δ = √((R + a dt²/8)² + (v dt / 2)²) − R ≈ (v dt)² / (8R) + a dt²/8``; for an ellipse
    (the left side increases with ``δ``) it is found by bisection.

    Parameters
    ----------
    obstacle : Obstacle
        The obstacle (its axes enlarged by its margin count).
    dt : float
        Time between nodes (s), > 0.
    speed : float
        Largest speed (m/s) of the path relative to the obstacle's centre, >= 0.
    acceleration : float
        Largest acceleration (m/s²) of the path relative to the centre, >= 0.

    Returns
    -------
    float
        The tolerance ``δ`` (m), >= 0: 0 when ``speed`` and ``acceleration`` are 0.
    """
    if not isinstance(obstacle, Obstacle):
        raise ValueError(f"obstacle must be a uuv_ocp.Obstacle, got {obstacle!r}")
    dt = check.positive_float("dt", dt)
    chord = check.nonnegative_float("speed", speed) * dt
    bulge = check.nonnegative_float("acceleration", acceleration) * dt**2 / 8.0
    major, minor = max(obstacle.axes) + obstacle.margin, min(obstacle.axes) + obstacle.margin
    if obstacle.kind == "circle":
        return math.sqrt((major + bulge) ** 2 + (chord / 2.0) ** 2) - major

    def short(tolerance: float) -> float:
        """How much ``tolerance`` falls short of the depth bound (<= 0: enough); increasing."""
        radius = (1.0 + tolerance / minor) * minor**2 / major  # ρ' of the scaled ellipse
        depth = radius - math.sqrt(radius**2 - chord**2 / 4.0) if chord < 2.0 * radius else chord / 2.0
        return depth + bulge - tolerance

    low, high = 0.0, bulge + chord + major
    while short(high) > 0.0:  # the depth falls to 0 as the tolerance grows: this ends
        low, high = high, 2.0 * high
    for _ in range(100):  # to a relative 1e-15 or so
        middle = 0.5 * (low + high)
        low, high = (low, middle) if short(middle) <= 0.0 else (middle, high)
        if high - low <= 1e-15 * high:
            break
    return high


def centre_motion(
    obstacle: Obstacle, t_start: float, t_end: float, samples: int = 2001
) -> tuple[float, float]:
    """Largest speed (m/s) and acceleration (m/s²) of an obstacle's centre on ``[t_start, t_end]``.

    ``(0, 0)`` for a fixed obstacle; for a moving one the exact derivatives of its centre
    path (CasADi's), taken at ``samples`` evenly spaced times: a sampled maximum, exact
    for the straight and uniformly curving paths of the examples.  An infinite ``t_end`` (a
    reference without an end) stands for ``t_start`` + :data:`MOTION_WINDOW`.
    """
    if not isinstance(obstacle, Obstacle):
        raise ValueError(f"obstacle must be a uuv_ocp.Obstacle, got {obstacle!r}")
    if obstacle._path is None:
        return 0.0, 0.0
    t_start = check.finite_float("t_start", t_start)
    if t_end == math.inf:
        t_end = t_start + MOTION_WINDOW
    t_end = check.finite_float("t_end", t_end)
    if t_end < t_start:
        raise ValueError(f"t_end must be >= t_start = {t_start}, got {t_end}")
    samples = check.positive_int("samples", samples, minimum=2)
    times = np.linspace(t_start, t_end, samples).reshape(1, -1)
    with BUILD_LOCK:  # CasADi expressions and functions are built here (uuv_ocp._concurrency)
        time = ca.SX.sym("t")
        centre = obstacle._path(time)
        velocity = ca.jacobian(centre, time)
        motion = ca.Function("centre_motion", [time], [velocity, ca.jacobian(velocity, time)])
        speeds, accelerations = (np.array(v) for v in motion.map(samples)(times))
    return float(np.max(np.linalg.norm(speeds, axis=0))), float(np.max(np.linalg.norm(accelerations, axis=0)))


def vehicle_motion(vehicle: Any, levels: int = 5) -> tuple[float, float]:
    """Top horizontal speed (m/s) and a sampled largest horizontal acceleration (m/s²) of a vehicle.

    The speed is ``vehicle.max_horizontal_speed()[0]`` (over ground in still water).  The
    acceleration is the largest ``‖p̈‖ = ‖(∂ṗ/∂x) f(x, u)‖`` of the horizontal position ``p``
    over level states at rest in pose (roll, pitch, heading 0: ``‖p̈‖`` does not depend on
    the heading) with surge, sway and yaw rate each on ``levels`` values across
    ``±vehicle.max_speed()`` and every corner of the control box (and zero): a sampled
    maximum of the model's own dynamics, which the plan cannot exceed by much.

    Raises
    ------
    ValueError
        If the vehicle has no ``max_horizontal_speed`` or ``max_speed`` (give a tolerance).
    """
    from uuv_ocp.model.base import model_function  # the model package imports nothing from here

    if not (hasattr(vehicle, "max_horizontal_speed") and hasattr(vehicle, "max_speed")):
        raise ValueError(
            f"vehicle {getattr(vehicle, 'name', vehicle)!r} has no max_horizontal_speed() and max_speed(): "
            "obstacle_tolerance='auto' needs them; give a tolerance in metres"
        )
    levels = check.positive_int("levels", levels, minimum=2)
    layout = vehicle.layout
    speed = float(vehicle.max_horizontal_speed()[0])
    top = np.asarray(vehicle.max_speed(), dtype=float)
    # pose state j moves with velocity state velocities[j] (x: surge, y: sway, heading: yaw rate)
    moving = [layout.positions[0], layout.positions[1], layout.heading]
    grids = [np.linspace(-top[j], top[j], levels) for j in moving]
    states = np.zeros((layout.state_dim, levels**3))
    for j, values in zip(moving, np.meshgrid(*grids, indexing="ij"), strict=True):
        states[layout.velocities[j]] = values.ravel()
    bound = np.asarray(vehicle.control_bound, dtype=float)
    corners = np.array(np.meshgrid(*[(-1.0, 1.0)] * bound.size, indexing="ij")).reshape(bound.size, -1)
    controls = np.hstack([np.zeros((bound.size, 1)), corners * bound[:, None]])
    n_states, n_controls = states.shape[1], controls.shape[1]
    with BUILD_LOCK:  # CasADi expressions and functions are built here (uuv_ocp._concurrency)
        x = ca.SX.sym("x", layout.state_dim)
        u = ca.SX.sym("u", bound.size)
        rhs = model_function("vehicle", vehicle)(x, u, ca.DM.zeros(layout.current_dim))
        horizontal = rhs[list(layout.positions[:2])]
        second = ca.Function("p_ddot", [x, u], [ca.mtimes(ca.jacobian(horizontal, x), rhs)])
        every = second.map(n_states * n_controls)
        values = np.array(every(np.repeat(states, n_controls, axis=1), np.tile(controls, n_states)))
    return speed, float(np.max(np.linalg.norm(values, axis=0)))


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
