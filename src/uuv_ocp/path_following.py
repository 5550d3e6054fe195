"""Path following: converge to a geometric path, then move along it at a commanded speed.

:class:`PathFollowingProblem` is the preset for vehicles that cannot hold an arbitrary pose in
time (torpedo AUVs such as :class:`~uuv_ocp.model.remus100.Remus100`: no sway thrust), and for
any vehicle of the :class:`~uuv_ocp.model.base.VehicleModel` protocol.  Its
:attr:`~uuv_ocp.tracking.DeclaredPreset.ocp` declares:

* the state ``[x, s]``: the vehicle's state ``x`` and the **path parameter** ``s``, which is the
  :class:`~uuv_ocp.reference.path.Reference`'s own time τ (s) — so the path point ``p(s)`` and
  its tangent ``p'(s) = dp/dτ`` are the reference's exact AD expressions, for every kind of
  reference (``from_xy``, ``from_xyz``, ``waypoints`` with turn radii, ``lawnmower``);
* the control ``[τ, v_s]``: the vehicle's controls and the **along-path speed** ``v_s`` (m/s),
  with bounds ``[0, max_path_speed]`` and the rate bound ``path_acceleration`` (m/s²); the
  path parameter moves as ``ṡ = v_s / |p'(s)|``, so ``v_s`` is the speed of ``p(s)`` along the
  path in m/s whatever the reference's timing (the effect of an arc-length parameterisation,
  without inverting an arc-length integral: a reference timed twice as fast gives the same
  optimal vehicle path);
* the least-squares cost ``Σ_k ‖Δu_k / u_max‖²_rate + ‖τ_k / τ_max‖²_effort + w_v (v_s,k − U)² +
  w_u (u_k − v_s,k)² + Σ_{k=1}^{N} ℓ(x_k, s_k)`` (``u`` the surge) with ``ℓ = w_a e_a² + w_c
  e_c² + w_z e_z² + w_att ‖(φ, θ)‖²``, where the errors of the vehicle's position from ``p(s)``
  are expressed in the path's tangent frame: along-track ``e_a`` (along the unit tangent ``t``),
  cross-track ``e_c`` (along the horizontal normal ``n = (−t_y, t_x, 0)/|…|``, positive to
  starboard of the path in NED) and, in 3-D, vertical ``e_z`` (along ``t × n``: depth error,
  positive down, on a level path).  The heading is not referenced: an underactuated vehicle
  cannot hold an arbitrary heading; the cross-track error steers it.  ``terminal="cost"`` weighs
  ``ℓ`` at node N by ``weights.terminal``; ``"none"`` takes ``ℓ`` as it is;
* the current as a stagewise parameter, as in :class:`~uuv_ocp.tracking.TrackingProblem`.

The problem is time-invariant (``t0 = 0``): a closed loop's state is ``[x, s]`` (the path
parameter is the controller's own state, known exactly, and the plant of :func:`simulate
<uuv_ocp.control.simulation.simulate>` integrates it beside the vehicle; an
:class:`~uuv_ocp.Estimator` on the problem estimates the vehicle's states and the current, not
``s``: :attr:`PathFollowingProblem.controller_states`);
:meth:`PathFollowingProblem.initial_state` appends to a vehicle state the parameter of its
closest path point.  :func:`path_errors` measures a run's cross-track, vertical and
along-track errors by projection on the path.

A waypoint path (``Reference.waypoints``, the lawnmower) is looked up in the pieces a plan can
reach from ``s_0`` (:class:`PathWindow`, a parameter :meth:`PathFollowingProblem.parameters`
chooses from ``s_0``): a chain over 2 rows instead of every piece, the same point and tangent.

The path must move where it is followed (``|p'(s)| > 0``).  Where a path of a finite window
comes to rest (a waypoint reference's final braking and hold), the path parameter stops at
:attr:`PathFollowingProblem.path_end`, the last time its speed is at least
:data:`END_SPEED_FRACTION` of its peak: an exact L1 penalty (``weights.terminal_penalty``)
on ``s > path_end`` at nodes 1..N, so the vehicle comes to the end of the path and stays.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import casadi as ca
import numpy as np
from scipy.optimize import minimize_scalar

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import built_once
from uuv_ocp.control.guidance import cruise_propeller_speed
from uuv_ocp.control.scenario import Scenario, plant_dynamics, scenario
from uuv_ocp.integrators import rk4_path
from uuv_ocp.model.base import VehicleLayout, check_vehicle
from uuv_ocp.obstacles import Obstacle, check_obstacles
from uuv_ocp.ocp import Ocp, check_transcription
from uuv_ocp.reference.path import Reference
from uuv_ocp.reference.waypoints import window_look_up
from uuv_ocp.tracking import (
    DeclaredPreset,
    control_limits,
    current_rows,
    stable_substeps,
    vehicle_rhs,
    warn_if_rk4_unstable,
)

PATH_TERMINAL_MODES = ("cost", "none")
#: Floor (m/s) under the path speed ``|p'(s)|`` in ``ṡ = v_s / |p'(s)|``: finite where a path rests.
SPEED_FLOOR = 1e-6
#: Stretch (s of reference time) of an unbounded path sampled for the closest-point projection.
PROJECTION_SPAN = 3600.0
#: Most samples of the projection polyline (its step is at least ``PROJECTION_STEP``).
PROJECTION_SAMPLES = 40_000
PROJECTION_STEP = 0.02
#: The path ends where its speed falls below this fraction of its peak for good (``path_end``).
END_SPEED_FRACTION = 0.1
#: Look a piecewise path's pieces up in the window the horizon can reach (:class:`PathWindow`),
#: whose rows are a parameter set from ``s_0``, instead of in the whole table (``False``: the
#: former formulation, kept as the tests' reference).
PATH_WINDOW = True
#: :class:`PathWindow`'s reach: this factor on ``N dt max_path_speed`` plus ``WINDOW_MARGIN`` m.
WINDOW_REACH_FACTOR = 1.1
WINDOW_MARGIN = 1.0
#: Default lower bound of a propeller (a control named ``"n"``) as a fraction of the cruise
#: propeller speed at the commanded speed (:func:`default_control_lower`).
PROPELLER_FLOOR = 0.9
#: Default ``PathWeights.rate`` of a fin-steered vehicle with a propeller, and of any other.
FIN_RATE_WEIGHT = 500.0
RATE_WEIGHT = 1.0


@dataclass(frozen=True)
class PathWeights:
    """Cost weights of :class:`PathFollowingProblem` (every one finite and >= 0).

    Parameters
    ----------
    cross_track : float
        Weight on the squared cross-track error (1/m²).
    along_track : float
        Weight on the squared along-track error from ``p(s)`` (1/m²).
    vertical : float
        Weight on the squared vertical error of a spatial path (1/m²); unused in the plane.
    speed : float
        Weight on the squared deviation of the along-path speed from the commanded one (s²/m²).
    surge : float
        Weight on the squared deviation of the vehicle's surge (its first body velocity) from
        the along-path speed (s²/m²): the vehicle moves with ``p(s)``, nose first, instead of
        reversing its propeller or stalling to wait for it.
    attitude : float
        Weight on the squared roll and pitch (1/rad²), the angles other than the heading
        (regulated to zero); a planar vehicle has none.
    effort : float
        Weight on the squared scaled vehicle controls ``τ / τ_max`` (dimensionless).
    rate : float or None
        Weight on the squared scaled control increments ``Δu / u_max``, the along-path speed's
        included (dimensionless).  ``None`` (default): per vehicle, resolved by
        :class:`PathFollowingProblem` (:func:`default_rate_weight`): :data:`FIN_RATE_WEIGHT`
        (500) for a fin-steered vehicle with a propeller (a control named ``"n"``: on the REMUS 100
        survey of ``benchmarks/bench_path.py`` it calms the fins below ILOS's activity at a
        fraction of its cross-track error, docs/benchmarks.md), else :data:`RATE_WEIGHT` (1: a
        thruster craft such as the RexROV weaves about a line with 500, 0.10 m after 40 s).
    terminal : float
        Factor on the state terms at node N with ``terminal="cost"`` (dimensionless).
    terminal_penalty : float
        Exact L1 penalty weight of the derivative-free solvers' hard-constraint violations.
    rate_penalty : float
        Penalty weight on the scaled rate-bound excess (derivative-free solvers only).
    """

    cross_track: float = 10.0
    along_track: float = 0.1
    vertical: float = 10.0
    speed: float = 10.0
    surge: float = 10.0
    attitude: float = 10.0
    effort: float = 0.0
    rate: float | None = None
    terminal: float = 10.0
    terminal_penalty: float = 1e4
    rate_penalty: float = 1e4

    def __post_init__(self) -> None:
        """Check every weight (``ValueError`` names it) and store it as a float."""
        for name in (
            "cross_track",
            "along_track",
            "vertical",
            "speed",
            "attitude",
            "effort",
            "terminal",
        ):
            object.__setattr__(self, name, check.nonnegative_float(f"weights.{name}", getattr(self, name)))
        if self.rate is not None:
            object.__setattr__(self, "rate", check.nonnegative_float("weights.rate", self.rate))
        for name in ("terminal_penalty", "rate_penalty"):
            object.__setattr__(self, name, check.positive_float(f"weights.{name}", getattr(self, name)))
        if self.cross_track == 0.0:
            raise ValueError("weights.cross_track must be > 0: no cost would bring the vehicle to the path")


def path_geometry(reference: Reference) -> ca.Function:
    """``s -> (p(s), p'(s))``: the path point (m) and its derivative in the reference's time (m/s).

    From :attr:`Reference.function <uuv_ocp.reference.path.Reference.function>`: the body
    velocity ``(u_R, v_R)`` turned by ``ψ_R`` to the inertial frame, and ``w_R = ż_R`` of a
    spatial reference (its pitch is zero).
    """
    s = ca.SX.sym("s")
    position, velocity = _point_and_tangent(reference.function(s), reference.spatial)
    return ca.Function("path_geometry", [s], [position, velocity], ["s"], ["position", "tangent"])


def _point_and_tangent(state: ca.SX, spatial: bool) -> tuple[ca.SX, ca.SX]:
    """``(p, p')`` from a reference state (:func:`path_geometry`)."""
    if spatial:
        position, heading, surge, sway, heave = state[0:3], state[5], state[6], state[7], state[8]
    else:
        position, heading, surge, sway, heave = state[0:2], state[2], state[3], state[4], None
    cos_psi, sin_psi = ca.cos(heading), ca.sin(heading)
    horizontal = [surge * cos_psi - sway * sin_psi, surge * sin_psi + sway * cos_psi]
    velocity = ca.vertcat(*horizontal, *([heave] if heave is not None else []))
    return position, velocity


@dataclass(frozen=True, eq=False)
class PathWindow:
    """The pieces of a piecewise path (waypoints, lawnmower) the horizon can reach, as parameters.

    A waypoint path's point is a look-up of its piece's constants (a ``casadi.if_else`` chain
    over every piece, evaluated at each RK4 stage of each interval: 8 times a stage on the
    REMUS 100 survey).  The path parameter of a plan starting at ``s_0`` stays within
    ``σ(s_0) − BACK`` and ``σ(s_0) + REACH`` of look-up key ``σ`` (horizontal arc length, m):
    ``s`` never decreases and the along-path speed is at most ``max_path_speed``, so in
    ``N dt`` the path point moves at most ``N dt max_path_speed`` m along the path (REACH adds
    10 % and 1 m for the discretisation and the QP's linearised steps).  Only the rows of each
    table that meet that window enter the NLP, as the parameter ``"path_window"`` chosen from
    ``s_0`` by :meth:`PathFollowingProblem.parameters` (a chain over ``rows`` rows instead of
    the whole table): the same point, tangent and plan wherever the plan's ``σ`` stays in the
    window; outside it, the window's last (first) piece's formula is extended beyond its end
    (before its start), continuous in value and tangent with the neighbour's (C¹ joints).

    Attributes
    ----------
    time : casadi.SX
        The path parameter symbol (s).
    position, tangent : casadi.SX
        ``p`` and ``dp/dt`` in ``time`` and the placeholders (``Reference.piecewise_parts``).
    parts : list
        Per look-up: ``(constants, key, table)``.
    rows : tuple of int
        Rows of each table in the window (the most any window of the path meets).
    keys : casadi.Function
        ``s -> σ`` of every look-up (their keys at ``s``).
    """

    time: ca.SX
    position: ca.SX
    tangent: ca.SX
    parts: list
    rows: tuple[int, ...]
    keys: ca.Function

    #: the window behind ``σ(s_0)`` (m of the key): a plan's ``s_k`` just below ``s_0``
    BACK: ClassVar[float] = 1.0

    @classmethod
    def of(cls, reference: Reference, reach: float) -> PathWindow | None:
        """Return the window of ``reference`` for plans that move at most ``reach`` m, or ``None``.

        ``None`` when the reference has no tabled look-ups (``Reference.piecewise_parts``) or a
        window would hold every row of a table anyway (no gain).
        """
        pieces = reference.piecewise_parts
        if pieces is None:
            return None
        time, position, all_parts = pieces
        # x, y and the heading look the same table up: one window (placeholders substituted
        # by the same rows), so one chain
        parts: list = []
        for constants, key, table in all_parts:
            for others, _, other_table in parts:
                if other_table == table and others.numel() == constants.numel():
                    position = ca.substitute(position, constants, others)
                    break
            else:
                parts.append((constants, key, table))
        rows = []
        for _, _, table in parts:
            starts = np.array([row[0] for row in table])
            # the pieces [σ0 − BACK, σ0 + reach] meets: a step function of σ0, largest where the
            # window's end just meets a start j; counted per j with no (start − reach) + reach
            # round trip (one ulp short lost piece j) and a tolerance towards one row more
            low = starts - reach - cls.BACK
            low -= 1e-12 * np.maximum(1.0, np.abs(low))
            first = np.maximum(np.searchsorted(starts, low, side="right") - 1, 0)
            rows.append(int(np.max(np.arange(starts.size) - first + 1)))
        if all(count >= len(table) for count, (_, _, table) in zip(rows, parts, strict=True)):
            return None
        keys = ca.Function("path_window_keys", [time], [ca.vertcat(*[key for _, key, _ in parts])])
        # p' straight from p (the pieces held: exact between joints), not rotated back from
        # the reference's heading and body velocities as path_geometry (equal to rounding)
        return cls(time, position, ca.jacobian(position, time), parts, tuple(rows), keys)

    @property
    def size(self) -> int:
        """Length of the parameter ``"path_window"`` (every window row, row by row)."""
        return sum(count * len(table[0]) for count, (_, _, table) in zip(self.rows, self.parts, strict=True))

    def geometry(self, s: Any, window: Any) -> tuple[ca.SX, ca.SX]:
        """``(p(s), p'(s))`` (m, m/s) from the window rows ``window`` (the parameter, SX)."""
        constants, values, offset = [], [], 0
        for (placeholder, key, table), count in zip(self.parts, self.rows, strict=True):
            width = len(table[0])
            rows = ca.reshape(window[offset : offset + count * width], width, count).T
            constants.append(placeholder)
            values.append(window_look_up(key, rows))
            offset += count * width
        both = ca.substitute(
            ca.vertcat(self.position, self.tangent), ca.vertcat(*constants), ca.vertcat(*values)
        )
        both = ca.substitute(both, self.time, s)
        size = self.position.numel()
        return both[:size], both[size:]

    def rows_from(self, key: np.ndarray) -> np.ndarray:
        """Return the window rows (row by row) for the look-up keys ``key`` (m) at ``s_0``.

        From each table's piece holding ``key − BACK``, padded with its last row.
        """
        blocks = []
        for (_, _, table), count, value in zip(self.parts, self.rows, key, strict=True):
            array = np.asarray(table, dtype=float)
            first = max(int(np.searchsorted(array[:, 0], value - self.BACK, side="right")) - 1, 0)
            chosen = array[first : first + count]
            padding = np.repeat(chosen[-1:], count - len(chosen), axis=0)  # the last row selects itself
            blocks.append(np.vstack([chosen, padding]).ravel())
        return np.concatenate(blocks)

    @built_once
    def _steps(self) -> tuple[np.ndarray, np.ndarray]:
        """Where (in s) a window's first row changes, and the window rows between those steps.

        A key is non-decreasing in ``s``: the step of table row ``j`` is the ``s`` where its key
        reaches ``start_j + BACK`` (bisection to 1e-12 s on the key Function, once), so a step's
        look-up costs a ``searchsorted`` instead of a CasADi call (38 -> 2 µs).
        """
        steps: list[float] = []
        for index, (_, _, table) in enumerate(self.parts):
            for row in table[1:]:
                target = row[0] + self.BACK
                low, high = -1.0, 1.0
                while float(self.keys(low)[index]) >= target and low > -1e12:
                    low *= 2.0
                while float(self.keys(high)[index]) < target and high < 1e12:
                    high *= 2.0
                if float(self.keys(high)[index]) < target:
                    continue  # never reached
                for _ in range(200):
                    middle = 0.5 * (low + high)
                    if float(self.keys(middle)[index]) >= target:
                        high = middle
                    else:
                        low = middle
                    if high - low <= 1e-12 * max(1.0, abs(high)):
                        break
                steps.append(high)
        edges = np.unique(np.array(steps))
        points = np.r_[edges[:1] - 1.0, edges] if edges.size else np.zeros(1)
        windows = np.array([self.rows_from(np.array(self.keys(point)).ravel()) for point in points])
        return edges, windows

    def values(self, s0: float) -> np.ndarray:
        """Return the window rows for a plan starting at path parameter ``s0`` (s), row by row."""
        edges, windows = self._steps
        return windows[int(np.searchsorted(edges, s0, side="right"))]


def tangent_frame_errors(offset: Any, tangent: Any) -> list[Any]:
    """``[e_a, e_c]`` (planar) or ``[e_a, e_c, e_z]`` (spatial) of ``offset = position − p(s)`` (m).

    ``tangent`` is ``p'(s)``; works on CasADi symbols and on numpy vectors alike.
    """
    size = offset.shape[0]  # CasADi and numpy alike
    speed = (sum(tangent[i] ** 2 for i in range(size)) + SPEED_FLOOR**2) ** 0.5
    t = [tangent[i] / speed for i in range(size)]
    level = (t[0] ** 2 + t[1] ** 2 + SPEED_FLOOR**2) ** 0.5
    n = [-t[1] / level, t[0] / level]
    along = sum(t[i] * offset[i] for i in range(len(t)))
    cross = n[0] * offset[0] + n[1] * offset[1]
    if len(t) == 2:
        return [along, cross]
    # b = t × n with n = (n0, n1, 0): (−t2 n1, t2 n0, t0 n1 − t1 n0)
    vertical = -t[2] * n[1] * offset[0] + t[2] * n[0] * offset[1] + (t[0] * n[1] - t[1] * n[0]) * offset[2]
    return [along, cross, vertical]


@dataclass(frozen=True)
class PathFollowingProblem(DeclaredPreset):
    """NMPC path following of a vehicle: converge to ``path`` and move along it at ``speed``.

    Parameters
    ----------
    vehicle : VehicleModel
        The controller's model (any :class:`~uuv_ocp.model.base.VehicleModel`).
    path : Reference
        The geometric path, of the kind ``vehicle.layout.reference`` names (planar or
        spatial); its timing only parameterises it (module doc).
    speed : float
        Commanded along-path speed U (m/s), > 0, at most ``max_path_speed``.
    horizon : int
        Number of shooting intervals N, 1 <= N <= 10 000.
    dt : float
        Sampling time (s), > 0.
    weights : PathWeights, optional
        Cost weights (default ``PathWeights()``); a ``rate`` of ``None`` becomes the vehicle's
        default (:func:`default_rate_weight`), so ``problem.weights.rate`` is always a float.
    terminal : {"cost", "none"}
        The state terms at node N weighted by ``weights.terminal``, or as at other nodes.
    substeps : int or None
        RK4 steps per interval of the prediction model, >= 1.  ``None`` (default): the fewest
        that keep RK4 stable on the vehicle's decaying modes at rest
        (:func:`~uuv_ocp.tracking.stable_substeps`; the REMUS 100 at ``dt = 0.5`` s: 2, the
        RexROV: 1).  A value that does not warns (:class:`~uuv_ocp.tracking.Rk4StabilityWarning`).
        (The straight-line stall of the REMUS with 2 substeps, the plan reversing the propeller
        until the vehicle stopped near the line, is gone with the propeller floor of
        ``control_lower``.)
    transcription : {"multiple_shooting", "collocation"}
        As :class:`~uuv_ocp.tracking.TrackingProblem`.
    degree : int, optional
        Collocation points per interval, with ``transcription="collocation"``.
    rate_limits : bool
        Enforce the vehicle's control rate bounds and ``path_acceleration``.
    max_path_speed : float, optional
        Upper bound of the along-path speed ``v_s`` (m/s); default ``2 speed``.
    path_acceleration : float
        Rate bound of ``v_s`` (m/s²), > 0.
    obstacles : tuple of Obstacle
        Static keep-out zones: hard constraints on the horizontal position of nodes 1..N (an
        exact penalty for the swarms).  Moving obstacles need a time the problem has not.
    control_lower : sequence of float, optional
        Lower bounds of the vehicle's controls (their units), each within ``[−u_max, u_max]``;
        the upper bounds stay ``u_max``.  Default :func:`default_control_lower`: ``−u_max``, but
        a propeller (a control named ``"n"``) floored at :data:`PROPELLER_FLOOR` × the cruise
        propeller speed at ``speed`` (:func:`~uuv_ocp.control.guidance.cruise_propeller_speed`;
        the REMUS 100 at 1.5 m/s: 0.9 × 896.2 = 806.6 rpm).  Why: without it the plan of a
        fin-steered vehicle may brake with the propeller in a turn or near a line, and a torpedo
        whose propeller stops loses its fins' authority and sinks (measured: 3 of 10 survey
        seeds stalled with ``PathWeights(rate=100)``).  ``-numpy.array(vehicle.control_bound)``
        allows reverse thrust again.
    """

    vehicle: Any
    path: Reference
    speed: float
    horizon: int = 20
    dt: float = 0.5
    weights: PathWeights | None = None
    terminal: str = "cost"
    substeps: int | None = None  # type: ignore[assignment]  # an int after __post_init__
    transcription: str = "multiple_shooting"
    degree: int | None = None
    rate_limits: bool = True
    max_path_speed: float | None = None
    path_acceleration: float = 1.0
    obstacles: tuple[Obstacle, ...] = ()
    control_lower: tuple[float, ...] | None = None  # a tuple after __post_init__
    #: trailing states the controller owns (the path parameter): an
    #: :class:`~uuv_ocp.Estimator` estimates the vehicle's states only
    controller_states: ClassVar[int] = 1

    def __post_init__(self) -> None:
        """Check the fields against each other and the vehicle (``ValueError`` names the field)."""
        set_field = object.__setattr__
        # the fields filled in below from the others: replace() leaves them None again
        defaulted = {"control_lower": self.control_lower, "substeps": self.substeps}
        defaulted["weights.rate"] = getattr(self.weights, "rate", None)
        set_field(self, "_defaulted", tuple(name for name, value in defaulted.items() if value is None))
        layout = check_vehicle("vehicle", self.vehicle).layout
        if not isinstance(self.path, Reference):
            raise ValueError(f"path must be a uuv_ocp.Reference, got {type(self.path).__name__}")
        if self.path.spatial != (layout.reference == "spatial"):
            kind = "spatial (Reference.from_xyz, 3-D waypoints, a lawnmower with depth)"
            if layout.reference == "planar":
                kind = "planar (Reference.from_xy, 2-D waypoints, a lawnmower without depth)"
            got = "spatial" if self.path.spatial else "planar"
            raise ValueError(f"path must be {kind} for this vehicle, got a {got} reference")
        set_field(self, "speed", check.positive_float("speed", self.speed))
        set_field(self, "horizon", check.positive_int("horizon", self.horizon))
        if self.horizon > 10_000:
            raise ValueError(f"horizon must be an integer <= 10000, got {self.horizon!r}")
        set_field(self, "dt", check.positive_float("dt", self.dt))
        if self.weights is None:
            set_field(self, "weights", PathWeights())
        if not isinstance(self.weights, PathWeights):
            raise ValueError(f"weights must be a uuv_ocp.PathWeights, got {check.shown(self.weights)}")
        if self.weights.rate is None:
            set_field(self, "weights", replace(self.weights, rate=default_rate_weight(self.vehicle)))
        check.choice("terminal", self.terminal, PATH_TERMINAL_MODES)
        if self.substeps is None:  # RK4 stable on the vehicle's modes at rest (the REMUS: 2 at 0.5 s)
            auto = self.transcription == "multiple_shooting"
            set_field(self, "substeps", stable_substeps(self.vehicle, self.dt) if auto else 1)
        substeps = check.positive_int("substeps", self.substeps)
        set_field(self, "substeps", substeps)
        check_transcription(self.transcription, self.degree, substeps)
        if self.transcription == "multiple_shooting":
            warn_if_rk4_unstable(self.vehicle, self.dt, substeps)
        check.boolean("rate_limits", self.rate_limits)
        top = 2.0 * self.speed if self.max_path_speed is None else self.max_path_speed
        top = check.positive_float("max_path_speed", top)
        if top < self.speed:
            raise ValueError(f"max_path_speed must be >= speed = {self.speed} m/s, got {top} m/s")
        set_field(self, "max_path_speed", top)
        set_field(
            self, "path_acceleration", check.positive_float("path_acceleration", self.path_acceleration)
        )
        obstacles = check_obstacles(self.obstacles)
        moving = [obstacle.name for obstacle in obstacles if obstacle.is_moving]
        if moving:
            raise ValueError(
                f"obstacles must be static for path following (the problem has no time), got moving {moving}"
            )
        set_field(self, "obstacles", obstacles)
        set_field(self, "control_lower", self._checked_control_lower())

    def _checked_control_lower(self) -> tuple[float, ...]:
        """``control_lower`` as a tuple of floats, the default's if None (``ValueError`` names it)."""
        if self.control_lower is None:
            return default_control_lower(self.vehicle, self.speed)
        bound, _ = control_limits(self.vehicle)
        lower = check.finite_array("control_lower", self.control_lower, bound.shape)
        outside = np.flatnonzero((lower < -bound) | (lower > bound))
        if outside.size:
            raise ValueError(
                f"control_lower must lie within the vehicle's bounds ±{bound.tolist()}, got {lower.tolist()}"
            )
        return tuple(float(value) for value in lower)

    # ------------------------------------------------------------- the Ocp
    # built_once, not functools.cached_property: its per-attribute lock, taken before BUILD_LOCK,
    # deadlocked against an .ocp being built (BUILD_LOCK held) that reads another problem's window
    @built_once
    def geometry(self) -> ca.Function:
        """``s -> (p(s), p'(s))`` of the path (:func:`path_geometry`; built under BUILD_LOCK)."""
        return path_geometry(self.path)

    @built_once
    def window(self) -> PathWindow | None:
        """The pieces the horizon can reach as a parameter (:class:`PathWindow`), or ``None``.

        ``None`` for a path without tabled pieces (``from_xyz``) or with :data:`PATH_WINDOW`
        off; the reach is ``WINDOW_REACH_FACTOR · N dt max_path_speed + WINDOW_MARGIN`` m.
        """
        if not PATH_WINDOW:
            return None
        assert self.max_path_speed is not None
        reach = WINDOW_REACH_FACTOR * self.horizon * self.dt * self.max_path_speed + WINDOW_MARGIN
        return PathWindow.of(self.path, reach)  # under BUILD_LOCK (built_once)

    def _declare(self) -> Ocp:
        vehicle, weights = self.vehicle, self.weights
        assert weights is not None and self.max_path_speed is not None
        layout: VehicleLayout = vehicle.layout
        nx, nu, nc = layout.state_dim, layout.control_dim, layout.current_dim
        ocp = self._empty_ocp(f"path_following_{self.path.name}")
        state = ocp.state("x", nx)
        s = ocp.state("s")
        max_control, max_rate = control_limits(vehicle)
        tau = ocp.control(
            "tau",
            nu,
            lower=np.asarray(self.control_lower, dtype=float),
            upper=max_control,
            max_rate=max_rate if self.rate_limits else None,
        )
        top = self.max_path_speed
        v_s = ocp.control(
            "v_s", lower=0.0, upper=top, max_rate=self.path_acceleration if self.rate_limits else None
        )
        current = ocp.parameter("current", nc, stagewise=True)
        ocp.set_der(state, vehicle_rhs(vehicle, state, tau, current))
        window = self.window
        if window is None:
            position, tangent = self.geometry(s)
        else:  # the reachable pieces, chosen from s_0 (parameters): a short look-up chain
            rows = ocp.parameter("path_window", window.size)
            position, tangent = window.geometry(s, rows)
        ocp.set_der(s, path_rate(v_s, tangent))
        ocp.add_stage_cost(
            residual=ca.vertcat(
                (tau - ocp.previous(tau)) / ca.DM(max_control),
                (v_s - ocp.previous(v_s)) / top,
                tau / ca.DM(max_control),
                v_s - self.speed,
                state[layout.velocities[0]] - v_s,
            ),
            weight=(*(weights.rate,) * (nu + 1), *(weights.effort,) * nu, weights.speed, weights.surge),
        )
        errors = tangent_frame_errors(state[list(layout.positions)] - position, tangent)
        attitude = [state[i] for i in layout.angles if i != layout.heading]
        residual = ca.vertcat(*errors, *attitude)
        stage = (weights.along_track, weights.cross_track, *([weights.vertical] if len(errors) == 3 else []))
        stage += (weights.attitude,) * len(attitude)
        if self.horizon > 1:  # nodes 1..N-1 (x_0 is given)
            ocp.add_stage_cost(residual=residual, weight=stage, start=1)
        factor = weights.terminal if self.terminal == "cost" else 1.0
        ocp.add_terminal_cost(residual=residual, weight=[factor * w for w in stage])
        if math.isfinite(self.path_end):  # soft: the plant may overshoot it by an ulp
            # on every node, though s never decreases along a plan and node N's bound would
            # do: soft on node N alone (written on F(x_(N-1), u_(N-1))) let plans run s far
            # past the end, and a hard row makes every RTI plan judged (+0.27 ms a step)
            ocp.bounded(-math.inf, s, self.path_end, soft=weights.terminal_penalty)
        horizontal = list(layout.positions[:2])
        for obstacle in self.obstacles:
            ocp.subject_to(obstacle.clearance(state[horizontal]) >= 0)
        return ocp

    # ------------------------------------------------------------- instances
    def instance_parameters(
        self,
        x0: object,
        t0: float = 0.0,
        *,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: Mapping[str, object] | None = None,
    ) -> np.ndarray:
        """Parameter vector of one instance, in the signature every problem shares.

        Path following is time-invariant: ``t0`` must be 0 (the path parameter in ``x0`` says
        where on the path the vehicle is); ``parameters`` is refused (an Ocp's argument).
        """
        if parameters is not None:
            raise ValueError("parameters= is for an Ocp; a PathFollowingProblem takes x0, u_prev and current")
        if check.finite_float("t0", t0) != 0.0:
            raise ValueError(
                f"t0 must be 0 for a PathFollowingProblem (time-invariant: the path parameter, the last "
                f"entry of x0, places the vehicle on the path), got {t0}"
            )
        return self.parameters(x0, u_prev, current)

    def parameters(
        self, x0: object, u_prev: object | None = None, current: object | None = None
    ) -> np.ndarray:
        """Parameter vector ``p = [x0, u_prev, current, path window]`` of one instance.

        Parameters
        ----------
        x0 : array_like, shape (nx + 1,)
            Vehicle state and path parameter ``s`` (s of the reference's time).
        u_prev : array_like, shape (nu + 1,), optional
            Last applied control and along-path speed (m/s); zero clipped into the box by
            default (the propeller floor).
        current : array_like, shape (nc,), (N, nc) or (N+1, nc), optional
            Inertial current velocity (m/s) the model assumes on each interval.
        """
        x0 = check.plausible_array("x0", x0, (self.state_dim,))
        nc = self.vehicle.layout.current_dim
        rows = current_rows(current, self.horizon, nc)
        values = {
            "current": np.zeros((self.horizon + 1, nc))
            if rows is None
            else np.broadcast_to(rows, (self.horizon + 1, nc))
        }
        if self.window is not None:
            values["path_window"] = self.window.values(float(x0[-1]))
        return self.ocp.pack(x0, self.ocp.check_previous(u_prev), values)

    def with_state(self, p: np.ndarray, x0: object) -> np.ndarray:
        """Return a copy of the instance ``p`` with its state set to ``x0`` (checked as there).

        Equal to :meth:`parameters` with ``x0`` and the last control and current of ``p``: the
        path window (:class:`PathWindow`) is chosen again from the new ``s_0``.
        """
        new = super().with_state(p, x0)
        if self.window is not None:
            rows: slice = self.spec().layout.entries["path_window"][0]
            new[rows] = self.window.values(float(new[self.spec().layout.x0][-1]))
        return new

    def initial_guess(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cold start: the last control held, ``v_s`` at the commanded speed, and their rollout.

        A consistent guess (the states the controls give): a held state on a moving path
        started IPOPT far from any plan the vehicle can fly (hundreds of iterations).
        """
        spec = self.spec()
        controls = np.tile(self.previous_scaled(p), (self.horizon, 1))
        controls[:, -1] = spec.scaled(np.r_[np.zeros(spec.control_size - 1), self.speed])[-1]
        states = self.rollout_scaled(controls.ravel(), p)
        if not np.all(np.isfinite(states)):  # a rollout that blew up guides nothing
            states = np.tile(np.asarray(p[spec.layout.x0], dtype=float), (self.horizon + 1, 1))
        return states, controls

    def initial_state(self, vehicle_state: object) -> np.ndarray:
        """Return ``[vehicle_state, s]`` with ``s`` the parameter of the path point closest to it."""
        layout = self.vehicle.layout
        state = check.plausible_array("vehicle_state", vehicle_state, (layout.state_dim,))
        return np.r_[state, self.closest_parameter(state[list(layout.positions)])]

    # ------------------------------------------------------------- projection
    @built_once
    def polyline(self) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``(times (m,), positions (m, d))`` of the path for the closest-point projection.

        Over ``[t_start, t_end]`` (``t_start + PROJECTION_SPAN`` for an unbounded window), at most
        ``PROJECTION_SAMPLES``
        samples and at least ``PROJECTION_STEP`` s apart: the chord of an arc of radius r is
        within ``(U step)² / (8 r)`` of it (µm for the presets).
        """
        start = self.path.t_start
        end = self.path.t_end if math.isfinite(self.path.t_end) else start + PROJECTION_SPAN
        count = int(min(PROJECTION_SAMPLES, math.ceil((end - start) / PROJECTION_STEP))) + 1
        times = np.linspace(start, end, count)
        columns = [0, 1, 2] if self.path.spatial else [0, 1]
        return times, self.path.evaluate(times)[:, columns]

    @built_once
    def path_end(self) -> float:
        """Last path parameter (s) the path parameter may reach: ``inf`` for an unbounded window.

        For a finite window, the last sample of :attr:`polyline` whose path speed is at least
        :data:`END_SPEED_FRACTION` of the peak (a waypoint reference's braking to rest, its
        hold excluded), or ``t_end``.
        """
        if not math.isfinite(self.path.t_end):
            return math.inf
        times, _ = self.polyline
        tangents = np.array(self.geometry.map(times.size)(times[None, :])[1]).T
        speed = np.linalg.norm(tangents, axis=1)
        moving = np.flatnonzero(speed >= END_SPEED_FRACTION * speed.max())
        return float(times[moving[-1]])

    def closest_parameter(self, position: object) -> float:
        """Return the path parameter ``s`` (s) of the path point closest to ``position`` (m).

        The closest point of the sampled polyline (:attr:`polyline`; every segment's, then the
        closest of those, the first on a tie), refined on the exact path by a bounded scalar
        minimisation (to 1e-10 s) over the neighbouring samples' interval.
        """
        times, points = self.polyline
        position = check.finite_array("position", position, (points.shape[1],))
        start, chord = points[:-1], np.diff(points, axis=0)
        length = np.einsum("ij,ij->i", chord, chord)
        fraction = np.einsum("ij,ij->i", position - start, chord) / np.where(length > 0.0, length, 1.0)
        fraction = np.clip(fraction, 0.0, 1.0)
        distance = np.sum((start + fraction[:, None] * chord - position) ** 2, axis=1)
        best = int(np.argmin(distance))
        # the chord's point is within the sampling's sagitta of the path: the exact distance is
        # minimised next to it, on the two neighbouring samples' interval (bounded Brent)
        low, high = times[max(best - 1, 0)], times[min(best + 2, times.size - 1)]

        def squared_distance(s: float) -> float:
            point = np.array(self.geometry(s)[0]).ravel()
            return float(np.sum((point - position) ** 2))

        found = minimize_scalar(
            squared_distance, bounds=(low, high), method="bounded", options={"xatol": 1e-10}
        )
        return float(found.x)


def default_rate_weight(vehicle: Any) -> float:
    """Return the default ``PathWeights.rate`` of ``vehicle`` (dimensionless).

    :data:`FIN_RATE_WEIGHT` for a vehicle with a propeller control ``"n"`` (a fin-steered
    torpedo), else :data:`RATE_WEIGHT`.
    """
    return FIN_RATE_WEIGHT if "n" in tuple(vehicle.layout.control_names) else RATE_WEIGHT


def default_control_lower(vehicle: Any, speed: float) -> tuple[float, ...]:
    """Default lower control bounds of :class:`PathFollowingProblem` (the controls' units).

    ``−u_max`` for every control but a propeller (a control named ``"n"``), which is floored at
    :data:`PROPELLER_FLOOR` × its cruise speed at ``speed`` m/s
    (:func:`~uuv_ocp.control.guidance.cruise_propeller_speed`): the plan keeps the vehicle
    moving, so its fins keep their authority (no braking stall in turns or near a line).
    """
    bound, _ = control_limits(vehicle)
    lower = -bound
    names = tuple(vehicle.layout.control_names)
    if "n" in names:
        lower[names.index("n")] = PROPELLER_FLOOR * cruise_propeller_speed(vehicle, speed)
    return tuple(float(value) for value in lower)


def path_rate(v_s: Any, tangent: Any) -> Any:
    """``ṡ = v_s / |p'(s)|``: the reference-time rate that moves ``p(s)`` at ``v_s`` m/s along the path."""
    return v_s / ca.sqrt(ca.sumsqr(tangent) + SPEED_FLOOR**2)


def path_errors(problem: PathFollowingProblem, states: Any) -> dict[str, np.ndarray]:
    """Cross-track, vertical and along-track errors of a run, by projection on the path.

    Parameters
    ----------
    problem : PathFollowingProblem
        The problem whose path the run followed.
    states : ClosedLoopResult or array_like, shape (n, nx) or (n, nx + 1)
        The run (its ``states``), or states of the vehicle, with or without the path parameter.

    Returns
    -------
    dict of numpy.ndarray, shape (n,)
        ``"cross_track"`` (m, signed: positive to starboard of the path, NED) and, for a spatial
        path, ``"vertical"`` (m, positive below it) of each position from its closest path point
        (:meth:`PathFollowingProblem.closest_parameter`); ``"closest"``, that point's parameter
        (s); with the path parameter in the states, ``"along_track"`` (m): the position's offset
        from ``p(s)`` along the path's tangent at ``s``.
    """
    layout = problem.vehicle.layout
    rows = np.atleast_2d(np.asarray(getattr(states, "states", states), dtype=float))
    if rows.shape[1] not in (layout.state_dim, layout.state_dim + 1):
        raise ValueError(
            f"states must have {layout.state_dim} or {layout.state_dim + 1} columns (the vehicle's "
            f"state, with or without the path parameter), got {rows.shape[1]}"
        )
    positions = rows[:, list(layout.positions)]
    closest = np.array([problem.closest_parameter(position) for position in positions])
    names = ["along", "cross_track", "vertical"][: positions.shape[1]]
    result: dict[str, list[float]] = {name: [] for name in names}
    along: list[float] = []
    for k, position in enumerate(positions):
        point, tangent = (np.array(value).ravel() for value in problem.geometry(closest[k]))
        for name, value in zip(names, tangent_frame_errors(position - point, tangent), strict=True):
            result[name].append(float(value))
        if rows.shape[1] == layout.state_dim + 1:
            point, tangent = (np.array(value).ravel() for value in problem.geometry(rows[k, -1]))
            along.append(float(tangent_frame_errors(position - point, tangent)[0]))
    errors = {name: np.array(values) for name, values in result.items() if name != "along"}
    errors["closest"] = closest
    if along:
        errors["along_track"] = np.array(along)
    return errors


@scenario.register
def _path_following(
    problem: PathFollowingProblem,
    *,
    t0: float | None,
    duration: float,
    plant: Any,
    parameters: Mapping[str, Any] | None,
    current: Any,
    substeps: int,
) -> Scenario:
    if parameters is not None:
        raise ValueError(
            f"parameters is for an Ocp; a PathFollowingProblem takes current=, got {check.shown(parameters)}"
        )
    if t0 is not None and check.finite_float("t0", t0) != 0.0:
        raise ValueError(f"t0 must be 0 or None for a PathFollowingProblem (time-invariant), got {t0}")
    layout = problem.vehicle.layout
    nx = problem.state_dim
    return Scenario(
        t0=0.0,
        steps=max(1, int(np.floor(duration / problem.dt + 1e-9))),
        plant_step=path_plant(problem, plant, substeps),
        current_dim=layout.current_dim,
        time_varying=False,
        name=problem.path.name,
        state_names=(*layout.state_names, "s"),
        state_units=(*layout.state_units, "s"),
        state_roles=(*layout.state_roles, ""),
        reference=lambda times: np.full((len(times), nx), np.nan),
    )


def path_plant(problem: PathFollowingProblem, plant: Any, substeps: int) -> ca.Function:
    """RK4 plant path ``([x, s], [τ, v_s], current) -> (nx + 1, substeps)``: the vehicle and ``s``."""
    dynamics = plant_dynamics(problem.vehicle, plant)
    layout = problem.vehicle.layout
    x = ca.MX.sym("x", layout.state_dim + 1)
    u = ca.MX.sym("u", layout.control_dim + 1)
    c = ca.MX.sym("current", layout.current_dim)
    _, tangent = problem.geometry(x[-1])
    rate = ca.vertcat(dynamics(x[:-1], u[:-1], c), path_rate(u[-1], tangent))
    augmented = ca.Function("path_plant", [x, u, c], [rate], ["x", "u", "current"], ["xdot"])
    return rk4_path(augmented, problem.dt, substeps, name="plant_step")


def path_metrics(run: Any, problem: Any) -> dict[str, float]:
    """Cross-track, depth, fin and energy figures of a closed-loop run along a path.

    Parameters
    ----------
    run : ClosedLoopResult
        The run (its ``t``, ``states`` and ``controls``); the states may carry the path
        parameter and the controls the along-path speed (extra columns are ignored).
    problem : PathFollowingProblem or TrackingProblem
        Gives the vehicle and the path (its ``path`` or its ``reference``), whichever
        controller flew it (NMPC path following, line-of-sight guidance, tracking).

    Returns
    -------
    dict of float
        ``"cross_track_rms"``, ``"cross_track_max"`` (m): the horizontal distance from each
        position to the path (the reference's curve sampled as :attr:`PathFollowingProblem.polyline`,
        the closest point of its segments), over the run until the closest point is the path's
        end (the vehicle has passed it); ``"depth_rms"`` (m): the vertical offset from that
        closest point's depth over the whole run (NaN for a planar path); ``"fin_activity"``
        (rad): ``Σ_k Σ_j |u_j,k+1 − u_j,k|`` over the controls in rad (rudder and planes);
        ``"energy"`` (J): ``Σ_k P_k Δt_k`` with ``P_k = vehicle.propeller_power(u_k, x_k)`` (W,
        the command held over its interval at the interval's first state), NaN for a vehicle
        without that method; ``"completed"``: 1.0 if the vehicle passed the path's end, else 0.0.
    """
    vehicle = problem.vehicle
    path = getattr(problem, "path", None) or problem.reference
    layout = vehicle.layout
    times = np.asarray(run.t, dtype=float)
    states = np.atleast_2d(np.asarray(run.states, dtype=float))[:, : layout.state_dim]
    controls = np.atleast_2d(np.asarray(run.controls, dtype=float))[:, : layout.control_dim]
    points = _path_polyline(path)
    horizontal, depth_of_path = points[:, :2], points[:, 2] if path.spatial else None
    distance, segment, fraction = _closest_on_polyline(horizontal, states[:, list(layout.positions[:2])])
    at_end = (segment == len(points) - 2) & (fraction >= 1.0)
    passed = np.flatnonzero(at_end)
    on_path = np.ones(len(distance), dtype=bool)
    if passed.size:
        on_path[passed[0] :] = False
    cross = distance[on_path] if on_path.any() else distance[:1]
    if depth_of_path is not None:
        depth = depth_of_path[segment] + fraction * (depth_of_path[segment + 1] - depth_of_path[segment])
        depth_rms = float(np.sqrt(np.mean((states[:, layout.positions[2]] - depth) ** 2)))
    else:
        depth_rms = math.nan
    fins = [j for j, unit in enumerate(layout.control_units) if unit == "rad"]
    activity = float(np.abs(np.diff(controls[:, fins], axis=0)).sum()) if fins else 0.0
    power = getattr(vehicle, "propeller_power", None)
    if power is None or len(controls) == 0:
        energy = math.nan
    else:
        count = len(controls)
        energy = float(np.sum(power(controls, states[:count]) * np.diff(times)[:count]))
    return {
        "cross_track_rms": float(np.sqrt(np.mean(cross**2))),
        "cross_track_max": float(np.max(cross)),
        "depth_rms": depth_rms,
        "fin_activity": activity,
        "energy": energy,
        "completed": float(passed.size > 0),
    }


def _path_polyline(path: Reference) -> np.ndarray:
    """Return the path's positions sampled as :attr:`PathFollowingProblem.polyline`, repeats dropped (m)."""
    start = path.t_start
    end = path.t_end if math.isfinite(path.t_end) else start + PROJECTION_SPAN
    count = int(min(PROJECTION_SAMPLES, math.ceil((end - start) / PROJECTION_STEP))) + 1
    points = path.evaluate(np.linspace(start, end, count))[:, [0, 1, 2] if path.spatial else [0, 1]]
    moved = np.ones(len(points), dtype=bool)
    moved[1:] = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1) > 1e-9  # a hold repeats its point
    return points[moved]


def _closest_on_polyline(vertices: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, ...]:
    """Distance (m) to the closest point of the segments, its segment and fraction along it.

    The nearest vertex (a k-d tree) then its two segments: the closest point of a polyline
    whose vertices are much closer together than the distance to its other parts.
    """
    from scipy.spatial import cKDTree

    last = len(vertices) - 2
    _, nearest = cKDTree(vertices).query(positions)
    best = np.full(len(positions), np.inf)
    segment = np.zeros(len(positions), dtype=int)
    fraction = np.zeros(len(positions))
    for candidate in (np.clip(nearest - 1, 0, last), np.clip(nearest, 0, last)):
        start, chord = vertices[candidate], vertices[candidate + 1] - vertices[candidate]
        length = np.einsum("ij,ij->i", chord, chord)
        along = np.clip(np.einsum("ij,ij->i", positions - start, chord) / length, 0.0, 1.0)
        gap = np.linalg.norm(start + along[:, None] * chord - positions, axis=1)
        better = gap < best
        best[better], segment[better], fraction[better] = gap[better], candidate[better], along[better]
    return best, segment, fraction
