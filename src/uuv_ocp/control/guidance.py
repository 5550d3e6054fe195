r"""Line-of-sight guidance with depth and heading autopilots: the marine baseline in the NMPC's loop.

:class:`LosGuidance` steers a fin-controlled torpedo (controls ``[δ_r, δ_s, n]``: rudder and
stern-plane angles in rad, propeller speed in rpm, as :class:`~uuv_ocp.model.remus100.Remus100`)
along the geometric path of its problem's reference, and is a controller that
:func:`~uuv_ocp.control.simulation.simulate` runs exactly as it runs an :class:`~uuv_ocp.NMPC`
(the :class:`~uuv_ocp.control.simulation.Controller` protocol).  Only the reference's path is
used, never its timing: the vehicle goes at the commanded speed through the water.

Guidance (horizontal plane)
---------------------------
Integral line-of-sight (ILOS) of Børhaug, Pavlov & Pettersen (2008) as in T. I. Fossen,
*Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed., Wiley, 2021, §12.4, and
his MSS toolbox's ``GNC/ILOSpsi.m`` (the form, the sign convention and the switching rule are
that file's).  On the active straight segment from ``p_k`` to ``p_{k+1}`` with the
path-tangential angle ``π_h = atan2(y_{k+1} − y_k, x_{k+1} − x_k)``::

    x_e =  (x − x_k) cos π_h + (y − y_k) sin π_h        (along-track error, m)
    y_e = −(x − x_k) sin π_h + (y − y_k) cos π_h        (cross-track error, m; > 0: right of the path)
    ψ_ref = π_h − atan(K_p (y_e + κ y_int)),  K_p = 1/Δ
    ẏ_int = Δ y_e / (Δ² + (y_e + κ y_int)²)            (forward Euler over the sample time)

with the look-ahead distance ``Δ`` (m) and the integral gain ``κ >= 0`` (``κ = 0``: plain LOS,
whose crab angle against a cross current needs a steady cross-track offset
``y_e = Δ tan(crab)``; the integral state supplies that angle instead).  A vehicle right of
the path (``y_e > 0``) is told to turn left, and vice versa.  The next segment becomes active
when the along-track distance left, ``d − x_e``, is below the radius of acceptance ``R``
(``ILOSpsi``'s switching criterion; ``R`` capped at half of the segment's length), and this
step's command is still the old segment's (``ILOSpsi``'s order); after the last waypoint the
last bearing is held.  ``y_int`` is kept across switches (as ``ILOSpsi``).

The path is the reference's horizontal (and depth) curve as a polyline: the reference sampled
along its window and simplified (Ramer–Douglas–Peucker) to within ``path_tolerance`` m, so the
straight legs of :meth:`Reference.waypoints <uuv_ocp.reference.path.Reference.waypoints>` and
:meth:`~uuv_ocp.reference.path.Reference.lawnmower` are single segments and their turning arcs
chords (:func:`path_points` is the one place that reads the path).  On a chord of a curve (both
of its ends' path tangents within :data:`SMOOTH_ANGLE` of the chord) ``π_h`` is the path's
tangent, turned linearly along the chord from the tangent at its start to the one at its end:
the path-tangential angle of Fossen's LOS for curved paths (2021, §12.4).  A *smooth* waypoint
(the path tangent there within :data:`SMOOTH_ANGLE` of both segments) is switched as the
vehicle passes it (``R = 0``), so ``π_h`` stays continuous along a curve; the radius of
acceptance serves the corners.  With the chords' own directions, every switch on an arc steps
``ψ_ref`` by the chord angle, and the heading autopilot's acceleration feedforward turns each
step into a rudder spike (a sawtooth that doubled the fin activity of the lawnmower
benchmark).  On a straight leg the tangents are the leg's direction, and the law is the
straight-line ILOS above.

Autopilots
----------
Both after Fossen's Python Vehicle Simulator ``remus100.py``, ``depthHeadingAutopilot``
(GitHub ``cybergalactic/PythonVehicleSimulator``, commit ``7e1db8ed``) and its
``control.integralSMC`` / ``guidance.refModel3``; the gains default to that file's, except
where the options say otherwise.

* **Depth** (successive loop closure): the desired depth is the path's depth at the projection
  on the active segment, low-pass filtered, ``z_d ← e^{−ω_z h} z_d + (1 − e^{−ω_z h}) z_path``;
  outer PI loop depth → pitch ``θ_d = K_pz ((z − z_d) + z_int / T_z)`` (clipped to
  ``±max_pitch``, an addition of this module); inner PID loop pitch → stern plane
  ``δ_s = K_pθ ssa(θ − θ_d) + K_dθ q + K_iθ θ_int + K_w w`` (the source's sign, after its
  final ``−δ_s``: a positive stern plane pitches the nose down).
* **Heading**: the integral sliding-mode controller of Fossen 2021 eq. 16.479 on the Nomoto
  model ``T ṙ + r = K δ_r`` (``integralSMC``), with a third-order reference model
  ``ψ_d⃛ = ω³ (ψ_ref − ψ_d) − (2ζ + 1) ω² ψ̇_d − (2ζ + 1) ω ψ̈_d``, ``|ψ̇_d| <= r_max``
  (``refModel3``; ``ψ_ref`` is taken within π of ``ψ_d``).  The reference model's natural
  frequency and ``r_max`` default faster than the source's (0.1 rad/s and 5 °/s, tuned for
  set-point changes) so that it follows the LOS command; see :class:`LosOptions`.
* **Propeller**: constant, the propeller speed at which the model's surge force vanishes in a
  straight run at the commanded speed through the water (a scalar root find on the model,
  :func:`cruise_propeller_speed`).

Every command is clipped to the vehicle's bounds and then to its rate bound around the last
applied command, so the plant never sees either violated (the box is convex and the last
command lies in it, so both hold together).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from scipy.optimize import brentq

from uuv_ocp import _validation as check
from uuv_ocp.tracking import TrackingProblem

#: The controls :class:`LosGuidance` commands, by name, in order (the REMUS 100's).
COMMANDS = ("delta_r", "delta_s", "n")
#: Reference samples per metre of path speed × second when :func:`path_points` samples a window.
SAMPLES_PER_METRE = 20.0
#: Samples of a window at most (a 10 km survey at 20 per metre).
MAX_SAMPLES = 200_000
#: A segment whose end tangents both lie within this angle (rad) of its direction is a chord of
#: a smooth curve: ``π_h`` follows the tangent along it (module doc); else a corner's leg.
SMOOTH_ANGLE = 0.35


def ssa(angle: float) -> float:
    """Smallest signed angle: ``angle`` wrapped to [−π, π) (rad)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _along(path: np.ndarray, k: int, north: float, east: float) -> float:
    """Distance (m) the point ``(north, east)`` lies past the end of segment ``k``, along it."""
    direction = path[k + 1, :2] - path[k, :2]
    return float((np.array([north, east]) - path[k + 1, :2]) @ direction / np.linalg.norm(direction))


