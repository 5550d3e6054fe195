"""Reference trajectories defined symbolically, with AD-derived pose and velocity.

A planar path ``(x_R(t), y_R(t))`` given as CasADi expressions of time defines the whole
reference state through the paper's Eq. (9):

    ψ_R = atan2(ẏ, ẋ),  u_R = √(ẋ² + ẏ²),  v_R = 0,  r_R = (ẋÿ − ẏẍ) / (ẋ² + ẏ²)

A heading ``ψ_R(t)`` may also be given independently of the tangent (a vehicle that crabs,
or holds station); then ``r_R = dψ_R/dt`` and the path velocity is rotated into the body frame,

    u_R = ẋ cos ψ_R + ẏ sin ψ_R,  v_R = −ẋ sin ψ_R + ẏ cos ψ_R,

and the path speed may vanish.  A spatial path ``(x_R, y_R, z_R)`` (NED, z down) gives the
12-state reference ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]`` of a 6-DOF vehicle with roll and
pitch regulated to zero, the heading of the horizontal motion as above and ``w_R = ż``.

All derivatives come from CasADi's algorithmic differentiation, never by hand or by finite
differences.  The heading returned by :meth:`Reference.evaluate` is continuous in time: it is
unwrapped with increments predicted by integrating ``r_R`` (Simpson's rule), so circles and
spirals never jump by 2π.
"""

from __future__ import annotations

import math
import numbers
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NoReturn

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK, serialised
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.reference.waypoints import PiecewiseExpression, WaypointPath, lawnmower_points

PathFunction = Callable[[ca.SX], Any]

