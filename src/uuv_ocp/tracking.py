"""Trajectory tracking of an underwater vehicle: a preset that builds an :class:`~uuv_ocp.ocp.Ocp`.

:class:`TrackingProblem` is a plain description (vehicle, reference, horizon, weights, terminal
mode).  Its :attr:`TrackingProblem.ocp` declares (DESIGN §4):

* the vehicle's state ``x`` and generalised force ``τ`` (box ``|τ| ≤ τ_max``, rate
  ``|Δτ| ≤ τ̇_max dt``), the reference over the horizon and the current as stagewise
  parameters;
* the cost ``Σ_{k=0}^{N-1} ‖Δτ_k / τ_max‖²_S + Σ_{k=1}^{N-1} ℓ(x_k, x_R,k) + V_N(x_N)`` in
  least-squares form, with ``ℓ = ‖wrap(η − η_R)‖²_Q + ‖ν − ν_R‖²_R`` and angle errors
  ``2 sin(e/2)`` (so ``(2 sin(e/2))² = 2(1 − cos e)``, wrap-safe);
* ``V_N = ℓ`` for ``terminal="none"``, a weighted ``‖x_N − x_R,N‖²`` for ``"cost"`` and the
  hard ``x_N = x_R,N`` for ``"equality"`` (the paper; exact-penalty fallback in the solvers);
* the vehicle's model parameters, if it declares any (``vehicle.model_parameters``: a thruster
  vehicle's ``health`` and ``thrust_offset``), as global parameters: given per instance as
  ``parameters={name: value}``, their defaults when omitted, changed without a rebuild;
* an optional soft position tube ``|e_x|, |e_y| ≤ tube`` (exact L1, ``Weights.tube_penalty``)
  on nodes 1..N.

Any vehicle of the :class:`~uuv_ocp.model.base.VehicleModel` protocol works, and only through
it (its layout, bounds and dynamics Function): :class:`~uuv_ocp.model.planar.Vehicle` (3-DOF,
planar references), :class:`~uuv_ocp.model.fossen6dof.Vehicle6DOF` (6-DOF, references from
``Reference.from_xyz`` / ``waypoints`` / ``hold``; depth tracked, roll and pitch regulated to
the reference's zero) or a class of your own (states without a reference of their name, such
as a 4-DOF vessel's roll, are regulated to zero).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK, built_once
from uuv_ocp.build import Transcribed
from uuv_ocp.model.base import (
    ModelParameter,
    VehicleLayout,
    check_vehicle,
    model_function,
    model_parameters,
    parametric_model_function,
)
from uuv_ocp.obstacles import Obstacle, between_nodes, centre_motion, check_obstacles, vehicle_motion
from uuv_ocp.ocp import Ocp, OcpSpec, check_transcription
from uuv_ocp.reference.path import UNWRAP_STEP, Reference

TERMINAL_MODES = ("equality", "cost", "none")
SAMPLE_BLOCK = 64  # sampling intervals per cached block of reference samples
_FLOAT = np.dtype(float)  # the dtype of the arrays the closed loop's fast instance takes as they are


def vehicle_dimensions(vehicle: Any) -> tuple[int, int, int]:
    """``(state_dim, control_dim, current_dim)`` of a vehicle model (from its layout)."""
    layout: VehicleLayout = vehicle.layout
    return layout.state_dim, layout.control_dim, layout.current_dim


def vehicle_rhs(vehicle: Any, state: ca.SX, control: ca.SX, current: ca.SX, *values: ca.SX) -> ca.SX:
    """Continuous-time right-hand side of a vehicle model: its dynamics Function on the symbols.

    ``values`` are the symbols of the vehicle's model parameters (``model_parameters``, in
    order): the parametric dynamics then; none for a vehicle that declares none.
    """
    if values:
        return parametric_model_function("vehicle", vehicle)(state, control, current, *values)
    return model_function("vehicle", vehicle)(state, control, current)


#: Most RK4 substeps ``substeps=None`` of :class:`~uuv_ocp.PathFollowingProblem` chooses.
MAX_AUTO_SUBSTEPS = 16


class Rk4StabilityWarning(RuntimeWarning):
    """RK4's step ``dt / substeps`` amplifies a mode of the vehicle's linearisation at rest."""


def rest_eigenvalues(vehicle: Any) -> np.ndarray:
    """Eigenvalues (1/s) of ``∂f/∂x`` of the vehicle's dynamics at rest (zero state, control, current).

    Cached per vehicle (by value) when it is hashable: tens of ms to build the Jacobian.
    """
    try:
        return np.array(_cached_rest_eigenvalues(vehicle))
    except TypeError:  # an unhashable user vehicle
        return np.array(_rest_eigenvalues(vehicle))


@functools.lru_cache(maxsize=32)
def _cached_rest_eigenvalues(vehicle: Any) -> tuple[complex, ...]:
    return _rest_eigenvalues(vehicle)


def _rest_eigenvalues(vehicle: Any) -> tuple[complex, ...]:
    nx, nu, nc = vehicle_dimensions(vehicle)
    with BUILD_LOCK:  # CasADi expressions are built here (uuv_ocp._concurrency)
        x = ca.SX.sym("x", nx)
        rhs = vehicle_rhs(vehicle, x, ca.SX(nu, 1), ca.SX(nc, 1))
        jacobian = ca.Function("rest", [x], [ca.jacobian(rhs, x)])
    matrix = np.array(jacobian(np.zeros(nx)), dtype=float)
    return tuple(complex(v) for v in np.linalg.eigvals(matrix)) if np.all(np.isfinite(matrix)) else ()


def rk4_amplification(eigenvalues: np.ndarray, step: float) -> float:
    """Largest ``|R(λ h)|`` of explicit RK4 over ``λ`` (1/s), ``h = step`` (s).

    ``R(z) = 1 + z + z²/2 + z³/6 + z⁴/24``; 0 without eigenvalues.
    """
    return float(np.max(np.abs(_rk4(np.asarray(eigenvalues, dtype=complex) * step)), initial=0.0))


def stable_substeps(vehicle: Any, dt: float) -> int:
    """Fewest RK4 substeps of ``dt`` (s), up to :data:`MAX_AUTO_SUBSTEPS`, stable at rest.

    Stable: ``|R(λ dt / substeps)| <= 1`` for every eigenvalue of the vehicle's linearisation at
    rest with a negative real part (the REMUS 100's roll mode ``−1.94 ± 6.03i`` /s needs
    ``h <= 0.446`` s); modes that do not decay at rest (integrators of the pose) are left out.
    """
    eigenvalues = rest_eigenvalues(vehicle)
    decaying = eigenvalues[eigenvalues.real < -1e-9]
    for substeps in range(1, MAX_AUTO_SUBSTEPS + 1):
        if rk4_amplification(decaying, dt / substeps) <= 1.0:
            return substeps
    return MAX_AUTO_SUBSTEPS


def warn_if_rk4_unstable(vehicle: Any, dt: float, substeps: int) -> None:
    """Warn (:class:`Rk4StabilityWarning`) if RK4 steps of ``dt / substeps`` amplify a mode at rest.

    Only the modes that decay at rest count (as :func:`stable_substeps`).
    """
    eigenvalues = rest_eigenvalues(vehicle)
    decaying = eigenvalues[eigenvalues.real < -1e-9]
    growth = rk4_amplification(decaying, dt / substeps)
    if growth > 1.0:
        worst = decaying[np.argmax(np.abs(_rk4(decaying * dt / substeps)))]
        warnings.warn(
            f"RK4 with dt = {dt} s and substeps = {substeps} is unstable for the vehicle's mode "
            f"λ = {worst.real:.3g}{worst.imag:+.3g}i 1/s at rest (|R(λh)| = {growth:.3g} per step): a "
            f"plan far from the optimum diverges along the horizon; substeps = "
            f"{stable_substeps(vehicle, dt)} is stable",
            Rk4StabilityWarning,
            stacklevel=3,
        )


def _rk4(z: np.ndarray) -> np.ndarray:
    return 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24


def control_limits(vehicle: Any) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric control bound and rate bound (per second) of a vehicle model."""
    return np.asarray(vehicle.control_bound, dtype=float), np.asarray(vehicle.control_rate_bound, dtype=float)