def _wrapped(angles: np.ndarray) -> np.ndarray:
    """:func:`ssa` of an array of angles (rad)."""
    return (angles + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class LosOptions:
    """Gains and settings of :class:`LosGuidance` (module doc: the laws they enter).

    Parameters
    ----------
    speed : float
        Commanded speed through the water (m/s), > 0; sets the constant propeller speed.
    lookahead : float
        Look-ahead distance Δ (m), > 0; ``K_p = 1/Δ``.
    kappa : float
        Integral gain κ >= 0 (dimensionless; ``K_i = κ K_p``); 0 is plain LOS.
    acceptance_radius : float
        Radius of acceptance R (m), > 0: switch when the along-track distance left is below it
        (capped at half of each segment's length).
    path_tolerance : float
        Largest distance (m), > 0, of the polyline from the sampled reference path.
    depth_filter_frequency : float
        ω_z (rad/s), > 0, of the desired depth's low-pass filter (source: 0.02).
    depth_gain : float
        K_pz (rad/m), >= 0, outer depth loop (source: 0.1).
    depth_integral_time : float
        T_z (s), > 0, outer depth loop (source: 100).
    max_pitch : float
        Bound on the desired pitch (rad), in (0, π/2) (not in the source; 30°).
    pitch_gains : tuple of 3 floats
        ``(K_pθ, K_dθ, K_iθ)`` (rad/rad, rad·s/rad, rad/(rad·s)), each >= 0 (source: 5, 2, 0.3).
    heave_gain : float
        K_w (rad·s/m), >= 0, heave-velocity feedback (source: 5).
    nomoto_gain : float
        Nomoto K (1/s), > 0: steady yaw rate per rudder angle (source: 5/20).
    nomoto_time_constant : float
        Nomoto T (s), > 0 (source: the yaw time constant, 1).
    heading_reference_frequency : float
        ω (rad/s), > 0, of the heading reference model (source: 0.1; default 1.0, so that ψ_d
        follows the LOS command).
    heading_reference_damping : float
        ζ, > 0, of the heading reference model (source: 1).
    max_yaw_rate : float
        r_max (rad/s), > 0, bound on ψ̇_d (source: 5 °/s; default 15 °/s for the turns).
    smc_lambda : float
        λ (rad/s), > 0, of the sliding surface ``σ = r̃ + 2λ ψ̃ + λ² ∫ψ̃`` (source: 0.1).
    smc_boundary : float
        Boundary-layer thickness φ_b, > 0 (source: 0.1).
    smc_damping : float
        K_d, >= 0 (source: 0.5).
    smc_switching : float
        K_σ, >= 0 (source: 0.05).
    """

    speed: float = 1.5
    lookahead: float = 10.0
    kappa: float = 0.3
    acceptance_radius: float = 5.0
    path_tolerance: float = 0.05
    depth_filter_frequency: float = 0.02
    depth_gain: float = 0.1
    depth_integral_time: float = 100.0
    max_pitch: float = math.radians(30.0)
    pitch_gains: tuple[float, float, float] = (5.0, 2.0, 0.3)
    heave_gain: float = 5.0
    nomoto_gain: float = 5.0 / 20.0
    nomoto_time_constant: float = 1.0
    heading_reference_frequency: float = 1.0
    heading_reference_damping: float = 1.0
    max_yaw_rate: float = math.radians(15.0)
    smc_lambda: float = 0.1
    smc_boundary: float = 0.1
    smc_damping: float = 0.5
    smc_switching: float = 0.05

    def __post_init__(self) -> None:
        """Check every field; ``ValueError`` names the field, what it must be and the value."""
        nonnegative = {"kappa", "depth_gain", "heave_gain", "smc_damping", "smc_switching"}
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "pitch_gains":
                gains = check.vector("pitch_gains", value, 3)
                for gain in gains:
                    if gain < 0.0:
                        raise ValueError(
                            f"pitch_gains must be three finite numbers >= 0 (K_pθ, K_dθ, K_iθ), "
                            f"got {check.shown(value)}"
                        )
                object.__setattr__(self, "pitch_gains", gains)
            elif item.name in nonnegative:
                object.__setattr__(self, item.name, check.nonnegative_float(item.name, value))
            else:
                object.__setattr__(self, item.name, check.positive_float(item.name, value))
        if self.max_pitch >= 0.5 * math.pi:
            raise ValueError(f"max_pitch must be an angle in (0, π/2) rad, got {self.max_pitch!r}")


def ilos_heading(
    position: tuple[float, float],
    start: tuple[float, float],
    end: tuple[float, float],
    y_int: float,
    lookahead: float,
    kappa: float,
) -> tuple[float, float, float, float]:
    """One evaluation of the ILOS law on the segment ``start → end`` (module doc).

    Parameters
    ----------
    position : (float, float)
        Vehicle's horizontal position ``(x, y)`` (m, NED).
    start, end : (float, float)
        The active segment's waypoints (m).
    y_int : float
        Integral state (m).
    lookahead : float
        Δ (m), > 0.
    kappa : float
        κ >= 0.

    Returns
    -------
    psi_ref : float
        Desired heading (rad), ``π_h − atan((y_e + κ y_int)/Δ)`` (not wrapped beyond π_h's range).
    y_int_dot : float
        ``Δ y_e / (Δ² + (y_e + κ y_int)²)`` (m/s per unit sample time, see module doc).
    along : float
        Along-track error x_e (m) from ``start``.
    cross : float
        Cross-track error y_e (m), > 0 right of the path.
    """
    pi_h = math.atan2(end[1] - start[1], end[0] - start[0])
    dx, dy = position[0] - start[0], position[1] - start[1]
    along = dx * math.cos(pi_h) + dy * math.sin(pi_h)
    cross = -dx * math.sin(pi_h) + dy * math.cos(pi_h)
    corrected = cross + kappa * y_int
    psi_ref = pi_h - math.atan(corrected / lookahead)
    y_int_dot = lookahead * cross / (lookahead**2 + corrected**2)
    return psi_ref, y_int_dot, along, cross


def path_points(problem: Any, tolerance: float) -> np.ndarray:
    """Return the problem's geometric path as a polyline ``(n, 4)`` of ``[x, y, z, ψ_t]``, n >= 2.

    The one place that reads the path: a :class:`~uuv_ocp.tracking.TrackingProblem`'s (and any
    problem with a ``reference``) reference sampled over its window and simplified to within
    ``tolerance`` m (Ramer–Douglas–Peucker); points where it stands still (a hold) are dropped.
    Positions in m (a planar reference has depth 0), ``ψ_t`` the reference's heading there
    (rad, the path tangent unless the reference sets its own heading).
    """
    reference = getattr(problem, "reference", None)
    if reference is None or not hasattr(reference, "evaluate"):
        raise ValueError(
            f"problem must have a reference path (a TrackingProblem), got {type(problem).__name__}"
        )
    if not math.isfinite(reference.t_end):
        raise ValueError(
            "problem.reference must have a finite window (t_end) for line-of-sight guidance to "
            f"follow its path, got t_end = {reference.t_end}"
        )
    span = reference.t_end - reference.t_start
    states = reference.evaluate(np.array([reference.t_start, 0.5 * (reference.t_start + reference.t_end)]))
    speed = float(np.max(np.abs(states[:, reference._surge_index])))  # a scale for the sampling
    count = int(min(MAX_SAMPLES, max(2, math.ceil(span * max(speed, 0.1) * SAMPLES_PER_METRE) + 1)))
    states = reference.evaluate(np.linspace(reference.t_start, reference.t_end, count))
    points = np.zeros((count, 4))
    points[:, :2] = states[:, :2]
    if reference.spatial:
        points[:, 2] = states[:, 2]
    points[:, 3] = states[:, reference.heading_index]
    moved = np.ones(count, dtype=bool)
    moved[1:] = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1) > 1e-9
    points = points[moved]
    if len(points) < 2:
        raise ValueError(f"problem.reference {reference.name!r} does not move: no path to follow")
    return points[_simplified(points[:, :3], tolerance)]