#: Speed (m/s) below which the heading of a path is undefined.
MIN_PATH_SPEED = 1e-6
#: Largest gap (s) between the samples used to unwrap the heading.
UNWRAP_STEP = 0.1
#: Length of the planar state ``[x, y, ψ, u, v, r]`` and of the spatial state
#: ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]``.
PLANAR_STATE_DIM = 6
SPATIAL_STATE_DIM = 12
#: Default time (s) a waypoint mission stays at its last waypoint (:meth:`Reference.waypoints`):
#: longer than the usual horizons (N dt = 2 to 5 s) plus the vehicle's lag, so that a closed
#: loop, which ends N dt before the reference does, reaches the last waypoint.
WAYPOINT_HOLD = 10.0
#: Span (s) of an unbounded window that construction checks (:meth:`Reference.check_window`):
#: ten minutes, twenty times the paper's runs.
CHECK_SPAN = 600.0
#: Sample spacing (s) of that check, and the most samples it takes on a long window.
CHECK_STEP = 0.1
CHECK_SAMPLES = 20_001
#: Bisection steps that shrink a suspect sample interval to ~1e-11 of its width: a jump
#: keeps its size there, a continuous function changes by (derivative x width) ~ 0.
CHECK_BISECTIONS = 36
#: Most suspect intervals bisected (the largest scores first).
CHECK_CANDIDATES = 256
#: Relative size (of max(1, |value|)) from which a change over the final interval is a jump.
JUMP_TOLERANCE = 1e-6


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
    """A reference path ``(x_R(t), y_R(t)[, z_R(t)])`` and everything derived from it.

    Parameters
    ----------
    path_x, path_y : callable
        Functions of a CasADi ``SX`` time symbol ``t`` (s) returning the position (m): a scalar
        expression, or a :class:`~uuv_ocp.reference.waypoints.PiecewiseExpression` (piecewise
        paths such as :meth:`waypoints`).
    name : str
        Label used in tables and plots.
    t_start, t_end : float
        Time window (s) on which the path is valid; evaluation outside raises ``ValueError``.
    description : str
        Human-readable formula.
    path_z : callable or None
        Depth ``z_R(t)`` (m, NED: positive down) of a spatial reference (12 states), or
        ``None`` for a planar one (6 states).
    heading : callable or None
        Heading ``ψ_R(t)`` (rad, any continuous angle) independent of the path tangent, or
        ``None`` for the tangent heading ``atan2(ẏ, ẋ)`` (then the horizontal path speed must
        not vanish).
    """

    path_x: PathFunction
    path_y: PathFunction
    name: str = "reference"
    t_start: float = 0.0
    t_end: float = math.inf
    description: str = ""
    path_z: PathFunction | None = None
    heading: PathFunction | None = None
    _function: ca.Function = field(init=False, repr=False, compare=False)
    # the map of the Function over n times, by n (shared: Functions are only read), and each
    # thread's zero-copy callers of them (.maps, by n: buffers are written by every call)
    _maps: dict = field(init=False, repr=False, compare=False, default_factory=dict)
    # the position before its table look-ups: (time, position, [(constants, key, table), ...]), or
    # None (no look-up, or one without a table): Reference.piecewise_parts
    _piecewise: tuple | None = field(init=False, repr=False, compare=False, default=None)
    _callers: threading.local = field(init=False, repr=False, compare=False, default_factory=threading.local)

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one) and build the Function."""
        for label in ("path_x", "path_y"):
            value = getattr(self, label)
            if not callable(value):
                raise ValueError(f"{label} must be a callable of a casadi SX time symbol, got {value!r}")
        if self.path_z is not None and not callable(self.path_z):
            raise ValueError(
                f"path_z must be a callable of a casadi SX time symbol (depth in m) or None, "
                f"got {self.path_z!r}"
            )
        if self.heading is not None and not callable(self.heading):
            raise ValueError(
                f"heading must be a callable of a casadi SX time symbol (heading in rad) or None, "
                f"got {self.heading!r}"
            )
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a string, got {self.name!r}")
        if not isinstance(self.description, str):
            raise ValueError(f"description must be a string, got {self.description!r}")
        t_start = check.finite_float("t_start", self.t_start)
        if isinstance(self.t_end, bool) or not isinstance(self.t_end, (int, float)):
            raise ValueError(f"t_end must be a number (s), got {self.t_end!r}")
        t_end = float(self.t_end)
        if not t_end > t_start:
            raise ValueError(f"t_end must be > t_start = {t_start}, got {self.t_end!r}")
        object.__setattr__(self, "t_start", t_start)
        object.__setattr__(self, "t_end", t_end)
        object.__setattr__(self, "_function", self._build_function())
        self.check_window()

    # ---------------------------------------------------------------- layout
    @property
    def spatial(self) -> bool:
        """Whether the reference is spatial (12 states, 6-DOF) rather than planar (6 states)."""
        return self.path_z is not None

    @property
    def state_dim(self) -> int:
        """Length of the reference state: 6 (planar) or 12 (spatial)."""
        return SPATIAL_STATE_DIM if self.spatial else PLANAR_STATE_DIM

    @property
    def heading_index(self) -> int:
        """Column of the heading ψ_R in the state: 2 (planar) or 5 (spatial)."""
        return 5 if self.spatial else 2

    @property
    def _position_dim(self) -> int:
        return 3 if self.spatial else 2

    @property
    def _surge_index(self) -> int:
        return self.state_dim // 2

    @property
    def _rate_index(self) -> int:
        return self.state_dim - 1

    # ---------------------------------------------------------------- builders
    @classmethod
    def from_xy(
        cls,
        path_x: PathFunction,
        path_y: PathFunction,
        name: str = "reference",
        *,
        heading: PathFunction | None = None,
        t_start: float = 0.0,
        t_end: float = math.inf,
        description: str = "",
    ) -> Reference:
        """Planar reference from callables on a CasADi time symbol, e.g. ``lambda t: 2*ca.sin(t)``.

        Parameters
        ----------
        path_x, path_y : callable
            Position (m) as functions of the time symbol ``t`` (s).
        name : str
            Label.
        heading : callable or None
            ``ψ_R(t)`` (rad); default: the path tangent (whose speed must not vanish).
        t_start, t_end : float
            Validity window (s).
        description : str
            Human-readable formula.
        """
        return cls(path_x, path_y, name, t_start, t_end, description, heading=heading)

    @classmethod
    def from_xyz(
        cls,
        path_x: PathFunction,
        path_y: PathFunction,
        path_z: PathFunction,
        name: str = "reference",
        *,
        heading: PathFunction | None = None,
        t_start: float = 0.0,
        t_end: float = math.inf,
        description: str = "",
    ) -> Reference:
        """Spatial reference for a 6-DOF vehicle (NED, z down) from three callables.

        The state is ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]`` (m, rad, m/s, rad/s) with roll
        and pitch regulated (``φ_R = θ_R = p_R = q_R = 0``), ``ψ_R`` the horizontal tangent
        heading ``atan2(ẏ, ẋ)`` or ``heading(t)``, ``u_R, v_R`` the horizontal path velocity in
        the body frame, ``w_R = ż`` and ``r_R = dψ_R/dt``.  Without ``heading`` the horizontal
        path speed must not vanish.
        """
        return cls(path_x, path_y, name, t_start, t_end, description, path_z=path_z, heading=heading)

    @classmethod
    def paper(cls, name: str) -> Reference:
        """One of the paper's ten references ``"s1"`` ... ``"s10"`` (all with ``x = 0.5 t``).

        ``s3`` is a semicircle of radius 7.5 m whose tangent is vertical (infinite speed) at
        t = 0 s and t = 30 s; it is valid on [1.5, 28.5] s, where the path speed stays below
        1.4 m/s.  See ``docs/references.md`` for how the paper's garbled formulas were read.
        """
        catalogue = _paper_catalogue()
        if not isinstance(name, str) or name not in catalogue:
            raise ValueError(f"reference name must be one of {list(catalogue)}, got {check.shown(name)}")
        path_y, t_start, t_end, formula = catalogue[name]
        return cls(lambda t: 0.5 * t, path_y, name, t_start, t_end, f"x = 0.5t, {formula}")

    @classmethod
    def waypoints(
        cls,
        points: object,
        speed: float,
        turn_radius: float,
        name: str = "waypoints",
        t_start: float = 0.0,
        hold: float = WAYPOINT_HOLD,
    ) -> Reference:
        """Straight legs between waypoints joined by tangent circular arcs, at constant speed.

        Parameters
        ----------
        points : array_like, shape (n, 2) or (n, 3)
            Waypoints (m), n >= 2.  With three columns the reference is spatial and ``z`` is
            interpolated along the horizontal arc length (see
            :class:`~uuv_ocp.reference.waypoints.WaypointPath`).
        speed : float
            Constant path speed (m/s), > 0 (the horizontal speed for spatial waypoints).
        turn_radius : float
            Radius (m) of the arc that replaces every corner; it must fit into the legs.
        name : str
            Label.
        t_start : float
            Time (s) at the first waypoint; the last is reached at ``t_start + length / speed``.
        hold : float
            Time (s, >= 0) the reference then stays at the last waypoint, at rest with the last
            leg's heading.  It comes to rest at constant deceleration ``speed² / (2 b)`` over the
            last ``b = min(turn_radius, length / 2)`` metres (half the centripetal acceleration
            its turns already ask for), so position and velocity stay continuous:
            ``t_end = t_start + (length + b) / speed + hold``.  A closed loop's horizon must stay
            inside the reference, so it ends ``N dt`` before ``t_end``: with ``hold >= N dt``
            (plus the time the vehicle lags behind) the mission reaches its last waypoint.
            ``hold=0`` ends the reference on arrival, still moving (no braking).

        Returns
        -------
        Reference
            Position C¹ in time (continuous velocity) until the last waypoint, tangent heading,
            ``u_R = speed``, ``r_R = ±speed / turn_radius`` on arcs and 0 on legs; with
            ``hold > 0`` the braking stretch, then the last waypoint at rest.
        """
        geometry = WaypointPath(points, turn_radius)
        speed = check.positive_float("speed", speed)
        t_start = check.finite_float("t_start", t_start)
        hold = check.nonnegative_float("hold", hold)
        if not math.isfinite(hold):
            raise ValueError(f"hold must be a finite number of seconds >= 0, got {hold!r}")

        def arc_length(t: ca.SX) -> ca.SX:
            return speed * (t - t_start)

        description = (
            f"{geometry.count} {'spatial ' if geometry.spatial else ''}waypoints at {speed:g} m/s, "
            f"turn radius {geometry.turn_radius:g} m, length {geometry.length:g} m"
        )
        t_end = t_start + geometry.length / speed + hold
        heading = None  # the tangent's, from the velocity
        if hold > 0.0:
            # The path speed ramps down to rest at the last waypoint, so the reference stays C¹
            # (a step to rest would be a jump its AD derivatives miss); the heading is the path's
            # direction, which stays defined at rest (the tangent of a vanishing velocity does not).
            braking = min(geometry.turn_radius, 0.5 * geometry.length)
            deceleration = speed**2 / (2.0 * braking)
            cruise_end = t_start + (geometry.length - braking) / speed
            t_end = cruise_end + speed / deceleration + hold
            description += (
                f", braking over its last {braking:g} m at {deceleration:.3g} m/s², "
                f"then {hold:g} s at the last waypoint"
            )

            def arc_length(t: ca.SX) -> ca.SX:
                braked = ca.fmin(ca.fmax(t - cruise_end, 0.0), speed / deceleration)
                cruising = ca.fmin(speed * (t - t_start), geometry.length - braking)
                return cruising + braked * (speed - 0.5 * deceleration * braked)

            heading = lambda t: geometry.heading(arc_length(t))  # noqa: E731
        path_x = lambda t: geometry.horizontal(arc_length(t))[0]  # noqa: E731
        path_y = lambda t: geometry.horizontal(arc_length(t))[1]  # noqa: E731
        if not geometry.spatial:
            return cls(path_x, path_y, name, t_start, t_end, description, heading=heading)
        path_z = lambda t: geometry.depth(arc_length(t))  # noqa: E731
        return cls(path_x, path_y, name, t_start, t_end, description, path_z=path_z, heading=heading)

    @classmethod
    def lawnmower(
        cls,
        origin: object = (0.0, 0.0),
        *,
        width: float,
        spacing: float,
        lanes: int,
        speed: float,
        turn_radius: float | None = None,
        heading: float = 0.0,
        depth: float | None = None,
        name: str = "lawnmower",
        t_start: float = 0.0,
        hold: float = WAYPOINT_HOLD,
    ) -> Reference:
        """Boustrophedon survey of ``lanes`` parallel lanes of length ``width``.

        A preset of :meth:`waypoints`: lane ends in travel order, joined by turns.

        Parameters
        ----------
        origin : (float, float)
            Start of the first lane (m).
        width : float
            Lane length (m), > 0.
        spacing : float
            Distance between neighbouring lanes (m), > 0.
        lanes : int
            Number of lanes, >= 1.
        speed : float
            Path speed (m/s), > 0.
        turn_radius : float or None
            Radius of the turns (m); default ``spacing / 2`` (each lane change a semicircle).
        heading : float
            Direction of the first lane (rad, from the x axis towards the y axis).  The lanes
            are stacked in the direction ``heading + π/2`` (to starboard in NED).
        depth : float or None
            Constant depth (m, z down) of a spatial survey, or ``None`` for a planar one.
        name : str
            Label.
        t_start : float
            Time (s) at the start of the first lane.
        hold : float
            Time (s, >= 0) at the end of the last lane, at rest (see :meth:`waypoints`).
        """
        points = lawnmower_points(origin, width, spacing, lanes, heading, depth)
        spacing = float(spacing)
        radius = spacing / 2.0 if turn_radius is None else turn_radius
        return cls.waypoints(points, speed, radius, name, t_start, hold)

    @classmethod
    def hold(cls, pose: object, name: str = "hold", duration: float = math.inf) -> Reference:
        """Station keeping: constant position and heading, zero velocities, on ``[0, duration]``.

        Parameters
        ----------
        pose : array_like, shape (3,) or (4,)
            ``(x, y, ψ)`` for a planar reference or ``(x, y, z, ψ)`` for a spatial one
            (m, rad; any ψ: it is not tied to a path tangent).
        name : str
            Label.
        duration : float
            Length of the window (s), > 0, may be ``math.inf``.
        """
        try:
            values = np.asarray(pose, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"pose must be (x, y, psi) or (x, y, z, psi) in m and rad, got {pose!r}"
            ) from error
        if values.shape not in ((3,), (4,)):
            raise ValueError(
                f"pose must be (x, y, psi) or (x, y, z, psi) in m and rad, got shape {values.shape}: {pose!r}"
            )
        if not np.all(np.isfinite(values)):
            raise ValueError(f"pose must be finite, got {pose!r}")
        if (
            isinstance(duration, bool)
            or not isinstance(duration, numbers.Real)
            or math.isnan(duration)
            or not duration > 0
        ):
            raise ValueError(f"duration must be a number > 0 (s, may be math.inf), got {duration!r}")
        *position, psi = (float(v) for v in values)

        def constant(value: float) -> PathFunction:
            return lambda t: value + 0 * t

        description = "hold " + ", ".join(
            f"{label} = {value:g}" for label, value in zip("xyz", position, strict=False)
        )
        description += f" m, psi = {psi:g} rad"
        paths = [constant(value) for value in position]
        return cls(
            paths[0],
            paths[1],
            name,
            0.0,
            float(duration),
            description,
            path_z=paths[2] if len(paths) == 3 else None,
            heading=constant(psi),
        )

    @staticmethod
    def _expression(label: str, function: PathFunction, time: ca.SX, placeholders: list) -> ca.SX:
        """``function(time)`` as a scalar SX expression, or a ``ValueError`` naming ``label``.

        The placeholders of a :class:`PiecewiseExpression` are appended to ``placeholders`` as
        ``(constants, values)``, to be substituted after differentiation.
        """
        try:
            result = function(time)
            if isinstance(result, PiecewiseExpression):
                placeholders.append((result.constants, result.values, result.key, result.table))
                result = result.expression
            expression = ca.SX(result) + 0 * time
        except Exception as error:  # user callables may fail in many ways
            raise ValueError(
                f"{label} must accept a casadi SX symbol and return a scalar expression; "
                f"calling it failed with: {error}"
            ) from error
        if expression.shape != (1, 1):
            raise ValueError(f"{label} must return a scalar expression, got shape {expression.shape}")
        return expression

    @serialised
    def _build_function(self) -> ca.Function:
        time = ca.SX.sym("t")
        placeholders: list[tuple[Any, ...]] = []
        position_x = self._expression("path_x", self.path_x, time, placeholders)
        position_y = self._expression("path_y", self.path_y, time, placeholders)
        velocity_x = ca.jacobian(position_x, time)
        velocity_y = ca.jacobian(position_y, time)
        if self.heading is None:
            acceleration_x = ca.jacobian(velocity_x, time)
            acceleration_y = ca.jacobian(velocity_y, time)
            speed_squared = velocity_x**2 + velocity_y**2
            heading = ca.atan2(velocity_y, velocity_x)
            surge, sway = ca.sqrt(speed_squared), 0 * time
            yaw_rate = (velocity_x * acceleration_y - velocity_y * acceleration_x) / speed_squared
        else:
            angle = self._expression("heading", self.heading, time, placeholders)
            # wrapped into (−π, π]; exact for angles already in that range
            heading = angle - 2.0 * math.pi * ca.ceil((angle - math.pi) / (2.0 * math.pi))
            cos_psi, sin_psi = ca.cos(angle), ca.sin(angle)
            surge = velocity_x * cos_psi + velocity_y * sin_psi
            sway = -velocity_x * sin_psi + velocity_y * cos_psi
            yaw_rate = ca.jacobian(angle, time)
        if self.path_z is not None:
            position_z = self._expression("path_z", self.path_z, time, placeholders)
            zero = 0 * time
            outputs = ca.vertcat(
                position_x, position_y, position_z, zero, zero, heading,
                surge, sway, ca.jacobian(position_z, time), zero, zero, yaw_rate,
            )  # fmt: skip
        else:
            outputs = ca.vertcat(position_x, position_y, heading, surge, sway, yaw_rate)
        if placeholders and all(table is not None for *_, table in placeholders):
            parts = [(constants, key, table) for constants, _, key, table in placeholders]
            position = ca.vertcat(position_x, position_y, *([position_z] if self.path_z is not None else []))
            object.__setattr__(self, "_piecewise", (time, position, parts))
        if placeholders:  # piecewise constants were held fixed for the derivatives: now their values
            constants = ca.vertcat(*[entry[0] for entry in placeholders])
            values = ca.vertcat(*[entry[1] for entry in placeholders])
            outputs = ca.substitute(outputs, constants, values)
        free = [symbol for symbol in ca.symvar(outputs) if not ca.is_equal(symbol, time)]
        if free:
            raise ValueError(
                f"path_x, path_y, path_z and heading must depend on the time symbol only, got the free "
                f"symbols {[symbol.name() for symbol in free]}"
            )
        # CasADi accepts letters, digits and single underscores in a Function name; the
        # reference's own name is a free label ("fast circle", "s-curve")
        label = "_".join(re.findall(r"[0-9A-Za-z]+", self.name))
        name = f"reference_{label}" if label else "reference"
        if self.heading is None and not self.spatial:  # the paper's references: as they always were
            return ca.Function(name, [time], [outputs], ["t"], ["state"])
        # piecewise paths (waypoints) look their pieces up once for x and once for y: share that
        return ca.Function(name, [time], [outputs], ["t"], ["state"], {"cse": True})

    @property
    def piecewise_parts(self) -> tuple[ca.SX, ca.SX, list[tuple[ca.SX, ca.SX, tuple]]] | None:
        """The position before its piecewise constants are looked up, or ``None``.

        ``(t, position, parts)``: the position ``(x, y[, z])`` (m) in the time symbol ``t`` and
        each :class:`~uuv_ocp.reference.waypoints.PiecewiseExpression`'s placeholder
        ``constants``, with ``parts`` their ``(constants, key, table)`` (the key an expression
        of ``t``).  ``None`` for a reference without look-ups or with one that has no table.
        Substituting each ``constants`` by its table's row at ``key`` gives the position of
        :attr:`function`; its derivative in ``t`` with the constants held is the velocity.
        """
        return self._piecewise

    # ------------------------------------------------------------ construction check
    def check_window(self) -> None:
        """Refuse a path that is not finite, not moving, implausibly far, or not C¹ on its window.

        Run at construction on ``[t_start, t_end]`` (the first ``CHECK_SPAN`` = 600 s of an
        unbounded window), sampled every ``CHECK_STEP`` = 0.1 s (at most ``CHECK_SAMPLES``
        samples).  ``ValueError``, naming the first time concerned, when

        * the position (or a given heading, velocity or yaw rate) is not finite at a sample, or
          the path does not move (speed below ``MIN_PATH_SPEED`` at every sample: its tangent
          heading is undefined everywhere; an isolated stop is allowed, and raises only when a
          window containing it is evaluated);
        * a position lies beyond ±1e9 m (``PLAUSIBLE_MAGNITUDE``: a unit or typing mistake);
        * the position, the velocity or a given heading jumps (a step or a kink of the path).

        A jump is found by bisection: sample intervals whose position change disagrees with
        the trapezoidal integral of the velocity, or whose velocity or heading change departs
        from its neighbours', are halved ``CHECK_BISECTIONS`` times towards the half with the
        larger change; a change still above ``JUMP_TOLERANCE`` x max(1, |value|) there is a
        jump.  A jump is refused rather than warned about: the derivatives come from AD, so
        the reference velocity and yaw rate miss it entirely (``y = |t − 5|`` gives ``r_R = 0``
        while the heading turns by 90°), and the controller would track a state that is not a
        motion at all.  Curvature may jump (``Reference.waypoints`` joins legs and arcs so).
        """
        span = min(self.t_end, self.t_start + CHECK_SPAN) - self.t_start
        count = int(min(CHECK_SAMPLES, max(257, math.ceil(span / CHECK_STEP) + 1)))
        grid = np.linspace(self.t_start, self.t_start + span, count)
        states = self._raw(grid)
        bad = self._defective(states)
        moving = states[:, self._surge_index]
        if (
            self.heading is None
            and np.all(np.isfinite(states[:, : self._position_dim]))
            and np.all(~(moving >= MIN_PATH_SPEED))
        ):
            kind = "horizontal speed" if self.spatial else "speed"
            raise ValueError(
                f"reference {self.name!r} does not move{' horizontally' if self.spatial else ''}: its "
                f"{kind} is below {MIN_PATH_SPEED:g} m/s at "
                f"every sampled time of [{self.t_start:g}, {self.t_start + span:g}] s, so its tangent "
                "heading is undefined; give heading= (or use Reference.hold to keep station)"
            )
        # an isolated point where the path stops (its tangent heading undefined) is allowed: only
        # a window containing it raises, at evaluation; a position or a given heading must be
        # defined everywhere
        undefined = ~np.all(np.isfinite(states[:, : self._position_dim]), axis=1)
        if self.heading is not None:
            undefined |= bad
        if np.any(undefined):
            row = int(np.argmax(undefined))
            self._raise_defect(grid[row : row + 1])
        positions = states[:, : self._position_dim]
        far = np.abs(positions) > check.PLAUSIBLE_MAGNITUDE
        if np.any(far):
            row = int(np.argmax(np.any(far, axis=1)))
            raise ValueError(
                f"reference {self.name!r}: its position {tuple(float(v) for v in positions[row])} m at "
                f"t = {grid[row]:g} s lies beyond ±{check.PLAUSIBLE_MAGNITUDE:g} m (a plausibility bound)"
            )
        jump = self._find_jump(grid, states)
        if jump is not None:
            when, what, size, unit = jump
            raise ValueError(
                f"reference {self.name!r} must be continuous in position and velocity (C¹ in time), "
                f"but its {what} jumps by {size:.3g} {unit} at t = {when:.6g} s; AD derivatives miss a jump, "
                "so join straight legs with Reference.waypoints (tangent arcs) or smooth the path"
            )

    def _motion(self, states: np.ndarray) -> dict[str, tuple[np.ndarray, str]]:
        """Position, world-frame velocity and (if given) heading of ``states``, with their units."""
        spatial = self.spatial
        psi = states[:, self.heading_index]
        surge, sway = states[:, self._surge_index], states[:, self._surge_index + 1]
        cos_psi, sin_psi = np.cos(psi), np.sin(psi)
        velocity = [surge * cos_psi - sway * sin_psi, surge * sin_psi + sway * cos_psi]
        if spatial:
            velocity.append(states[:, 8])
        parts = {
            "position": (states[:, : self._position_dim], "m"),
            "velocity": (np.stack(velocity, axis=1), "m/s"),
        }
        if self.heading is not None:
            parts["heading"] = (psi[:, None], "rad")
        return parts

    def _interval_scores(
        self, start: np.ndarray, end: np.ndarray, start_states: np.ndarray, end_states: np.ndarray
    ) -> np.ndarray:
        """Return the changes over each interval ``[start[i], end[i]]`` (m, m/s, rad), one column each.

        Columns: the position change minus the trapezoidal integral of the velocity (O(w³) if
        smooth), the velocity change (O(w)), and the heading change minus the integral of the
        yaw rate (a given heading only; else 0).
        """
        first, last = self._motion(start_states), self._motion(end_states)
        width = (end - start)[:, None]
        position, velocity = first["position"][0], first["velocity"][0]
        position_end, velocity_end = last["position"][0], last["velocity"][0]
        residual = position_end - position - 0.5 * width * (velocity + velocity_end)
        scores = np.zeros((start.size, 3))
        scores[:, 0] = np.linalg.norm(residual, axis=1)
        scores[:, 1] = np.linalg.norm(velocity_end - velocity, axis=1)
        if "heading" in first:
            psi, psi_end = first["heading"][0][:, 0], last["heading"][0][:, 0]
            rate, rate_end = start_states[:, self._rate_index], end_states[:, self._rate_index]
            turned = (psi_end - psi + math.pi) % (2.0 * math.pi) - math.pi
            scores[:, 2] = np.abs(turned - 0.5 * width[:, 0] * (rate + rate_end))
        return scores

    def _find_jump(self, grid: np.ndarray, states: np.ndarray) -> tuple[float, str, float, str] | None:
        """Return ``(time, what, size, unit)`` of a jump of position, velocity or heading, or ``None``."""
        motion = self._motion(states)
        # one scale per column over the window (relative to max(1, largest value))
        scale = np.array(
            [
                max(1.0, float(np.max(np.linalg.norm(motion[what][0], axis=1))))
                for what in ("position", "velocity")
            ]
            + [1.0]
        )
        scores = self._interval_scores(grid[:-1], grid[1:], states[:-1], states[1:]) / scale
        # every change of a smooth path varies smoothly from interval to interval; a jump is a
        # spike (compared with the intervals two away: a jump on a sample splits over two)
        padded = np.pad(scores, ((2, 2), (0, 0)), mode="edge")
        typical = np.maximum(padded[:-4], padded[4:])
        score = np.max(scores - 2.0 * typical, axis=1)
        suspects = np.flatnonzero(score > JUMP_TOLERANCE)
        if suspects.size == 0:
            return None
        suspects = suspects[np.argsort(-score[suspects])[:CHECK_CANDIDATES]]
        low, high = grid[suspects].copy(), grid[suspects + 1].copy()
        low_states, high_states = states[suspects].copy(), states[suspects + 1].copy()
        count = low.size
        index = np.arange(count)
        conclusive = np.ones(count, dtype=bool)
        for _ in range(CHECK_BISECTIONS):
            middle = 0.5 * (low + high)
            mid_states = self._raw(middle)
            # a stop between samples (undefined tangent heading, NaN yaw rate): that interval
            # cannot shrink, so it says nothing; evaluation names the stop when a window holds it
            conclusive &= np.all(np.isfinite(mid_states), axis=1)
            left = (self._interval_scores(low, middle, low_states, mid_states) / scale).max(axis=1)
            right = (self._interval_scores(middle, high, mid_states, high_states) / scale).max(axis=1)
            go_left = (left >= right) | ~conclusive
            high = np.where(go_left, middle, high)
            high_states = np.where(go_left[:, None], mid_states, high_states)
            low = np.where(go_left, low, middle)
            low_states = np.where(go_left[:, None], low_states, mid_states)
        parts_low, parts_high = self._motion(low_states), self._motion(high_states)
        for what, (values, unit) in parts_low.items():
            other = parts_high[what][0]
            difference = other - values
            if what == "heading":
                difference = (difference + math.pi) % (2.0 * math.pi) - math.pi
            size = np.linalg.norm(difference, axis=1)
            scale = np.maximum(1.0, np.maximum(np.linalg.norm(values, axis=1), np.linalg.norm(other, axis=1)))
            jumped = index[(size > JUMP_TOLERANCE * scale) & conclusive]
            if jumped.size:
                first = jumped[np.argmin(low[jumped])]
                return float(0.5 * (low[first] + high[first])), what, float(size[first]), unit
        return None

    # -------------------------------------------------------------- evaluation
    @property
    def function(self) -> ca.Function:
        """``t -> state`` as a CasADi Function, with the heading wrapped into (−π, π].

        The state is ``[x_R, y_R, ψ_R, u_R, v_R, r_R]`` (planar) or
        ``[x_R, y_R, z_R, φ_R, θ_R, ψ_R, u_R, v_R, w_R, p_R, q_R, r_R]`` (spatial).
        """
        return self._function

    def _raw(self, times: np.ndarray) -> np.ndarray:
        size = times.size
        callers = getattr(self._callers, "maps", None)
        if callers is None:  # the first evaluation in this thread
            callers = self._callers.maps = {}
        caller = callers.get(size)
        if caller is None:
            with BUILD_LOCK:  # CasADi would build a new map on every horzcat call: once per size
                if size not in self._maps:
                    self._maps[size] = self._function.map(size)
                caller = callers[size] = BufferedFunction(self._maps[size])
        (states,) = caller(times)
        return states.reshape(size, -1)

    def evaluate(self, times: object) -> np.ndarray:
        """Evaluate the reference state at the given times, with a continuous heading.

        Parameters
        ----------
        times : array_like, shape (n,)
            Non-decreasing times (s) inside ``[t_start, t_end]``.

        Returns
        -------
        numpy.ndarray, shape (n, state_dim)
            Planar: ``[x_R, y_R, ψ_R, u_R, v_R, r_R]`` (m, m, rad, m/s, m/s, rad/s).
            Spatial: ``[x_R, y_R, z_R, φ_R, θ_R, ψ_R, u_R, v_R, w_R, p_R, q_R, r_R]``
            (m, rad, m/s, rad/s).  ``ψ_R`` (column :attr:`heading_index`) at the first time
            lies in (−π, π]; later values are unwrapped.
        """
        try:
            times = np.atleast_1d(np.asarray(times, dtype=float))
        except (TypeError, ValueError) as error:
            raise ValueError(f"times must be real numbers (s), got {check.shown(times)}") from error
        if times.ndim != 1 or times.size == 0:
            raise ValueError(f"times must be a non-empty 1-D array (s), got shape {times.shape}")
        if not np.all(np.isfinite(times)):
            raise ValueError(f"times must be finite, got {check.shown(times)}")
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
            self._raise_defect(dense)
        if dense.size == times.size:
            return states
        return states[np.searchsorted(dense, times)]

    def evaluate_grid(self, times: np.ndarray) -> np.ndarray:
        """Fast :meth:`evaluate` for a grid the caller has already checked.

        ``times`` must be strictly increasing, inside the window, with gaps <= 0.1 s (the
        closed loop's reference windows).  Falls back to :meth:`evaluate` (and its error
        messages) if the state is not finite or the tangent heading is undefined.
        """
        states = self._states_on_grid(times)
        return self.evaluate(times) if states is None else states

    def _defective(self, states: np.ndarray) -> np.ndarray:
        """Rows whose state is not finite or whose tangent heading is undefined."""
        bad = ~np.all(np.isfinite(states), axis=1)
        if self.heading is None:
            bad |= states[:, self._surge_index] < MIN_PATH_SPEED
        return bad

    def _states_on_grid(self, grid: np.ndarray) -> np.ndarray | None:
        """Return the states with unwrapped heading on a fine increasing grid.

        ``None`` if the state is not finite (or the tangent heading undefined) somewhere on the
        grid or its midpoints.
        """
        midpoints = 0.5 * (grid[:-1] + grid[1:])
        both = self._raw(np.concatenate([grid, midpoints]))  # one call for grid and midpoints
        states, mid_rate = both[: grid.size], both[grid.size :, self._rate_index]
        if np.any(self._defective(states)) or not np.all(np.isfinite(mid_rate)):
            return None
        column = self.heading_index
        states[:, column] = _unwrapped_heading(grid, states[:, column], states[:, self._rate_index], mid_rate)
        return states

    def _raise_defect(self, grid: np.ndarray) -> NoReturn:
        """Raise the ``ValueError`` explaining why the state on ``grid`` cannot be returned."""
        probe = np.unique(np.concatenate([grid, 0.5 * (grid[:-1] + grid[1:])]))
        raw = self._raw(probe)
        bad = self._defective(raw)
        if not np.any(bad):  # cannot happen: _states_on_grid failed on these times
            raise ValueError(f"reference {self.name!r} cannot be evaluated on t = {grid!r}")
        row = int(np.argmax(bad))
        when, state = probe[row], raw[row]
        position = state[: self._position_dim]
        if not np.all(np.isfinite(position)):
            raise ValueError(
                f"reference {self.name!r}: its position is not finite at t = {when} s "
                f"(got {tuple(float(v) for v in position)} m)"
            )
        speed = float(state[self._surge_index])
        if self.heading is None and not (np.isfinite(speed) and speed >= MIN_PATH_SPEED):
            kind = "horizontal speed" if self.spatial else "speed"
            raise ValueError(
                f"reference {self.name!r} has a vanishing or non-finite {kind} at t = {when} s "
                f"(speed {speed:g} m/s): its heading is undefined there"
            )
        raise ValueError(
            f"reference {self.name!r} has a non-finite heading, velocity or yaw rate at t = {when} s "
            f"(state {tuple(float(v) for v in state)})"
        )

    def initial_state(self, t0: float | None = None) -> np.ndarray:
        """Pose on the reference at ``t0`` (default ``t_start``), at rest.

        Returns
        -------
        numpy.ndarray, shape (state_dim,)
            The reference pose with every velocity set to zero.
        """
        t0 = self.t_start if t0 is None else check.finite_float("t0", t0)
        state = self.evaluate([t0])[0]
        state[self.state_dim // 2 :] = 0.0
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
    """Return ``times`` plus extra points so that no gap exceeds ``UNWRAP_STEP``; sorted, unique."""
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