@dataclass(frozen=True)
class Weights:
    """Cost weights of the tracking problem.

    Parameters
    ----------
    pose : tuple of floats
        Weights on the pose error, one per pose state of the vehicle's layout: 3-DOF
        ``(q_x, q_y, q_ψ)``, 6-DOF ``(q_x, q_y, q_z, q_φ, q_θ, q_ψ)``; position errors
        (1/m²), angle errors wrap-safe as ``2(1 − cos(ψ − ψ_R))`` (1/rad²).  At least 3
        (x, y, heading); its length fixes the lengths of ``velocity`` (the same) and
        ``terminal`` (twice).
    velocity : tuple of floats
        Weights on the body-velocity errors (s²/m², s²/rad²), one per degree of freedom.
        Every weight is finite and >= 0; ``pose``, ``velocity`` and ``terminal`` are not all
        zero (``ValueError``).
    rate : tuple of floats
        Weights on the scaled control increments ``Δτ / τ_max`` (dimensionless), one per
        control.
    terminal : tuple of floats
        Terminal weights on ``x_N − x_R,N`` for ``terminal="cost"``, one per state.
    terminal_penalty : float
        Exact L1 penalty weight ρ on terminal residuals (m, rad, m/s, rad/s) in the soft
        fallback of ``terminal="equality"`` and in the derivative-free solvers' cost.  Exact
        (same minimiser as the hard problem) whenever ρ exceeds the largest terminal multiplier.
    rate_penalty : float
        Penalty weight on the scaled rate-bound excess, used by derivative-free solvers only.
    tube_penalty : float
        L1 weight on position-tube slacks (1/m).
    """

    pose: tuple[float, ...] = (1e4, 1e4, 1e3)  # 3 planar, 6 spatial entries (see ``spatial``)
    velocity: tuple[float, ...] = (10.0, 10.0, 10.0)
    rate: tuple[float, ...] = (0.1, 0.1, 0.1)
    terminal: tuple[float, ...] = (1e4, 1e4, 1e3, 100.0, 100.0, 100.0)
    terminal_penalty: float = 1e4
    rate_penalty: float = 1e4
    tube_penalty: float = 1e3

    @classmethod
    def spatial(cls, controls: int = 6) -> Weights:
        """Return the default weights of 6-DOF tracking.

        They are the planar ones, with depth weighted like x and y and roll and pitch
        regulated like heading; ``controls`` rate weights (6, or one per thruster).
        """
        return cls(
            pose=(1e4, 1e4, 1e4, 1e3, 1e3, 1e3),
            velocity=(10.0,) * 6,
            rate=(0.1,) * controls,
            terminal=(1e4, 1e4, 1e4, 1e3, 1e3, 1e3) + (100.0,) * 6,
        )

    @classmethod
    def for_layout(cls, layout: VehicleLayout) -> Weights:
        """Return the default weights of a vehicle layout.

        Positions 1e4 (1/m²), angles 1e3 (1/rad²), other pose states 0, velocities 10, rates
        0.1 and terminal weights the pose's then 100 on velocities: :meth:`Weights` of the
        3-DOF vehicle and :meth:`spatial` of the 6-DOF one, the same numbers.
        """
        pose = tuple(
            1e4 if i in layout.positions else 1e3 if i in layout.angles else 0.0
            for i in range(layout.pose_dim)
        )
        velocities = len(layout.velocities)
        return cls(
            pose=pose,
            velocity=(10.0,) * velocities,
            rate=(0.1,) * layout.control_dim,
            terminal=pose + (100.0,) * velocities,
        )

    def __post_init__(self) -> None:
        """Check every weight and store the vectors as tuples of floats."""
        set_field = object.__setattr__
        for name in ("pose", "velocity", "rate", "terminal"):
            value = getattr(self, name)
            length = len(value) if isinstance(value, (tuple, list, np.ndarray)) else 0
            if length == 0:
                raise ValueError(f"weights.{name} must be a non-empty tuple of numbers, got {value!r}")
            set_field(self, name, check.vector(f"weights.{name}", value, length, nonnegative=True))
        for name in ("terminal_penalty", "rate_penalty", "tube_penalty"):
            set_field(self, name, check.positive_float(f"weights.{name}", getattr(self, name)))
        # the lengths fit a vehicle on their own: a pose of 2 weights was accepted here and
        # refused only by a TrackingProblem (every layout has x, y and a heading in its pose)
        dof = len(self.pose)
        if dof < 3:
            raise ValueError(
                f"weights.pose must have 3 entries or more (one per pose state: 3-DOF x, y, psi; "
                f"6-DOF 6; your vehicle's layout.pose_dim), got {dof}: {check.shown(self.pose)}"
            )
        # the pose block may also hold actuator states (a thruster's delivered force, referenced
        # to zero): fewer velocities than pose weights then, never more
        velocities = len(self.velocity)
        if velocities > dof:
            raise ValueError(
                f"weights.velocity must have {dof} entries (one per degree of freedom, as "
                f"weights.pose) or fewer (a pose with actuator states), got {velocities}: "
                f"{check.shown(self.velocity)}"
            )
        if len(self.terminal) != dof + velocities:
            raise ValueError(
                f"weights.terminal must have {dof + velocities} entries (one per state: {dof} pose, "
                f"{velocities} velocity), got {len(self.terminal)}: {check.shown(self.terminal)}"
            )
        if not any(self.pose + self.velocity + self.terminal):
            raise ValueError(
                "weights.pose, weights.velocity and weights.terminal must not all be zero (no cost "
                "would track the reference)"
            )


