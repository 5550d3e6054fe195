"""Thruster layouts and the thrust-allocation matrix of a 6-DOF vehicle.

A thruster ``i`` at body-frame position ``r_i`` (m) that pushes with force ``f_i`` (N) along the
body-frame unit vector ``d_i`` contributes the generalised force ``f_i [d_i; r_i × d_i]``
(Fossen 2011, §11.2.1).  Stacking the columns gives the 6×n allocation matrix ``T`` with
``τ = T f``.  All vectors are in Fossen's body frame: x forward, y starboard, z down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uuv_ocp import _validation as check

GENERALISED_FORCE_NAMES = ("X", "Y", "Z", "K", "M", "N")
_UNIT_TOLERANCE = 1e-6


def _rows(name: str, value: object) -> np.ndarray:
    """Return ``value`` as a finite (n, 3) float array with n >= 1, else raise ``ValueError``."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a real array of shape (n, 3), got {value!r}") from error
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] < 1:
        raise ValueError(f"{name} must have shape (n, 3) with n >= 1, got shape {array.shape}")
    return check.finite_array(name, array, array.shape)


def _from_ros_mounts(
    mounts: tuple[tuple[tuple[float, float, float], tuple[float, float]], ...],
) -> tuple[tuple[tuple[float, float, float], ...], tuple[tuple[float, float, float], ...]]:
    """Positions and directions in Fossen's frame of thrusters mounted as in a uuv_simulator xacro.

    Each mount is ``((x, y, z), (pitch, yaw))`` in the ROS body frame (x forward, y port, z up;
    m and degrees, roll 0): the thruster pushes along its frame's x axis, i.e.
    ``(cos yaw cos pitch, sin yaw cos pitch, −sin pitch)``, and ``(x, y, z) → (x, −y, −z)``
    maps both to x forward, y starboard, z down.
    """
    positions = []
    directions = []
    for (x, y, z), (pitch_deg, yaw_deg) in mounts:
        pitch, yaw = math.radians(pitch_deg), math.radians(yaw_deg)
        direction = (math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch))
        positions.append((x, -y, -z))
        directions.append((direction[0], -direction[1], -direction[2]))
    return tuple(positions), tuple(directions)