def _simplified(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Return the indices kept by Ramer–Douglas–Peucker (horizontal distance, and depth) at ``tolerance``."""
    keep = np.zeros(len(points), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(points) - 1)]
    while stack:
        first, last = stack.pop()
        if last - first < 2:
            continue
        a, b = points[first], points[last]
        inner = points[first + 1 : last]
        chord = b - a
        length2 = float(chord @ chord)
        fraction = np.clip((inner - a) @ chord / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(inner))
        distance = np.linalg.norm(inner - (a + fraction[:, None] * chord), axis=1)
        worst = int(np.argmax(distance))
        if distance[worst] > tolerance:
            middle = first + 1 + worst
            keep[middle] = True
            stack.extend(((first, middle), (middle, last)))
    return np.flatnonzero(keep)


def cruise_propeller_speed(vehicle: Any, speed: float) -> float:
    """Propeller speed (rpm) at which the vehicle's surge acceleration vanishes at ``speed`` m/s.

    The model's ``u̇`` at a straight run (only ``u = speed`` nonzero, every other control at
    zero, still water) as a function of the propeller speed (the control named ``"n"``), solved
    by Brent's method on ``[0, n_max]``.  The one computation of the cruise propeller speed:
    :class:`LosGuidance` holds it, and :class:`~uuv_ocp.path_following.PathFollowingProblem`
    floors its propeller bound at a fraction of it.

    Raises
    ------
    ValueError
        If the vehicle has no control named ``"n"``, or even ``n_max`` cannot hold ``speed``
        (beyond the vehicle's top speed).
    """
    layout = vehicle.layout
    if "n" not in layout.control_names:
        raise ValueError(
            f"vehicle must have a propeller control named 'n' (rpm), got controls {layout.control_names}"
        )
    propeller = layout.control_names.index("n")
    dynamics = vehicle.model_function()
    state = np.zeros(layout.state_dim)
    state[layout.velocities[0]] = speed
    current = np.zeros(layout.current_dim)
    surge = layout.velocities[0]

    def acceleration(rpm: float) -> float:
        control = np.zeros(layout.control_dim)
        control[propeller] = rpm
        return float(np.asarray(dynamics(state, control, current)).ravel()[surge])

    top = float(vehicle.control_bound[propeller])
    if acceleration(top) <= 0.0:
        raise ValueError(
            f"speed must be reachable at the propeller bound {top:g} rpm (the vehicle's top speed), "
            f"got {speed} m/s"
        )
    return float(brentq(acceleration, 0.0, top, xtol=1e-9))


@dataclass(frozen=True)
class GuidanceStep:
    """What one :meth:`LosGuidance.step` returns (the fields :func:`simulate` reads, and the guidance's).

    Parameters
    ----------
    control : numpy.ndarray, shape (3,)
        Commands ``[δ_r, δ_s, n]`` (rad, rad, rpm), within bounds and rate bounds.
    message : str
        The step's status in ``ClosedLoopResult.statuses``: ``"ilos"`` or ``"los"`` (κ = 0).
    cross_track : float
        Cross-track error y_e (m) on the active segment.
    heading_command : float
        LOS heading ψ_ref (rad).
    depth_command : float
        Filtered desired depth z_d (m).
    pitch_command : float
        Desired pitch θ_d (rad).
    segment : int
        Index of the active segment's first point in :attr:`LosGuidance.path`.
    """

    control: np.ndarray
    message: str
    cross_track: float
    heading_command: float
    depth_command: float
    pitch_command: float
    segment: int
    fallback: bool = False
    deadline_hit: bool = False
    fallback_source: str = ""
    fast_path: str = ""

    @property
    def result(self) -> None:
        """No solver result: guidance solves nothing."""
        return None


class LosGuidance:
    """ILOS guidance with depth and heading autopilots, a controller for :func:`~uuv_ocp.simulate`.

    Parameters
    ----------
    problem : TrackingProblem
        The vehicle (controls ``[δ_r, δ_s, n]``: :class:`~uuv_ocp.Remus100` or one of its
        structure) and the reference whose geometric path is followed; its ``dt`` is the
        guidance's sample time.  ``simulate`` takes the plant and the time window from it.
        Any problem with ``vehicle``, ``dt``, ``reference`` and ``check_state(x)`` will do (a
        path-following preset); the vehicle's states are read by the layout's indices.
    options : LosOptions, optional
        Gains (default ``LosOptions()``).

    Notes
    -----
    The path and the propeller speed are computed by :meth:`warm_up` (``simulate`` calls it),
    or by the first :meth:`step`.  :meth:`reset` restarts the guidance: the active segment, the
    integral states and the reference model (initialised from the first measured state).
    """

    def __init__(self, problem: TrackingProblem | Any, options: LosOptions | None = None) -> None:
        # what the guidance reads of its problem, not its class: a path-following problem with a
        # vehicle, a sample time and a reference path serves as well (path_points reads the path)
        if not all(hasattr(problem, name) for name in ("vehicle", "dt", "reference", "check_state")):
            raise ValueError(
                "problem must have a vehicle, a dt and a reference path (a uuv_ocp.TrackingProblem), "
                f"got {type(problem).__name__}"
            )
        names = tuple(problem.vehicle.layout.control_names)
        if names != COMMANDS:
            raise ValueError(
                f"problem.vehicle must be steered by rudder, stern plane and propeller (controls "
                f"{COMMANDS}, e.g. uo.Remus100()), got controls {names}"
            )
        if options is None:
            options = LosOptions()
        if not isinstance(options, LosOptions):
            raise ValueError(f"options must be a uuv_ocp.LosOptions or None, got {type(options).__name__}")
        self.problem = problem
        self.options = options
        self.solver_name = "ilos" if options.kappa > 0.0 else "los"
        layout = problem.vehicle.layout
        self._position = layout.positions
        self._angles = layout.angles
        self._velocities = layout.velocities
        self._bound = np.asarray(problem.vehicle.control_bound, dtype=float)
        self._rate_step = np.asarray(problem.vehicle.control_rate_bound, dtype=float) * problem.dt
        self.path: np.ndarray | None = None
        self._smooth_segment = np.zeros(0, dtype=bool)  # per segment / point of path (_build)
        self._smooth_joint = np.zeros(0, dtype=bool)
        self.propeller_speed: float | None = None
        #: whether :meth:`warm_up` has run
        self.warmed_up = False
        self.reset()

    def reset(self) -> None:
        """Restart at the first segment with zero integrals; the reference models start at the next state."""
        self._segment = 0
        self._y_int = 0.0
        self._z_int = 0.0
        self._theta_int = 0.0
        self._psi_int = 0.0
        self._reference: list[float] | None = None  # [z_d, ψ_d, r_d, a_d] once started

    def warm_up(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> None:
        """Sample the path and find the propeller speed (what the steps need); then :meth:`reset`."""
        self._build()
        self.reset()
        self.warmed_up = True

    def _build(self) -> None:
        if self.path is None:
            path = path_points(self.problem, self.options.path_tolerance)
            chords = np.arctan2(np.diff(path[:, 1]), np.diff(path[:, 0]))
            # per point: how far the path tangent turns off the outgoing and the incoming segment
            outgoing = np.abs(_wrapped(path[:, 3] - np.append(chords, chords[-1])))
            incoming = np.abs(_wrapped(path[:, 3] - np.insert(chords, 0, chords[0])))
            self._smooth_segment = (outgoing[:-1] < SMOOTH_ANGLE) & (incoming[1:] < SMOOTH_ANGLE)
            self._smooth_joint = (outgoing < SMOOTH_ANGLE) & (incoming < SMOOTH_ANGLE)
            self.path = path
        if self.propeller_speed is None:
            self.propeller_speed = cruise_propeller_speed(self.problem.vehicle, self.options.speed)

    def step(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> GuidanceStep:
        """Commands for the measured state ``x`` (the last applied command ``u_prev`` bounds their rate).

        ``t``, ``current`` and ``parameters`` are accepted for the controller protocol and not
        used: the guidance follows the path, not the reference's timing, and knows no current.
        """
        if parameters is not None:
            raise ValueError("parameters is for an Ocp's NMPC; LosGuidance takes none")
        self._build()
        assert self.path is not None and self.propeller_speed is not None
        state = self.problem.check_state(x)
        o, h = self.options, self.problem.dt
        north, east, depth = (float(state[i]) for i in self._position)
        _, theta, psi = (float(state[i]) for i in self._angles)
        _, _, w, _, q, r = (float(state[i]) for i in self._velocities)
        if self._reference is None:
            self._reference = [depth, psi, r, 0.0]

        # ILOS on the active segment; switch when within the radius of acceptance (ILOSpsi:
        # this step's command is the segment's that was active when it started)
        path, last_segment = self.path, len(self.path) - 2
        k = self._segment
        # a smooth waypoint (module doc) is switched as soon as it is passed, before the command
        while k < last_segment and self._smooth_joint[k + 1] and _along(path, k, north, east) > 0.0:
            k += 1
        self._segment = k
        start, end = path[k], path[k + 1]
        psi_ref, y_int_dot, along, cross = ilos_heading(
            (north, east), (start[0], start[1]), (end[0], end[1]), self._y_int, o.lookahead, o.kappa
        )
        length = float(np.hypot(*(end[:2] - start[:2])))
        if self._smooth_segment[k]:  # a chord of a curve: π_h is the path's tangent (module doc)
            chord = math.atan2(end[1] - start[1], end[0] - start[0])
            first, last = ssa(start[3] - chord), ssa(end[3] - chord)
            psi_ref += first + min(max(along / length, 0.0), 1.0) * (last - first)
        # a corner within the radius of acceptance, after the command (ILOSpsi's order)
        if k < last_segment and not self._smooth_joint[k + 1]:
            if length - along < min(o.acceptance_radius, 0.5 * length):
                self._segment = k + 1
        self._y_int += h * y_int_dot
        # the path's depth at the projection on the segment (the last one: its end depth)
        fraction = min(max(along / length, 0.0), 1.0)
        depth_ref = float(start[2] + fraction * (end[2] - start[2]))

        z_d, psi_d, r_d, a_d = self._reference
        # depth: low-pass filter, PI depth -> pitch, PID pitch -> stern plane
        decay = math.exp(-h * o.depth_filter_frequency)
        z_d = decay * z_d + (1.0 - decay) * depth_ref
        theta_d = o.depth_gain * ((depth - z_d) + self._z_int / o.depth_integral_time)
        theta_d = min(max(theta_d, -o.max_pitch), o.max_pitch)
        kp, kd, ki = o.pitch_gains
        pitch_error = ssa(theta - theta_d)
        stern = kp * pitch_error + kd * q + ki * self._theta_int + o.heave_gain * w
        self._z_int += h * (depth - z_d)
        self._theta_int += h * pitch_error

        # heading: integral SMC on the Nomoto model around the reference model's ψ_d, r_d, a_d
        lam = o.smc_lambda
        e_psi, e_r = ssa(psi - psi_d), r - r_d
        r_ref_dot = a_d - 2.0 * lam * e_r - lam**2 * e_psi
        r_ref = r_d - 2.0 * lam * e_psi - lam**2 * self._psi_int
        sigma = e_r + 2.0 * lam * e_psi + lam**2 * self._psi_int
        switching = o.smc_switching * min(max(sigma / o.smc_boundary, -1.0), 1.0)
        rudder = (
            o.nomoto_time_constant * r_ref_dot + r_ref - o.smc_damping * sigma - switching
        ) / o.nomoto_gain
        self._psi_int += h * e_psi
        # third-order reference model toward ψ_ref taken within π of ψ_d (forward Euler)
        omega, zeta = o.heading_reference_frequency, o.heading_reference_damping
        target = psi_d + ssa(psi_ref - psi_d)
        jerk = omega**3 * (target - psi_d) - (2 * zeta + 1) * omega**2 * r_d - (2 * zeta + 1) * omega * a_d
        psi_d, r_d, a_d = psi_d + h * r_d, r_d + h * a_d, a_d + h * jerk
        r_d = min(max(r_d, -o.max_yaw_rate), o.max_yaw_rate)
        self._reference = [z_d, psi_d, r_d, a_d]

        command = self._admissible(np.array([rudder, stern, self.propeller_speed]), u_prev)
        return GuidanceStep(
            control=command,
            message=self.solver_name,
            cross_track=cross,
            heading_command=psi_ref,
            depth_command=z_d,
            pitch_command=theta_d,
            segment=k,
        )

    def _admissible(self, command: np.ndarray, u_prev: object | None) -> np.ndarray:
        """Clip to the box, then to the rate bound around ``u_prev`` (which lies in the box)."""
        command = np.clip(command, -self._bound, self._bound)
        if u_prev is None:
            return command
        last = np.clip(np.asarray(u_prev, dtype=float).ravel(), -self._bound, self._bound)
        return np.clip(command, last - self._rate_step, last + self._rate_step)