class ReferenceSpeedWarning(RuntimeWarning):
    """The reference moves faster than the vehicle can go somewhere on a closed-loop run."""


def _speed_columns(reference: Reference, vehicle: Any) -> tuple[int, int] | None:
    """Columns ``(u_R, v_R)`` of the reference state, or ``None`` where no top speed applies."""
    if not hasattr(vehicle, "max_horizontal_speed"):  # optional: not part of the VehicleModel protocol
        return None
    if reference.spatial != (vehicle.layout.reference == "spatial"):
        return None
    return (6, 7) if reference.spatial else (3, 4)


def warn_if_reference_too_fast(
    reference: Reference, vehicle: Any, times: np.ndarray, *, stacklevel: int = 3
) -> float | None:
    """Warn (:class:`ReferenceSpeedWarning`) if the path speed on ``times`` exceeds the top speed.

    The top speed is the vehicle's ``max_horizontal_speed()`` (over ground in still water,
    crabbing allowed: the physical limit of position tracking; the surge-only
    ``max_speed()[0]`` is lower): :meth:`Vehicle.max_horizontal_speed
    <uuv_ocp.model.planar.Vehicle.max_horizontal_speed>` for a 3-DOF vehicle on a planar
    reference, :meth:`Vehicle6DOF.max_horizontal_speed
    <uuv_ocp.model.fossen6dof.Vehicle6DOF.max_horizontal_speed>` (level, at constant depth) for
    a 6-DOF vehicle on a spatial one, or any vehicle with a ``max_horizontal_speed()`` on its
    kind of reference.  The path speed is ``hypot(u_R, v_R)`` of the reference state.  Other
    pairings, and vehicles without ``max_horizontal_speed``, are not checked.

    Returns
    -------
    float or None
        The first time (s) the path speed exceeds the top speed, or ``None``.
    """
    columns = _speed_columns(reference, vehicle)
    if columns is None:
        return None
    states = reference.evaluate(times)
    speed = np.hypot(states[:, columns[0]], states[:, columns[1]])
    top, crab = vehicle.max_horizontal_speed()
    over = np.flatnonzero(speed > top)
    if over.size == 0:
        return None
    when = float(times[over[0]])
    warnings.warn(
        f"reference {reference.name!r} is faster than the vehicle {vehicle.name!r} can go: path "
        f"speed {float(speed[over[0]]):.3g} m/s > top speed {top:.3g} m/s (over ground, crabbing at "
        f"{math.degrees(crab):.0f} deg) from t = {when:g} s (peak {float(speed.max()):.3g} m/s); "
        "the tracking error grows from there",
        ReferenceSpeedWarning,
        stacklevel=stacklevel,
    )
    return when


class DeclaredPreset(Transcribed):
    """A preset problem: a frozen dataclass that declares its :class:`~uuv_ocp.ocp.Ocp` in ``_declare``.

    Shared by :class:`TrackingProblem` and :class:`~uuv_ocp.path_following.PathFollowingProblem`:
    the Ocp is declared once, on first use, under the build lock, and kept beside the frozen
    fields (not a field: ``replace()`` and ``==`` see only the description).  A preset
    declares a stagewise parameter ``"current"`` (m/s).
    """

    # the fields every preset declares (annotations only: each subclass is the dataclass)
    horizon: int
    dt: float
    substeps: int
    transcription: str
    degree: int | None
    weights: Any

    def _declare(self) -> Ocp:
        raise NotImplementedError

    def _empty_ocp(self, name: str) -> Ocp:
        """Return a new :class:`~uuv_ocp.ocp.Ocp` of this preset's horizon, transcription and penalties."""
        weights = self.weights
        return Ocp(
            self.horizon,
            self.dt,
            substeps=self.substeps,
            transcription=self.transcription,
            degree=self.degree,
            terminal_penalty=weights.terminal_penalty,
            constraint_penalty=weights.terminal_penalty,
            rate_penalty=weights.rate_penalty,
            name=name,
        )

    @property
    def ocp(self) -> Ocp:
        """The :class:`~uuv_ocp.ocp.Ocp` this preset declares (built once, immutable)."""
        ocp: Ocp | None = self.__dict__.get("_declared_ocp")
        if ocp is None:
            with BUILD_LOCK:  # CasADi expressions are built here (uuv_ocp._concurrency)
                ocp = self.__dict__.get("_declared_ocp")
                if ocp is None:
                    ocp = self._declare()
                    object.__setattr__(self, "_declared_ocp", ocp)
        return ocp

    def spec(self) -> OcpSpec:
        """Return the frozen description of :attr:`ocp`."""
        return self.ocp.spec()

    @property
    def still_water_slice(self) -> slice | None:
        """The current over the horizon in ``p``: exact backends specialise the NLP when it is zero."""
        return self.current_slice

    @property
    def current_slice(self) -> slice:
        """Where the current over the horizon, ``(N+1, nc)`` row by row (m/s), sits in ``p``."""
        part: slice = self.spec().layout.entries["current"][0]
        return part

    def replace(self, **changes: Any) -> Self:
        """Return a copy with some fields changed (a new, unbuilt problem).

        A field the preset filled in because it was left ``None`` (listed in ``_defaulted``,
        e.g. a path-following problem's propeller floor, which depends on ``speed``) is left
        ``None`` again unless changed, so the copy takes the default of its own fields.
        """
        for name in self.__dict__.get("_defaulted", ()):
            if name == "weights.rate":
                if "weights" not in changes:
                    changes["weights"] = dataclasses.replace(self.weights, rate=None)
            elif name not in changes:
                changes[name] = None
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]  # subclasses are dataclasses