@dataclass(frozen=True)
class ThrusterConfiguration:
    """Positions, directions and force bounds of a vehicle's fixed thrusters.

    Parameters
    ----------
    positions : array_like, shape (n, 3)
        Body-frame position ``r_i`` of each thruster's point of action (m), relative to the
        body origin of the vehicle model (x forward, y starboard, z down).
    directions : array_like, shape (n, 3)
        Body-frame unit vector ``d_i`` along which a positive command ``f_i`` pushes the
        vehicle.  Each row must have norm 1 to within 1e-6; it is then normalised exactly.
    max_thrust : float or array_like, shape (n,)
        Symmetric bound ``|f_i| <= max_thrust[i]`` (N), > 0.  A scalar applies to every thruster.
    name : str
        Label used in tables and plots.
    time_constant : float or array_like, shape (n,)
        First-order response of each thruster (s), ``ḟ_a = (f − f_a) / τ``: the delivered
        force ``f_a`` lags the command ``f``.  Either all 0 (default: the command acts at once,
        the vehicle's state stays 12-long) or all > 0 (the vehicle's state carries ``f_a``,
        :class:`~uuv_ocp.model.Vehicle6DOF`); a scalar applies to every thruster.  Why not
        mixed: a thruster with τ = 0 has no state, and one layout per vehicle keeps the state's
        meaning fixed.

    Notes
    -----
    The fields are stored as tuples, so configurations are hashable and compare by value.
    """

    positions: tuple[tuple[float, float, float], ...]
    directions: tuple[tuple[float, float, float], ...]
    max_thrust: tuple[float, ...]
    name: str = "thrusters"
    time_constant: tuple[float, ...] | float = 0.0

    def __post_init__(self) -> None:
        """Validate shapes, finiteness, unit directions and bounds; store rows as tuples."""
        set_field = object.__setattr__
        positions = _rows("positions", self.positions)
        count = positions.shape[0]
        directions = _rows("directions", self.directions)
        if directions.shape != (count, 3):
            raise ValueError(
                f"directions must have shape ({count}, 3) to match positions, got shape {directions.shape}"
            )
        norms = np.linalg.norm(directions, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > _UNIT_TOLERANCE)
        if bad.size:
            raise ValueError(
                f"directions must be unit vectors (norm 1 within {_UNIT_TOLERANCE:g}), "
                f"got norm {norms[bad[0]]!r} in row {int(bad[0])}: {directions[bad[0]].tolist()}"
            )
        directions = directions / norms[:, None]
        max_thrust = self.max_thrust
        if isinstance(max_thrust, (int, float)) and not isinstance(max_thrust, bool):
            max_thrust = (max_thrust,) * count
        set_field(self, "positions", tuple(tuple(float(v) for v in row) for row in positions))
        set_field(self, "directions", tuple(tuple(float(v) for v in row) for row in directions))
        set_field(self, "max_thrust", check.vector("max_thrust", max_thrust, count, positive=True))
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a string, got {self.name!r}")
        constant = self.time_constant
        if np.ndim(constant) == 0 and not isinstance(constant, (bool, np.bool_, str)):
            constant = (constant,) * count  # any real scalar (numpy's too) applies to every thruster
        constants = check.vector("time_constant", constant, count, nonnegative=True)
        if any(constants) and not all(constants):
            raise ValueError(f"time_constant must be all 0 or all > 0 (s), got {constants!r}")
        set_field(self, "time_constant", constants)

    @property
    def responds(self) -> bool:
        """True when the thrusters have a first-order response (``time_constant`` > 0)."""
        return any(self.time_constant)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ presets
    @classmethod
    def bluerov2_heavy(cls) -> ThrusterConfiguration:
        """Build the eight T200 thrusters of the BlueROV2 in its Heavy configuration.

        Four horizontal thrusters vectored at 45° in a plane 85 mm below the origin at
        ``(±0.156, ±0.111, 0.085)`` m and four vertical thrusters at ``(±0.120, ±0.218, 0)`` m,
        body frame x forward, y starboard, z down.  Order: horizontal front-right, front-left,
        aft-right, aft-left, then vertical front-right, front-left, aft-right, aft-left.  The
        positive directions alternate as in the source (they follow the propeller handedness;
        with symmetric bounds only the line of action matters).

        Source: the thrust-allocation script ``Thrust_Allocation.m`` of A. Sitorus' BlueROV2
        thesis code (GitHub ``AndreasKing-Goks/0_THESIS``), which takes its vehicle data from
        von Benzon et al., "An Open-Source Benchmark Simulator: Control of a BlueROV2 Underwater
        Robot", J. Mar. Sci. Eng. 10(12), 1898 (2022).  The geometry was not checked against
        the paper's own table.

        Bound 40 N per thruster, the same in both directions: the T200 at 16 V is rated at about
        5.25 kgf (51.5 N) forward and 4.1 kgf (40.2 N) reverse (Blue Robotics T200 technical
        details; the Blue Robotics forum confirms that forward thrust is about 30 % above
        reverse).  Taking the weaker direction makes every command inside the box achievable
        whichever way a propeller is mounted.  The 5.25 / 4.1 kgf figures themselves could not
        be checked against a stored copy of the product page.
        """
        s = math.sqrt(0.5)
        return cls(
            positions=(
                (0.156, 0.111, 0.085),
                (0.156, -0.111, 0.085),
                (-0.156, 0.111, 0.085),
                (-0.156, -0.111, 0.085),
                (0.120, 0.218, 0.0),
                (0.120, -0.218, 0.0),
                (-0.120, 0.218, 0.0),
                (-0.120, -0.218, 0.0),
            ),
            directions=(
                (s, -s, 0.0),
                (s, s, 0.0),
                (-s, -s, 0.0),
                (-s, s, 0.0),
                (0.0, 0.0, -1.0),
                (0.0, 0.0, 1.0),
                (0.0, 0.0, 1.0),
                (0.0, 0.0, -1.0),
            ),
            max_thrust=(40.0,) * 8,
            name="bluerov2-heavy-t200",
        )

    @classmethod
    def rexrov(cls) -> ThrusterConfiguration:
        """Build the eight thrusters of uuv_simulator's RexROV in Fossen's body frame.

        Positions and orientations from ``uuv_descriptions/urdf/rexrov_actuators.xacro``
        (GitHub ``uuvsimulator/uuv_simulator``): four thrusters pitched about 75° out of the
        horizontal plane at ``(±0.890895, ±0.334385, 0.528822)`` m and four horizontal ones at
        45° at ``(±0.412125, ±0.505415, 0.129)`` m (ROS ``base_link``: x forward, y port, z up),
        in the file's order 0..7.  Each pushes along the x axis of its frame, oriented by
        ``rpy = (0, pitch, yaw)``, mapped to x forward, y starboard, z down as for
        :meth:`rexrov2`.  The allocation matches the simulator's
        ``uuv_control/uuv_thruster_manager/config/rexrov/TAM.yaml`` after the same change of
        frame.

        Bound 2000 N per thruster: the figure DESIGN §6 states (the planar
        :meth:`Vehicle.rexrov <uuv_ocp.model.planar.Vehicle.rexrov>`'s thrust box 2000 N /
        2000 N / 1400 N·m is reachable with it).  The simulator itself sets no useful bound:
        its ``thruster_manager.yaml`` has ``max_thrust: 100000``.
        """
        # (x, y, z) in m and (pitch, yaw) in degrees, as written in rexrov_actuators.xacro
        mounts = (
            ((-0.890895, 0.334385, 0.528822), (-74.53, -53.21)),
            ((-0.890895, -0.334385, 0.528822), (-74.53, 53.21)),
            ((0.890895, 0.334385, 0.528822), (-105.47, 53.21)),
            ((0.890895, -0.334385, 0.528822), (-105.47, -53.21)),
            ((-0.412125, 0.505415, 0.129), (0.0, 45.0)),
            ((-0.412125, -0.505415, 0.129), (0.0, -45.0)),
            ((0.412125, 0.505415, 0.129), (0.0, 135.0)),
            ((0.412125, -0.505415, 0.129), (0.0, -135.0)),
        )
        positions, directions = _from_ros_mounts(mounts)
        return cls(
            positions=positions, directions=directions, max_thrust=(2000.0,) * 8, name="rexrov-thrusters"
        )

    @classmethod
    def rexrov2(cls) -> ThrusterConfiguration:
        """Build the six thrusters of uuv_simulator's RexROV2 in Fossen's body frame.

        Positions and orientations from ``rexrov2_description/xacro/rexrov2_actuators.xacro``
        (GitHub ``uuvsimulator/rexrov2``).  There each thruster pushes along the x axis of its
        frame, oriented by ``rpy = (0, pitch, yaw)`` in the ROS body frame (x forward, y port,
        z up), so its direction is ``(cos yaw cos pitch, sin yaw cos pitch, −sin pitch)``;
        positions and directions are then mapped to x forward, y starboard, z down by
        ``(x, y, z) → (x, −y, −z)``.  The resulting allocation matches the simulator's
        ``rexrov2_control/config/TAM.yaml`` after the same change of frame.  Bound 1540 N per
        thruster: ``max_thrust`` of ``rexrov2_control/config/thruster_manager.yaml``.
        """
        # (x, y, z) in m and (pitch, yaw) in degrees, as written in rexrov2_actuators.xacro
        mounts = (
            ((0.4878, 0.0, 0.2373), (0.0, 90.0)),
            ((-0.8217, 0.0, 0.589), (-75.0, 0.0)),
            ((0.8654, -0.5322, 0.5332), (-67.5, 90.0)),
            ((0.8654, 0.5322, 0.5332), (67.5, 90.0)),
            ((-0.7076, 0.5129, 0.2404), (0.0, 25.0)),
            ((-0.7076, -0.5129, 0.2404), (0.0, -25.0)),
        )
        positions, directions = _from_ros_mounts(mounts)
        return cls(
            positions=positions,
            directions=directions,
            max_thrust=(1540.0,) * 6,
            name="rexrov2-thrusters",
        )

    # --------------------------------------------------------------- properties
    @property
    def count(self) -> int:
        """Number of thrusters n."""
        return len(self.positions)

    @property
    def allocation(self) -> np.ndarray:
        """Thrust-allocation matrix ``T`` of shape (6, n) with columns ``[d_i; r_i × d_i]``.

        ``τ = T f`` maps thruster forces ``f`` (N) to the generalised force
        ``τ = [X, Y, Z, K, M, N]`` (N, N, N, N·m, N·m, N·m).  A fresh array on every call.
        """
        positions = np.array(self.positions)
        directions = np.array(self.directions)
        return np.vstack([directions.T, np.cross(positions, directions).T])

    def generalised_force_limits(self) -> tuple[float, ...]:
        """Largest pure force or moment on each axis that the thrusters can produce (N, N·m).

        For axis ``k`` this is ``max t`` subject to ``T f = t e_k`` and ``|f_i| <= max_thrust[i]``
        (a linear programme, solved with ``scipy.optimize.linprog``): the other five components
        are held at zero.  An axis the thrusters cannot actuate on its own gives 0.

        Returns
        -------
        tuple of 6 floats
            Limits for ``[X, Y, Z, K, M, N]``.
        """
        from scipy.optimize import linprog

        allocation = self.allocation
        count = self.count
        bounds = [(-limit, limit) for limit in self.max_thrust] + [(0.0, None)]
        cost = np.zeros(count + 1)
        cost[-1] = -1.0
        limits = []
        for axis in range(6):
            unit = np.zeros((6, 1))
            unit[axis] = 1.0
            result = linprog(
                cost,
                A_eq=np.hstack([allocation, -unit]),
                b_eq=np.zeros(6),
                bounds=bounds,
                method="highs",
            )
            if result.status != 0:
                raise RuntimeError(
                    f"linprog failed on axis {GENERALISED_FORCE_NAMES[axis]}: {result.message}"
                )
            limits.append(max(float(result.x[-1]), 0.0))
        return tuple(limits)