def current_rows(current: object, horizon: int, nc: int) -> np.ndarray | None:
    """Check an instance's current: ``(nc,)`` held on every node, or ``(N, nc)`` / ``(N+1, nc)`` (m/s).

    Returns ``None`` for ``None``, the ``(nc,)`` vector as given, or ``(N+1, nc)`` rows (an
    ``(N, nc)`` current holds its last row on node N).
    """
    if current is None:
        return None
    try:
        rows = np.array(current, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"current must be numbers of shape ({nc},) or ({horizon}, {nc}), got {current!r}"
        ) from error
    if rows.shape == (nc,):  # held on every node: checked once, broadcast into p
        return check.plausible_array("current", rows, (nc,))
    if rows.shape == (horizon, nc):
        rows = np.vstack([rows, rows[-1:]])
    return check.plausible_array("current", rows, (horizon + 1, nc))


@dataclass(frozen=True)
class TrackingProblem(DeclaredPreset):
    """NMPC trajectory-tracking problem of an underwater vehicle (paper §3.2, DESIGN §4).

    Parameters
    ----------
    vehicle : VehicleModel
        The controller's model of the vehicle: a Vehicle, Vehicle6DOF or any class of the
        :class:`~uuv_ocp.model.base.VehicleModel` protocol.
    reference : Reference
        Path to track, of the kind ``vehicle.layout.reference`` names (planar for a 3-DOF
        vehicle, spatial for a 6-DOF one); mapped to the vehicle's states by
        :meth:`VehicleLayout.reference_state <uuv_ocp.model.base.VehicleLayout.reference_state>`.
    horizon : int
        Number of shooting intervals N, 1 <= N <= 10 000.
    dt : float
        Sampling time (s), > 0.
    terminal : {"equality", "cost", "none"}
        Terminal condition: hard ``x_N = x_R,N`` (paper, with an exact-penalty fallback when
        infeasible), a weighted terminal cost, or nothing.
    weights : Weights, optional
        Cost weights; default ``Weights.for_layout(vehicle.layout)`` (``Weights()`` for 3-DOF,
        ``Weights.spatial()`` for 6-DOF).
    substeps : int
        RK4 steps per interval in the prediction model, >= 1 (multiple shooting).
    transcription : {"multiple_shooting", "collocation"}
        The Ocp's transcription (:class:`~uuv_ocp.ocp.Ocp`): RK4 multiple shooting, or direct
        Radau collocation of ``degree``.
    degree : int, optional
        Collocation points per interval (1..5, default 3), with ``transcription="collocation"``.
    rate_limits : bool
        Enforce ``|Δτ| ≤ τ̇_max dt``.
    position_tube : float or None
        Half-width (m) of a soft tube on the horizontal position error of nodes 1..N, or
        ``None``.
    obstacles : tuple of Obstacle
        Keep-out zones (:class:`~uuv_ocp.obstacles.Obstacle`): hard constraints on nodes
        1..N for exact solvers, an exact penalty for swarms; moving ones are sampled at
        ``t0 + k dt``.
    obstacle_tolerance : float or "auto"
        How far (m, >= 0) the nodes are kept outside each enlarged obstacle
        (``Obstacle.clearance(..., tolerance=)``), so that the path between two nodes stays
        out too.  ``"auto"``: per obstacle, :func:`~uuv_ocp.obstacles.between_nodes` at this
        ``dt`` with the vehicle's top horizontal speed and sampled largest acceleration
        (:func:`~uuv_ocp.obstacles.vehicle_motion`) plus a moving obstacle's own
        (:func:`~uuv_ocp.obstacles.centre_motion` over the reference window): a few mm for the
        RexROV at ``dt = 0.1`` s (:attr:`obstacle_tolerances`).  The default 0 constrains the
        nodes only, where the path between them may cut into the margin by a fraction of a mm.
        The vehicle's speed is through the water: the current is an instance parameter the
        problem does not know when it is built, so under a current of ``c`` m/s give the
        tolerance yourself, ``between_nodes(obstacle, dt, v + c, a)``.
    """

    vehicle: Any
    reference: Reference
    horizon: int = 20
    dt: float = 0.1
    terminal: str = "equality"
    weights: Weights | None = None
    substeps: int = 1
    transcription: str = "multiple_shooting"
    degree: int | None = None
    rate_limits: bool = True
    position_tube: float | None = None
    obstacles: tuple[Obstacle, ...] = ()
    obstacle_tolerance: float | str = 0.0

    def __post_init__(self) -> None:
        """Check the fields against each other and the vehicle; fill in the default weights."""
        layout = check_vehicle("vehicle", self.vehicle).layout
        if not isinstance(self.reference, Reference):
            raise ValueError(f"reference must be a uuv_ocp.Reference, got {type(self.reference).__name__}")
        nx, nu = layout.state_dim, layout.control_dim
        reference_dim = self.reference.state_dim
        if reference_dim != layout.reference_dim:
            kind = "planar" if layout.reference == "planar" else "spatial: Reference.from_xyz/waypoints/hold"
            raise ValueError(
                f"reference must give {layout.reference_dim} states for this vehicle (a {kind} "
                f"reference), got a reference of {reference_dim} states"
            )
        object.__setattr__(self, "horizon", check.positive_int("horizon", self.horizon))
        if self.horizon > 10_000:
            raise ValueError(f"horizon must be an integer <= 10000, got {self.horizon!r}")
        object.__setattr__(self, "dt", check.positive_float("dt", self.dt))
        check.choice("terminal", self.terminal, TERMINAL_MODES)
        if self.weights is None:
            object.__setattr__(self, "weights", Weights.for_layout(layout))
        if not isinstance(self.weights, Weights):
            raise ValueError(f"weights must be a uuv_ocp.Weights, got {self.weights!r}")
        pose, velocity = layout.pose_dim, len(layout.velocities)
        for name, expected in (("pose", pose), ("velocity", velocity), ("rate", nu), ("terminal", nx)):
            if len(getattr(self.weights, name)) != expected:
                raise ValueError(
                    f"weights.{name} must have {expected} entries for this vehicle, got "
                    f"{getattr(self.weights, name)!r}"
                )
        tracked = {"none": ("pose", "velocity"), "cost": ("pose", "velocity", "terminal")}
        if self.terminal in tracked and not any(
            any(getattr(self.weights, name)) for name in tracked[self.terminal]
        ):
            names = " and ".join(f"weights.{name}" for name in tracked[self.terminal])
            raise ValueError(
                f"{names} must not all be zero with terminal={self.terminal!r}: no cost would track "
                "the reference"
            )
        object.__setattr__(self, "substeps", check.positive_int("substeps", self.substeps))
        check_transcription(self.transcription, self.degree, self.substeps)
        if self.transcription == "multiple_shooting":
            warn_if_rk4_unstable(self.vehicle, self.dt, self.substeps)
        check.boolean("rate_limits", self.rate_limits)
        if self.position_tube is not None:
            tube = check.positive_float("position_tube", self.position_tube)
            object.__setattr__(self, "position_tube", tube)
        object.__setattr__(self, "obstacles", check_obstacles(self.obstacles))
        if not (isinstance(self.obstacle_tolerance, str) and self.obstacle_tolerance == "auto"):
            tolerance = self.obstacle_tolerance
            if isinstance(tolerance, str):
                raise ValueError(
                    f"obstacle_tolerance must be a distance in m >= 0 or 'auto', got {tolerance!r}"
                )
            object.__setattr__(
                self, "obstacle_tolerance", check.nonnegative_float("obstacle_tolerance", tolerance)
            )
        if self.reference.t_end - self.reference.t_start < self.horizon * self.dt:
            raise ValueError(
                f"horizon * dt = {self.horizon * self.dt} s exceeds the reference window "
                f"[{self.reference.t_start}, {self.reference.t_end}] s"
            )

    # ------------------------------------------------------------- the Ocp
    def _declare(self) -> Ocp:
        vehicle, weights = self.vehicle, self.weights
        assert weights is not None
        layout: VehicleLayout = vehicle.layout
        nx, nu, nc = layout.state_dim, layout.control_dim, layout.current_dim
        ocp = self._empty_ocp(f"tracking_{self.reference.name}")
        state = ocp.state("x", nx)
        max_thrust, max_rate = control_limits(vehicle)
        rate = max_rate if self.rate_limits else None
        tau = ocp.control("tau", nu, lower=-max_thrust, upper=max_thrust, max_rate=rate)
        ref = ocp.parameter("reference", nx, stagewise=True)
        current = ocp.parameter("current", nc, stagewise=True)
        # the vehicle's model parameters (thruster health): global parameters, changed per step
        values = [ocp.parameter(item.name, item.size) for item in self.model_parameters]
        ocp.set_der(state, vehicle_rhs(vehicle, state, tau, current, *values))
        error = state - ref
        angles = layout.angles
        wrapped = ca.vertcat(*[2.0 * ca.sin(error[i] / 2.0) if i in angles else error[i] for i in range(nx)])
        increment = (tau - ocp.previous(tau)) / ca.DM(max_thrust)
        ocp.add_stage_cost(residual=increment, weight=weights.rate)
        if self.horizon > 1:  # nodes 1..N-1; N = 1 has none (x_1 is the terminal node)
            ocp.add_stage_cost(residual=wrapped, weight=(*weights.pose, *weights.velocity), start=1)
        if self.terminal == "none":
            ocp.add_terminal_cost(residual=wrapped, weight=(*weights.pose, *weights.velocity))
        elif self.terminal == "cost":
            ocp.add_terminal_cost(residual=wrapped, weight=weights.terminal)
        else:
            ocp.subject_to(state == ref, at="terminal")
        horizontal = list(layout.positions[:2])  # (x, y)
        if self.position_tube is not None:
            ocp.bounded(-self.position_tube, error[horizontal], self.position_tube, soft=weights.tube_penalty)
        for i, (obstacle, tolerance) in enumerate(zip(self.obstacles, self.obstacle_tolerances, strict=True)):
            centre = ocp.parameter(f"obstacle{i}", 2, stagewise=True) if obstacle.is_moving else None
            ocp.subject_to(obstacle.clearance(state[horizontal], centre, tolerance) >= 0)
        return ocp

    @built_once
    def obstacle_tolerances(self) -> tuple[float, ...]:
        """Tolerance (m) each obstacle's node constraint holds (``obstacle_tolerance`` resolved)."""
        if not isinstance(self.obstacle_tolerance, str):  # "auto" is the only string __post_init__ keeps
            return (float(self.obstacle_tolerance),) * len(self.obstacles)
        if not self.obstacles:
            return ()
        speed, acceleration = vehicle_motion(self.vehicle)
        window = (self.reference.t_start, self.reference.t_end)
        tolerances = []
        for obstacle in self.obstacles:
            # relative to a moving centre the speeds and accelerations add (triangle inequality)
            centre_speed, centre_acceleration = centre_motion(obstacle, *window)
            tolerances.append(
                between_nodes(obstacle, self.dt, speed + centre_speed, acceleration + centre_acceleration)
            )
        return tuple(tolerances)

    # ------------------------------------------------------------- dimensions
    @property
    def max_thrust(self) -> np.ndarray:
        """Control bounds (N, N·m; thruster forces for a vehicle with thrusters)."""
        return control_limits(self.vehicle)[0]

    @property
    def rate_step_bound(self) -> np.ndarray:
        """Largest scaled control change per interval, ``τ̇_max dt / τ_max``."""
        bound, rate = control_limits(self.vehicle)
        return rate * self.dt / bound

    @property
    def _heading_index(self) -> int:
        """Column of the heading in the vehicle's (reference) state."""
        return int(self.vehicle.layout.heading)

    @built_once  # read on every instance of a closed loop: gathered once
    def model_parameters(self) -> tuple[ModelParameter, ...]:
        """The vehicle's model parameters (``vehicle.model_parameters``; ``()`` if it declares none).

        Each is a global parameter of :attr:`ocp`, given per instance as
        ``parameters={name: value}`` (:meth:`parameters`), its default when omitted.
        """
        return model_parameters(self.vehicle)

    def model_parameter_values(self, p: np.ndarray) -> dict[str, np.ndarray]:
        """Return the model parameters' values in an instance ``p``, by name (copies)."""
        entries = self.spec().layout.entries
        return {item.name: np.array(p[entries[item.name][0]]) for item in self.model_parameters}

    def latest_start(self) -> float:
        """Latest start time t0 (s) whose horizon stays inside the reference window."""
        return self.reference.t_end - self.horizon * self.dt

    # ------------------------------------------------------------- parameters
    def check_state(self, x0: object, name: str = "x0") -> np.ndarray:
        """Validate a state vector: shape (nx,), finite."""
        return check.plausible_array(name, x0, (self.state_dim,))

    def check_time(self, t0: object) -> float:
        """Validate a start time: finite and inside ``[t_start, latest_start()]``."""
        t0 = check.finite_float("t0", t0)
        if t0 < self.reference.t_start - 1e-12 or t0 > self.latest_start() + 1e-9:
            raise ValueError(
                f"t0 must lie in [{self.reference.t_start}, {self.latest_start()}] s so that the "
                f"horizon stays inside the reference window, got {t0}"
            )
        return t0

    def initial_state(self, t0: float | None = None) -> np.ndarray:
        """Return the vehicle's state on the reference pose at ``t0`` (s; the start by default), at rest.

        :meth:`Reference.initial_state <uuv_ocp.reference.path.Reference.initial_state>`
        mapped to the vehicle's layout (``layout.reference_state``): states the reference does
        not name (a roll, say) are zero.
        """
        at_rest = self.reference.initial_state(t0)[None, :]
        state: np.ndarray = self.vehicle.layout.reference_state(at_rest)[0]
        return state.copy()

    def reference_window(self, t0: float, heading: float | None = None) -> np.ndarray:
        """Return the reference states at ``t0 + k dt``, k = 0..N, shape (N+1, nx).

        The heading is shifted by a multiple of 2π so that its first value is the one closest
        to ``heading`` (the vehicle's), which keeps the terminal equality wrap-safe.

        When ``t0`` is a sampling instant ``i dt`` (a closed loop started at a multiple of
        ``dt``), the window is cut from blocks of reference samples at ``(i + k) dt``
        evaluated once per problem; otherwise, or if a block cannot be evaluated, the
        reference is evaluated at ``t0 + k dt``.  The two agree to floating-point rounding
        (the sample times differ by an ulp, the heading branch is chosen the same way).
        """
        window = self._window_from_samples(t0)
        if window is None:
            times = np.minimum(t0 + self.dt * np.arange(self.horizon + 1), self.reference.t_end)
            if self.dt <= UNWRAP_STEP and times[-1] > times[-2]:
                window = self.reference.evaluate_grid(times)
            else:
                window = self.reference.evaluate(times)
        # the reference's states -> the vehicle's (the same array when they are the same states)
        window = self.vehicle.layout.reference_state(window)
        if heading is None:  # the first heading in [-π, π], as the reference gives it
            heading = math.remainder(window[0, self._heading_index], 2.0 * math.pi)
        _move_heading_branch(window, heading, self._heading_index)
        return window

    def _window_from_samples(self, t0: float, out: np.ndarray | None = None) -> np.ndarray | None:
        """Return the window at ``t0 = i dt`` from cached sample blocks, or ``None`` (see above).

        Written into ``out`` (shape (N+1, reference width), e.g. a view into ``p``) when given:
        the same numbers without the window's own array; ``out`` is then unspecified after ``None``.
        """
        dt, horizon, reference = self.dt, self.horizon, self.reference
        if not math.isfinite(t0):
            return None
        first = round(t0 / dt)
        last = first + horizon
        if first * dt != t0 or dt > UNWRAP_STEP or last * dt > reference.t_end:
            return None
        joined = self._joined_blocks(first // SAMPLE_BLOCK, last // SAMPLE_BLOCK)
        if joined is not None:
            start_index, states = joined
            if start_index <= first and last - start_index < states.shape[0]:
                if out is None:
                    return states[first - start_index : last - start_index + 1].copy()
                if out.shape[1] == states.shape[1]:
                    out[:] = states[first - start_index : last - start_index + 1]
                    return out
        window = out
        row = 0  # rows of the window written
        for block in range(first // SAMPLE_BLOCK, last // SAMPLE_BLOCK + 1):
            samples = self._sample_block(block)
            if samples is None:
                return None
            start_index, states = samples
            lo, hi = max(first, start_index), min(last, start_index + states.shape[0] - 1)
            if lo > hi:
                return None  # the reference starts after t0
            part = states[lo - start_index : hi - start_index + 1]  # the memo's: only read
            if window is None:
                window = np.empty((horizon + 1, states.shape[1]))
            elif window.shape[1] != states.shape[1]:
                return None
            if row:
                # neighbouring blocks share their boundary sample: drop it, and move this
                # block's heading to the branch of the previous one
                column = reference.heading_index  # raw reference samples, before the mapping
                rows = window[row : row + part.shape[0] - 1]
                rows[:] = part[1:]
                _shift_heading(rows, window[row - 1, column], part[0, column], column)
                row += part.shape[0] - 1
            else:
                window[: part.shape[0]] = part
                row = part.shape[0]
        return window if row == horizon + 1 else None

    def _joined_blocks(self, first: int, last: int) -> tuple[int, np.ndarray] | None:
        """Return sample blocks ``first`` to ``last`` as one run (first index, states), or ``None``.

        Each block after the first moved to the heading branch of the one before, as the loop
        of :meth:`_window_from_samples` moves them: a window inside the run is a slice of it
        (the same numbers; a memo, so the moves are made once per pair of blocks, not per step).
        ``None`` when a block cannot be sampled or two do not meet: that loop then decides.
        """
        runs = self.joined_blocks
        key = (first, last)
        if key not in runs:
            column = self.reference.heading_index  # raw reference samples, before the mapping
            parts: list[np.ndarray] = []
            start_index = end_index = 0
            for block in range(first, last + 1):
                samples = self._sample_block(block)
                if samples is None or (parts and samples[0] != end_index):
                    runs[key] = None
                    return None
                index, states = samples
                if parts:
                    part = states.copy()
                    _move_heading_branch(part, parts[-1][-1, column], column)
                    parts.append(part[1:])
                else:
                    start_index = index
                    parts.append(states)
                end_index = index + states.shape[0] - 1
            runs[key] = (start_index, parts[0] if len(parts) == 1 else np.concatenate(parts))
        return runs[key]

    @built_once
    def joined_blocks(self) -> dict[tuple[int, int], tuple[int, np.ndarray] | None]:
        """Runs of sample blocks by (first block, last block): :meth:`_joined_blocks`' memo."""
        return {}

    @built_once
    def sample_blocks(self) -> dict[int, tuple[int, np.ndarray] | None]:
        """Reference samples already taken, by block of :data:`SAMPLE_BLOCK` intervals (a memo).

        Filled by :meth:`reference_window`; a ``None`` block is one the direct evaluation serves.
        """
        return {}

    def _sample_block(self, block: int) -> tuple[int, np.ndarray] | None:
        """Return the samples at ``i dt`` for ``i`` in block ``block`` (its first index, states)."""
        blocks = self.sample_blocks
        if block not in blocks:
            dt, reference = self.dt, self.reference
            indices = block * SAMPLE_BLOCK + np.arange(SAMPLE_BLOCK + 1)
            times = indices * dt
            inside = (times >= reference.t_start) & (times <= reference.t_end)
            try:
                blocks[block] = (int(indices[inside][0]), reference.evaluate_grid(times[inside]))
            except (IndexError, ValueError):  # empty, or the speed vanishes inside the block
                blocks[block] = None
        return blocks[block]

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

        A tracking problem takes its data from the reference (``t0``) and ``current``;
        ``parameters`` gives values of the vehicle's model parameters (:attr:`model_parameters`)
        and is refused for a vehicle that declares none; see :meth:`parameters`.
        """
        if parameters is not None and not self.model_parameters:
            raise ValueError(
                f"parameters= is for an Ocp or a vehicle with model parameters; a {type(self).__name__} "
                f"of vehicle {getattr(self.vehicle, 'name', '?')!r} takes x0, t0, u_prev and current"
            )
        return self.parameters(x0, t0, u_prev, current, model=parameters)

    def parameters(
        self,
        x0: object,
        t0: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        model: Mapping[str, object] | None = None,
    ) -> np.ndarray:
        """Parameter vector ``p = [x0, u_prev, model parameters, reference window, current]`` of one instance.

        Parameters
        ----------
        x0 : array_like, shape (nx,)
            Current state (3-DOF: m, m, rad, m/s, m/s, rad/s).
        t0 : float
            Current time (s); the reference is sampled at ``t0 + k dt``.
        u_prev : array_like, shape (nu,), optional
            Last applied control (N, N·m); defaults to zero clipped into the box; must lie
            inside the thrust box.
        current : array_like, shape (nc,), (N, nc) or (N+1, nc), optional
            Inertial current velocity (m/s) the model assumes on each interval.
        model : mapping, optional
            Values of the vehicle's model parameters by name (:attr:`model_parameters`; e.g.
            ``{"health": h}`` for a vehicle with thrusters); each omitted one takes its default.
            ``ValueError`` for an unknown name or a value of the wrong size or out of bounds.
        """
        if model is None and current is None:
            fast = self._closed_loop_parameters(x0, t0, u_prev)
            if fast is not None:
                return fast
        x0 = self.check_state(x0)
        model_values = self._model_values(model)
        t0 = self.check_time(t0)
        layout, nc, heading_index = self._parameter_layout
        n = self.horizon
        current = current_rows(current, n, nc)
        window = self.reference_window(t0, heading=x0[heading_index])
        u_prev = self.ocp.check_previous(u_prev)
        # every part is checked above (the window is finite by construction): written straight
        # into p at the places of Ocp.pack (tests/control/test_mpc_fast_paths.py checks p against
        # Ocp.parameters, the general validated path, on random instances)
        p = np.empty(layout.size)
        p[layout.x0] = x0
        p[layout.u_prev] = u_prev
        p[layout.entries["reference"][0]] = window.ravel()
        for name, value in model_values:
            p[layout.entries[name][0]] = value
        if current is None:
            p[layout.entries["current"][0]] = 0.0
        else:
            p[layout.entries["current"][0]].reshape(n + 1, nc)[:] = current  # a view into p
        if self.obstacles:
            times = t0 + self.dt * np.arange(n + 1)
            for i, obstacle in enumerate(self.obstacles):
                if obstacle.is_moving:
                    p[layout.entries[f"obstacle{i}"][0]] = np.ravel(obstacle.centre_at(times))
        return p

    def _closed_loop_parameters(self, x0: object, t0: object, u_prev: object) -> np.ndarray | None:
        """:meth:`parameters` of a closed loop's instance without a current or model values, or ``None``.

        For float64 arrays ``x0`` (nx,) and ``u_prev`` (nu,) and a float ``t0``: both are
        written straight into ``p`` and checked there in one pass against the bounds of the
        general path (every entry of ``x0`` within ±PLAUSIBLE_MAGNITUDE, ``u_prev`` in the
        slack box; NaN fails), and the window is cut from the sample blocks into ``p``.  The
        same numbers as the general path (tests/control/test_mpc_fast_paths.py); ``None`` for anything else,
        a bad value included: the general path then gives its ``ValueError``.
        """
        plan = self._closed_loop_plan
        if (
            plan is None
            or type(x0) is not np.ndarray
            or type(u_prev) is not np.ndarray
            or not isinstance(t0, float)
            or x0.dtype is not _FLOAT
            or u_prev.dtype is not _FLOAT
        ):
            return None
        size, nx, nu, lows, highs, t_low, t_high, window_part, current_part, defaults, heading = plan
        t0 = float(t0)
        if x0.shape != (nx,) or u_prev.shape != (nu,) or not (t_low <= t0 <= t_high and math.isfinite(t0)):
            return None
        p = np.empty(size)
        p[:nx] = x0
        p[nx : nx + nu] = u_prev
        entries = p[: nx + nu].tolist()
        if not (all(map(operator.le, lows, entries)) and all(map(operator.le, entries, highs))):
            return None
        window = p[window_part].reshape(self.horizon + 1, nx)  # a view into p
        if self._window_from_samples(t0, window) is None:
            window[:] = self.reference_window(t0, heading=x0[heading])
        else:
            _move_heading_branch(window, x0[heading], heading)
        p[current_part] = 0.0
        for part, value in defaults:
            p[part] = value
        return p

    @built_once
    def _closed_loop_plan(self) -> tuple[Any, ...] | None:
        """Where :meth:`_closed_loop_parameters` writes, and its bounds (``None``: it does not apply).

        It applies when ``p`` is ``[x0, u_prev]`` then the window, the current and model
        parameters only (no moving obstacle), and the vehicle's states are the reference's.
        """
        layout, nc, heading = self._parameter_layout
        nx, nu = self.state_dim, self.spec().control_size
        entries = layout.entries
        models = {item.name for item in self.model_parameters}
        if (
            (layout.x0.start, layout.x0.stop, layout.u_prev.start, layout.u_prev.stop) != (0, nx, nx, nx + nu)
            or set(entries) != {"reference", "current", *models}
            or self.vehicle.layout.reference_columns != tuple(range(nx))
            or entries["reference"][0].stop - entries["reference"][0].start != (self.horizon + 1) * nx
            or nx + nu + sum(part.stop - part.start for part, _, _ in entries.values()) != layout.size
        ):
            return None
        x_low, x_high = -check.PLAUSIBLE_MAGNITUDE, check.PLAUSIBLE_MAGNITUDE
        u_low, u_high = self.ocp.previous_bounds()
        return (
            layout.size,
            nx,
            nu,
            [x_low] * nx + list(u_low),
            [x_high] * nx + list(u_high),
            self.reference.t_start - 1e-12,  # check_time's bounds
            self.latest_start() + 1e-9,
            entries["reference"][0],
            entries["current"][0],
            tuple((entries[name][0], value) for name, value in self._default_model_values),
            heading,
        )

    def _model_values(self, model: Mapping[str, object] | None) -> tuple[tuple[str, np.ndarray], ...]:
        """Return checked values of every model parameter (the defaults where ``model`` omits one)."""
        declared = self.model_parameters
        if model is None:
            return self._default_model_values
        if not isinstance(model, Mapping):
            raise ValueError(
                f"parameters must be a mapping of model parameter names to values, got {model!r}"
            )
        names = [item.name for item in declared]
        unknown = sorted(set(model) - set(names))
        if unknown:
            raise ValueError(
                f"parameters has unknown names {unknown}: vehicle {getattr(self.vehicle, 'name', '?')!r} "
                f"declares the model parameters {names}"
            )
        return tuple(
            (item.name, item.check(model[item.name]) if item.name in model else np.array(item.default))
            for item in declared
        )

    @built_once
    def _default_model_values(self) -> tuple[tuple[str, np.ndarray], ...]:
        """The model parameters' defaults (only read: written into each new ``p``)."""
        return tuple((item.name, np.array(item.default)) for item in self.model_parameters)

    def with_state(self, p: np.ndarray, x0: object) -> np.ndarray:
        """Return a copy of the instance ``p`` (from :meth:`parameters`) with its state set to ``x0``.

        Equal to :meth:`parameters` with ``x0`` and the time, last control and current of ``p``:
        besides its own place, the state chooses the heading branch of the reference window,
        which is moved here the same way.  ``x0`` is checked as there.
        """
        x0 = self.check_state(x0)
        layout, _, heading_index = self._parameter_layout
        new = p.copy()
        new[layout.x0] = x0
        window = new[layout.entries["reference"][0]].reshape(self.horizon + 1, -1)  # a view into new
        _move_heading_branch(window, x0[heading_index], heading_index)
        return new

    @built_once
    def _parameter_layout(self) -> tuple[Any, int, int]:
        """The layout of ``p``, the current's size and the heading's column (the hot path's memo)."""
        return (self.spec().layout, vehicle_dimensions(self.vehicle)[2], self._heading_index)

    def parameter_parts(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Numeric ``p`` -> (x0 (nx,), reference (N+1, nx), u_prev (nu,), current (N, nc))."""
        layout = self.spec().layout
        reference, size, _ = layout.entries["reference"]
        current, nc, _ = layout.entries["current"]
        return (
            p[layout.x0],
            p[reference].reshape(self.horizon + 1, size),
            p[layout.u_prev],
            p[current].reshape(self.horizon + 1, nc)[:-1],
        )

    def initial_guess(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cold start: the reference window from ``x_0``, the last control held."""
        x0, reference, _, _ = self.parameter_parts(p)
        states = reference.copy()
        states[0] = x0
        return states, np.tile(self.previous_scaled(p), (self.horizon, 1))


def _move_heading_branch(states: np.ndarray, heading: float, column: int = 2) -> None:
    """Shift the heading column of ``states`` by a multiple of 2π, in place.

    The multiple is the one that brings its first value closest to ``heading``.
    """
    _shift_heading(states, heading, states[0, column], column)


def _shift_heading(states: np.ndarray, heading: float, start: float, column: int) -> None:
    """Add to ``states``' heading column the multiple of 2π that brings ``start`` closest to ``heading``."""
    # Python's round on a float (half to even, as np.round) instead of np.round on a numpy
    # scalar: this runs on every closed-loop step (a third of TrackingProblem.with_state's time)
    turns = (float(heading) - float(start)) / (2.0 * math.pi)
    if not math.isfinite(turns):  # NaN and inf propagate as they did through np.round
        states[:, column] += turns
    elif turns := round(turns):  # no turn leaves the column as it is
        states[:, column] += 2.0 * math.pi * turns
