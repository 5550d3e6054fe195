r"""6-DOF underwater vehicle model in Fossen's vectorial form (Fossen 2011).

References are to T. I. Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*,
Wiley, 2011.

State ``x = [x, y, z, φ, θ, ψ, u, v, w, p, q, r]``: NED position (m), ZYX Euler angles roll,
pitch, yaw (rad), body-frame linear velocity (m/s) and angular velocity (rad/s).  The body frame
has x forward, y starboard and z down.  Control ``τ = [X, Y, Z, K, M, N]``: generalised force
in the body frame about the body origin (N, N, N, N·m, N·m, N·m).  Current: inertial (NED)
water velocity ``V_c = [V_x, V_y, V_z]`` (m/s), constant and irrotational.

Equations (Fossen 2011 §10.3, equations of relative motion).  With the body-frame current
``ν_c = [R(Θ)ᵀ V_c; 0, 0, 0]`` and the relative velocity ``ν_r = ν − ν_c``,

.. math::

    M \dot\nu_r + C_{RB}(\nu_r)\nu_r + C_A(\nu_r)\nu_r + D(\nu_r)\nu_r + g(\eta) = \tau,
    \qquad
    \dot\nu = \dot\nu_r + [-S(\omega) R^\top V_c;\ 0],
    \qquad
    \dot\eta = J(\Theta)\,\nu .

- ``M = M_RB + M_A``, with ``M_RB = [[m I₃, −m S(r_g)], [m S(r_g), I_o]]`` (eq. 3.44; ``I_o``
  is the inertia about the body origin) and ``M_A`` the added-mass matrix (positive
  magnitudes, symmetric positive semidefinite).
- ``C_RB(ν) = [[m S(ν₂), −m S(ν₂) S(r_g)], [m S(r_g) S(ν₂), −S(I_o ν₂)]]``, the
  parametrisation independent of the linear velocity (eq. 3.60).  With it, and because
  ``d/dt (Rᵀ V_c) = Ṙᵀ V_c = −S(ω) Rᵀ V_c`` for constant ``V_c``, the rigid-body terms satisfy
  ``M_RB ν̇ + C_RB(ν) ν = M_RB ν̇_r + C_RB(ν_r) ν_r`` exactly (Property 10.1), so a constant
  irrotational current enters only through ``ν_r``.
- ``C_A(ν) = [[0, −S(A₁₁ν₁ + A₁₂ν₂)], [−S(A₁₁ν₁ + A₁₂ν₂), −S(A₂₁ν₁ + A₂₂ν₂)]]`` (eq. 6.43).
- ``D(ν_r) = diag(d_lin) + diag(d_quad) · diag(|ν_r|)`` (positive magnitudes).
- ``g(η)`` is the restoring force of weight W at ``r_g`` and buoyancy B at ``r_b`` (eq. 4.6).
- ``J(Θ) = diag(R(Θ), T(Θ))`` with the ZYX rotation ``R = R_z(ψ) R_y(θ) R_x(φ)`` (eq. 2.18)
  and the Euler-rate transform ``T(Θ)`` (eq. 2.28).  The position derivative uses the absolute
  velocity ``ν``, not ``ν_r``.

``T(Θ)`` contains ``1/cos θ`` and ``tan θ``: it is singular at ``θ = ±90°`` and the model must
not be used there (keep the pitch well inside ``(−90°, 90°)``, e.g. with a state bound).

The accelerations are ``ν̇_r = M⁻¹ (τ − C(ν_r)ν_r − D(ν_r)ν_r − g(η))`` with ``M⁻¹`` the
numeric inverse of the constant mass matrix, computed once with numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import cast

import casadi as ca
import numpy as np
import numpy.typing as npt

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import built_once
from uuv_ocp.model.base import ModelParameter, VehicleLayout
from uuv_ocp.model.damping import steady_speed
from uuv_ocp.model.thrusters import GENERALISED_FORCE_NAMES, ThrusterConfiguration

STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
STATE_UNITS = ("m", "m", "m", "rad", "rad", "rad", "m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")
FORCE_NAMES = GENERALISED_FORCE_NAMES
FORCE_UNITS = ("N", "N", "N", "N·m", "N·m", "N·m")
STATE_DIM = 12
FORCE_DIM = 6
CURRENT_DIM = 3
GRAVITY = 9.81  # m/s², used by the presets only

_SYMMETRY_TOLERANCE = 1e-9  # relative to the largest entry
_CACHED = ("dynamics", "thruster_dynamics", "faulty_thruster_dynamics")


# ---------------------------------------------------------------------- helpers
def _skew_numpy(a: np.ndarray) -> np.ndarray:
    """Numeric cross-product matrix ``S(a)`` with ``S(a) b = a × b``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _skew(a):
    """Symbolic cross-product matrix ``S(a)`` (Fossen 2011 eq. 2.10) of a 3-vector."""
    return ca.vertcat(
        ca.horzcat(0, -a[2], a[1]),
        ca.horzcat(a[2], 0, -a[0]),
        ca.horzcat(-a[1], a[0], 0),
    )


def mass_coriolis_matrix(mass: np.ndarray, nu):
    """``m2c(M, ν) = [[0, −S(M₁₁ν₁ + M₁₂ν₂)], [−S(…), −S(M₂₁ν₁ + M₂₂ν₂)]]`` (Fossen 2011 eq. 6.43).

    Parameters
    ----------
    mass : numpy.ndarray, shape (6, 6)
        A mass matrix (kg, kg·m, kg·m²): the added mass, or a symmetric rigid-body one.
    nu : casadi.SX, MX or DM, shape (6,)
        Velocity ``[u, v, w, p, q, r]`` (m/s, rad/s).

    Returns
    -------
    casadi.SX, MX or DM, shape (6, 6)
    """
    linear, angular = nu[0:3], nu[3:6]
    a1 = ca.DM(mass[0:3, 0:3]) @ linear + ca.DM(mass[0:3, 3:6]) @ angular
    a2 = ca.DM(mass[3:6, 0:3]) @ linear + ca.DM(mass[3:6, 3:6]) @ angular
    return ca.vertcat(
        ca.horzcat(ca.DM.zeros(3, 3), -_skew(a1)),
        ca.horzcat(-_skew(a1), -_skew(a2)),
    )


def _column(value, length: int):
    """Return a CasADi column: symbolic input unchanged, numbers as a ``DM`` of ``length`` rows."""
    if isinstance(value, (ca.SX, ca.MX, ca.DM)):
        return value
    return ca.DM(np.asarray(value, dtype=float).reshape(length, 1))


def rotation_matrix(phi, theta, psi):
    """ZYX Euler rotation ``R(Θ) = R_z(ψ) R_y(θ) R_x(φ)`` from body to NED (Fossen 2011 eq. 2.18).

    Parameters
    ----------
    phi, theta, psi : casadi.SX, MX or float
        Roll, pitch and yaw (rad).

    Returns
    -------
    casadi.SX, MX or DM, shape (3, 3)
    """
    cphi, sphi = ca.cos(phi), ca.sin(phi)
    cth, sth = ca.cos(theta), ca.sin(theta)
    cpsi, spsi = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth),
        ca.horzcat(spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi),
        ca.horzcat(-sth, cth * sphi, cth * cphi),
    )


def euler_rate_matrix(phi, theta):
    """Euler-angle rate transform ``T(Θ)`` with ``Θ̇ = T(Θ) ω`` (Fossen 2011 eq. 2.28).

    Singular at ``θ = ±90°`` (``cos θ = 0``): do not evaluate it there.

    Parameters
    ----------
    phi, theta : casadi.SX, MX or float
        Roll and pitch (rad).

    Returns
    -------
    casadi.SX, MX or DM, shape (3, 3)
    """
    cphi, sphi = ca.cos(phi), ca.sin(phi)
    cth, tth = ca.cos(theta), ca.tan(theta)
    return ca.vertcat(
        ca.horzcat(1, sphi * tth, cphi * tth),
        ca.horzcat(0, cphi, -sphi),
        ca.horzcat(0, sphi / cth, cphi / cth),
    )


def _symmetric_matrix(name: str, value: object, size: int) -> np.ndarray:
    """Return ``value`` (a (size, size) matrix or its diagonal) as a finite symmetric array."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"{name} must be a ({size}, {size}) real matrix or {size} diagonal entries, got {value!r}"
        ) from error
    if array.shape == (size,):
        array = np.diag(array)
    if array.shape != (size, size):
        raise ValueError(
            f"{name} must have shape ({size}, {size}) or ({size},) for a diagonal, got shape {array.shape}"
        )
    array = check.finite_array(name, array, (size, size))
    asymmetry = float(np.max(np.abs(array - array.T)))
    if asymmetry > _SYMMETRY_TOLERANCE * max(1.0, float(np.max(np.abs(array)))):
        raise ValueError(f"{name} must be symmetric, got a largest |A - Aᵀ| entry of {asymmetry!r}")
    return 0.5 * (array + array.T)


def _matrix_tuple(array: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in row) for row in array)


# ------------------------------------------------------------------------ model
@dataclass(frozen=True)
class Vehicle6DOF:
    """Parameters of a 6-DOF underwater vehicle in Fossen's model (see the module docstring).

    Parameters
    ----------
    mass : float
        Rigid-body mass m (kg), > 0.
    inertia : array_like, shape (3, 3) or (3,)
        Rigid-body inertia matrix ``I_o`` about the body ORIGIN (kg·m²), symmetric positive
        definite; three numbers mean its diagonal.  Products of inertia enter with their sign in
        the matrix, ``I_o = [[I_x, −I_xy, −I_xz], ...]`` with ``I_xy = ∫ x y dm``.
    added_mass : array_like, shape (6, 6) or (6,)
        Added-mass matrix ``M_A`` as POSITIVE magnitudes (kg, kg·m, kg·m²), i.e. ``M_A`` itself,
        not the negative derivatives ``X_u̇, ...``; symmetric positive semidefinite.  Six numbers
        mean its diagonal ``(X_u̇, Y_v̇, Z_ẇ, K_ṗ, M_q̇, N_ṙ)`` in magnitude.
    linear_damping : array_like, shape (6,)
        Magnitudes of the linear damping ``(X_u, Y_v, Z_w, K_p, M_q, N_r)`` (N·s/m for the first
        three, N·m·s/rad for the last three), >= 0.
    quadratic_damping : array_like, shape (6,)
        Magnitudes of the quadratic damping ``(X_u|u|, ..., N_r|r|)`` (N·s²/m², N·m·s²/rad²),
        >= 0.
    weight : float
        Weight W = m g (N), > 0; given separately so that the gravity constant is the user's.
    buoyancy : float
        Buoyancy B = ρ g ∇ (N), >= 0.
    centre_of_gravity : array_like, shape (3,)
        ``r_g`` in the body frame, relative to the body origin (m).
    centre_of_buoyancy : array_like, shape (3,)
        ``r_b`` in the body frame, relative to the body origin (m).  z is down, so a centre of
        buoyancy above the centre of gravity has the smaller z.
    max_thrust : array_like, shape (6,), optional
        Symmetric bounds on the generalised force ``|X|, |Y|, |Z|`` (N) and ``|K|, |M|, |N|``
        (N·m), > 0.  May be omitted only if ``thrusters`` is given; it is then the largest pure
        force or moment on each axis the thrusters can produce
        (:meth:`ThrusterConfiguration.generalised_force_limits`).
    max_thrust_rate : array_like, shape (6,), optional
        Bounds on the rate of change of the generalised force (N/s, N·m/s), > 0.  ``None``
        means ``2 × max_thrust`` per second.
    name : str
        Label used in tables and plots.  Every number above is at most 1e9 in magnitude and the
        mass at least 1e-6 kg (plausibility bounds, ``ValueError`` outside).
    thrusters : ThrusterConfiguration, optional
        Thruster layout.  With it the control becomes the vector of thruster forces
        (:attr:`control_dim` is the number of thrusters, bounded by the thrusters' own
        ``max_thrust``), :attr:`allocation` gives ``T`` with ``τ = T f`` and
        :attr:`thruster_dynamics` is ``f(x, f, current)``.  :attr:`dynamics` still takes the
        generalised force ``τ``.  Thrusters with a first-order response
        (``ThrusterConfiguration.time_constant`` > 0) add their delivered forces ``f_a`` (N) to
        the state, between the pose and the velocities: ``[η, f_a, ν]``, ``ḟ_a = (f − f_a) / τ``,
        ``τ_gen = T f_a`` (:attr:`state_dim` 12 + n).

    Notes
    -----
    Matrices and vectors are stored as (nested) tuples, so a vehicle is hashable and equality
    compares parameter values.  :attr:`dynamics` is built on first use and cached on the
    instance; the cache is not part of equality, hashing or pickling.
    """

    mass: float
    inertia: npt.ArrayLike
    added_mass: npt.ArrayLike
    linear_damping: tuple[float, ...]
    quadratic_damping: tuple[float, ...]
    weight: float
    buoyancy: float
    centre_of_gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    centre_of_buoyancy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_thrust: tuple[float, ...] | None = None
    max_thrust_rate: tuple[float, ...] | None = None
    name: str = "vehicle6dof"
    thrusters: ThrusterConfiguration | None = None

    def __post_init__(self) -> None:
        """Validate every field, store arrays as tuples and fill in derived bounds."""
        set_field = object.__setattr__
        set_field(self, "mass", check.positive_float("mass", self.mass))

        inertia = _symmetric_matrix("inertia", self.inertia, 3)
        smallest = float(np.linalg.eigvalsh(inertia)[0])
        if smallest <= 0.0:
            raise ValueError(f"inertia must be positive definite, got smallest eigenvalue {smallest!r} kg·m²")
        set_field(self, "inertia", _matrix_tuple(inertia))

        added_mass = _symmetric_matrix("added_mass", self.added_mass, 6)
        smallest = float(np.linalg.eigvalsh(added_mass)[0])
        if smallest < -_SYMMETRY_TOLERANCE * max(1.0, float(np.max(np.abs(added_mass)))):
            raise ValueError(
                "added_mass must be positive semidefinite (give M_A as positive magnitudes, not "
                f"the negative derivatives X_u̇, ...), got smallest eigenvalue {smallest!r}"
            )
        set_field(self, "added_mass", _matrix_tuple(added_mass))

        for field in ("linear_damping", "quadratic_damping"):
            set_field(self, field, check.vector(field, getattr(self, field), 6, nonnegative=True))
        set_field(self, "weight", check.positive_float("weight", self.weight))
        set_field(self, "buoyancy", check.nonnegative_float("buoyancy", self.buoyancy))
        for field in ("centre_of_gravity", "centre_of_buoyancy"):
            set_field(self, field, check.vector(field, getattr(self, field), 3))

        if self.thrusters is not None and not isinstance(self.thrusters, ThrusterConfiguration):
            raise ValueError(f"thrusters must be a ThrusterConfiguration or None, got {self.thrusters!r}")
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a string, got {self.name!r}")

        check.plausible_parameter("mass", self.mass, "kg", minimum=check.SMALLEST_INERTIA)
        for field, unit in (
            ("inertia", "kg·m²"),
            ("added_mass", "kg, kg·m or kg·m²"),
            ("linear_damping", "N·s/m or N·m·s/rad"),
            ("quadratic_damping", "N·s²/m² or N·m·s²/rad²"),
            ("weight", "N"),
            ("buoyancy", "N"),
            ("centre_of_gravity", "m"),
            ("centre_of_buoyancy", "m"),
        ):
            value = getattr(self, field)
            entries = np.ravel(value).tolist() if not isinstance(value, float) else value
            check.plausible_parameter(field, entries, unit)
        mass_matrix = self.mass_matrix
        smallest = float(np.linalg.eigvalsh(mass_matrix)[0])
        if smallest <= _SYMMETRY_TOLERANCE * float(np.max(np.abs(mass_matrix))):
            raise ValueError(
                "mass matrix M = M_RB + M_A (from mass, inertia, centre_of_gravity and added_mass) "
                f"must be symmetric positive definite, got smallest eigenvalue {smallest!r}"
            )

        max_thrust = self.max_thrust
        if max_thrust is None:
            if self.thrusters is None:
                raise ValueError(
                    "max_thrust must be 6 numbers > 0 (N, N, N, N·m, N·m, N·m), got None; it may be "
                    "omitted only when thrusters are given"
                )
            max_thrust = self.thrusters.generalised_force_limits()
            weak = [label for label, limit in zip(FORCE_NAMES, max_thrust, strict=True) if limit <= 0.0]
            if weak:
                raise ValueError(
                    f"max_thrust cannot be derived from thrusters {self.thrusters.name!r}: they "
                    f"produce no pure {', '.join(weak)}; give max_thrust explicitly"
                )
        limits = check.vector("max_thrust", max_thrust, FORCE_DIM, positive=True)
        check.plausible_parameter("max_thrust", limits, "N or N·m")
        set_field(self, "max_thrust", limits)
        if self.max_thrust_rate is None:
            set_field(self, "max_thrust_rate", tuple(2.0 * limit for limit in limits))
        else:
            rates = check.vector("max_thrust_rate", self.max_thrust_rate, FORCE_DIM, positive=True)
            check.plausible_parameter("max_thrust_rate", rates, "N/s or N·m/s")
            set_field(self, "max_thrust_rate", rates)

    def __getstate__(self) -> dict:
        """Pickle the parameters only; cached CasADi Functions are rebuilt on demand."""
        return {key: value for key, value in self.__dict__.items() if key not in _CACHED}

    # ------------------------------------------------------------------ presets
    @classmethod
    def bluerov2_heavy(cls, *, thrusters: bool = False, water_density: float = 1026.0) -> Vehicle6DOF:
        """Build the BlueROV2 Heavy (Blue Robotics) after von Benzon et al. (2022).

        Reference: M. von Benzon, F. F. Sørensen, E. Uth, J. Jouffroy, J. Liniger,
        S. Pedersen, "An Open-Source Benchmark Simulator: Control of a BlueROV2 Underwater
        Robot", J. Mar. Sci. Eng. 10(12), 1898 (2022), doi:10.3390/jmse10121898.  The paper's
        tables could not be read directly; every number below was taken from two independent
        code transcriptions that cite it, and agrees between them unless noted:
        ``RESULTS/Util/BlueROV2_param.m`` of GitHub ``AndreasKing-Goks/0_THESIS`` (cites the
        paper) and a MATLAB script headed "BlueROV2 Heavy Configuration Specifications".

        - mass 13.5 kg; inertia ``diag(0.26, 0.23, 0.37)`` kg·m² (no products of inertia);
          ``r_g = (0, 0, 0)``, ``r_b = (0, 0, −0.01)`` m (buoyancy 1 cm above gravity);
          displaced volume 0.0134 m³.
        - added mass ``(X_u̇, Y_v̇, Z_ẇ, K_ṗ, M_q̇, N_ṙ) = (6.36, 7.12, 18.68, 0.189, 0.135,
          0.222)``.  The thesis file gives 6.3567, 7.1206, 18.6863, 0.1858, 0.1348, 0.2215: the
          same values to rounding except ``K_ṗ`` (0.1858 against 0.189), which is unresolved;
          0.189 is used.
        - linear damping ``(13.7, 0, 33.0, 0, 0.8, 0)`` and quadratic damping
          ``(141, 217, 190, 1.19, 0.47, 1.5)`` (both sources; the thesis has 1.192 for roll).
        - W = m g with g = 9.81 m/s²; B = ρ g ∇ with ``water_density`` ρ.  The sources differ
          on ρ (1000, 999.7 and 1028 kg/m³); the default 1026 kg/m³ is sea water, which makes
          the vehicle about 2.4 N buoyant (with ρ = 1000 it is 1.0 N heavy).
        - Generalised-force bounds ``max_thrust``: the largest pure force or moment per axis
          that the eight 40 N thrusters of :meth:`ThrusterConfiguration.bluerov2_heavy` can
          produce, about ``(113.1, 113.1, 160, 34.9, 19.2, 30.2)`` N / N·m.
          ``max_thrust_rate = 2 × max_thrust`` per second (a convention, not a measurement).

        Parameters
        ----------
        thrusters : bool
            If True the vehicle carries :meth:`ThrusterConfiguration.bluerov2_heavy` and its
            control is the vector of the eight thruster forces (N).
        water_density : float
            Water density ρ (kg/m³) for the buoyancy, > 0.
        """
        layout = ThrusterConfiguration.bluerov2_heavy()
        rho = check.positive_float("water_density", water_density)
        mass = 13.5
        return cls(
            mass=mass,
            inertia=(0.26, 0.23, 0.37),
            added_mass=(6.36, 7.12, 18.68, 0.189, 0.135, 0.222),
            linear_damping=(13.7, 0.0, 33.0, 0.0, 0.8, 0.0),
            quadratic_damping=(141.0, 217.0, 190.0, 1.19, 0.47, 1.5),
            weight=mass * GRAVITY,
            buoyancy=rho * GRAVITY * 0.0134,
            centre_of_gravity=(0.0, 0.0, 0.0),
            centre_of_buoyancy=(0.0, 0.0, -0.01),
            max_thrust=layout.generalised_force_limits(),
            max_thrust_rate=None,
            name="bluerov2-heavy",
            thrusters=layout if check.boolean("thrusters", thrusters) else None,
        )

    @classmethod
    def rexrov2(cls, *, thrusters: bool = False) -> Vehicle6DOF:
        """Build uuv_simulator's RexROV2, full 6-DOF model, in Fossen's body frame.

        Source: ``rexrov2_control/config/model_params_exact.yaml`` of GitHub
        ``uuvsimulator/rexrov2`` (the same numbers as ``rexrov2_description/urdf/
        rexrov2.gazebo.xacro`` and ``rexrov2_base.xacro``, which cite Berg 2012):

        - mass 1862.87 kg; inertia ``ixx 525.39, iyy 794.2, izz 691.23, ixy 1.44, ixz 33.41,
          iyz 2.6`` kg·m² (URDF tensor entries) about the origin; ``cog = (0, 0, 0)``;
          ``cob = (0, 0, 0.3)`` m (ENU convention); volume 1.83826 m³; density 1028 kg/m³.
        - the full 6×6 added-mass matrix ``Ma`` (positive, as the simulator uses it).  It is
          symmetric except ``Ma[2][5] = 10.774`` against ``Ma[5][2] = 10.775``; the mean is used.
          ``M_A`` and ``M`` are positive definite (smallest eigenvalue of ``M_A`` about 220).
        - linear damping ``(74.82, 69.48, 728.4, 268.8, 309.77, 105)`` and quadratic damping
          ``(748.22, 992.53, 1821.01, 672, 774.44, 523.27)``: the yaml lists them negated
          (Gazebo convention), magnitudes here.

        The simulator's body frame is ROS ``base_link`` (x forward, y port, z up); Fossen's is x
        forward, y starboard, z down.  The change ``P = diag(1, −1, −1)`` (``diag(P, P)`` on
        6-vectors) is applied: ``I_o = P I P``, ``M_A = P₆ Ma P₆`` (flipping the sign of the
        couplings between {x, roll} and {y, z, pitch, yaw}), ``r_b = (0, 0, −0.3)`` m.
        W = m g and B = ρ g ∇ with g = 9.81 m/s² (B − W ≈ 264 N: slightly buoyant).

        Generalised-force bounds ``max_thrust``: the largest pure force or moment per axis that
        the six 1540 N thrusters of :meth:`ThrusterConfiguration.rexrov2` can produce (bound
        from ``rexrov2_control/config/thruster_manager.yaml``); ``max_thrust_rate = 2 ×
        max_thrust`` per second (a convention).

        Parameters
        ----------
        thrusters : bool
            If True the vehicle carries :meth:`ThrusterConfiguration.rexrov2` and its control is
            the vector of the six thruster forces (N).
        """
        inertia_ros = np.array([[525.39, 1.44, 33.41], [1.44, 794.2, 2.6], [33.41, 2.6, 691.23]])
        added_mass_ros = np.array(
            [
                [779.79, -6.8773, -103.32, 8.5426, -165.54, -7.8033],
                [-6.8773, 1222.0, 51.29, 409.44, -5.8488, 62.726],
                [-103.32, 51.29, 3659.9, 6.1112, -386.42, 10.774],
                [8.5426, 409.44, 6.1112, 534.9, -10.027, 21.019],
                [-165.54, -5.8488, -386.42, -10.027, 842.69, -1.1162],
                [-7.8033, 62.726, 10.775, 21.019, -1.1162, 224.32],
            ]
        )
        added_mass_ros = 0.5 * (added_mass_ros + added_mass_ros.T)
        flip3 = np.diag([1.0, -1.0, -1.0])
        flip6 = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])
        layout = ThrusterConfiguration.rexrov2()
        mass, volume, density = 1862.87, 1.83826, 1028.0
        return cls(
            mass=mass,
            inertia=flip3 @ inertia_ros @ flip3,
            added_mass=flip6 @ added_mass_ros @ flip6,
            linear_damping=(74.82, 69.48, 728.4, 268.8, 309.77, 105.0),
            quadratic_damping=(748.22, 992.53, 1821.01, 672.0, 774.44, 523.27),
            weight=mass * GRAVITY,
            buoyancy=density * GRAVITY * volume,
            centre_of_gravity=(0.0, 0.0, 0.0),
            centre_of_buoyancy=(0.0, 0.0, -0.3),
            max_thrust=layout.generalised_force_limits(),
            max_thrust_rate=None,
            name="rexrov2",
            thrusters=layout if check.boolean("thrusters", thrusters) else None,
        )

    # --------------------------------------------------------------- dimensions
    @property
    def response_dim(self) -> int:
        """Number of delivered-thrust states: n with a thruster response, else 0."""
        return self.thrusters.count if self.thrusters is not None and self.thrusters.responds else 0

    @property
    def state_dim(self) -> int:
        """Length of the state vector (12, or 12 + n with a thruster response)."""
        return STATE_DIM + self.response_dim

    @property
    def control_dim(self) -> int:
        """Length of the control: 6 (generalised force) or the number of thrusters."""
        return FORCE_DIM if self.thrusters is None else self.thrusters.count

    @property
    def current_dim(self) -> int:
        """Length of the current vector ``[V_x, V_y, V_z]`` (3)."""
        return CURRENT_DIM

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the state components (``f_a1, ...`` after the pose with a thruster response)."""
        delivered = tuple(f"f_a{index + 1}" for index in range(self.response_dim))
        return STATE_NAMES[:6] + delivered + STATE_NAMES[6:]

    @property
    def state_units(self) -> tuple[str, ...]:
        """Units of the state components."""
        return STATE_UNITS[:6] + ("N",) * self.response_dim + STATE_UNITS[6:]

    @property
    def control_names(self) -> tuple[str, ...]:
        """``("X", "Y", "Z", "K", "M", "N")``, or ``("f_1", ..., "f_n")`` with thrusters."""
        if self.thrusters is None:
            return FORCE_NAMES
        return tuple(f"f_{index + 1}" for index in range(self.thrusters.count))

    @property
    def control_units(self) -> tuple[str, ...]:
        """Units of the control components."""
        if self.thrusters is None:
            return FORCE_UNITS
        return ("N",) * self.thrusters.count

    @cached_property  # read on every parameters() call of a closed loop: built once
    def layout(self) -> VehicleLayout:
        """State ``[η, f_a, ν]`` (``f_a`` only with a thruster response), controls, spatial references."""
        nx = self.state_dim
        return VehicleLayout(
            state_names=self.state_names,
            state_units=self.state_units,
            control_names=self.control_names,
            control_units=self.control_units,
            positions=(0, 1, 2),
            angles=(3, 4, 5),
            heading=5,
            velocities=tuple(range(nx - 6, nx)),
            current_dim=CURRENT_DIM,
            reference="spatial",
        )

    def model_function(self) -> ca.Function:
        """Return the dynamics in the vehicle's controls (thruster forces with thrusters, else τ)."""
        return self.thruster_dynamics if self.thrusters is not None else self.dynamics

    @property
    def model_parameters(self) -> tuple[ModelParameter, ...]:
        """With thrusters, ``health`` and ``thrust_offset`` (n each); without, none.

        ``health`` h ∈ [0, 1]^n is each thruster's effectiveness (default 1) and
        ``thrust_offset`` s (N, within ±max_thrust, default 0) a known force a thruster delivers
        whatever its command: the model's generalised force is ``τ = T (h ∘ f + s)``
        (:attr:`faulty_thruster_dynamics`).  A thruster that lost effectiveness has
        ``0 < h_i < 1``; a failed one ``h_i = 0``; one stuck at force ``v`` ``h_i = 0`` and
        ``s_i = v``.  A :class:`~uuv_ocp.TrackingProblem` makes them parameters of its Ocp:
        the controller is told a fault with ``parameters={"health": h, "thrust_offset": s}``,
        without a rebuild.
        """
        if self.thrusters is None:
            return ()
        count, bounds = self.thrusters.count, self.thrusters.max_thrust
        return (
            ModelParameter("health", count, (1.0,) * count, (0.0,) * count, (1.0,) * count, "1"),
            ModelParameter("thrust_offset", count, (0.0,) * count, tuple(-b for b in bounds), bounds, "N"),
        )

    def parametric_model_function(self) -> ca.Function:
        """Return :attr:`faulty_thruster_dynamics` (the dynamics of :attr:`model_parameters`).

        Raises
        ------
        AttributeError
            If the vehicle has no thrusters (it declares no model parameters).
        """
        return self.faulty_thruster_dynamics

    @property
    def control_bound(self) -> tuple[float, ...]:
        """Symmetric bound on each control component: ``max_thrust`` or the thrusters' bounds."""
        if self.thrusters is None:
            return cast("tuple[float, ...]", self.max_thrust)
        return self.thrusters.max_thrust

    @property
    def control_rate_bound(self) -> tuple[float, ...]:
        """Bound on each control component's rate (per second).

        ``max_thrust_rate`` for the generalised force; with thrusters ``2 × max_thrust`` of each
        thruster per second (the same convention as the default ``max_thrust_rate``).
        """
        if self.thrusters is None:
            return cast("tuple[float, ...]", self.max_thrust_rate)
        return tuple(2.0 * limit for limit in self.thrusters.max_thrust)

    # ----------------------------------------------------------------- matrices
    @property
    def inertia_matrix(self) -> np.ndarray:
        """Rigid-body inertia ``I_o`` about the origin, shape (3, 3) (kg·m²)."""
        return np.array(self.inertia)

    @property
    def rigid_body_mass_matrix(self) -> np.ndarray:
        """``M_RB = [[m I₃, −m S(r_g)], [m S(r_g), I_o]]``, shape (6, 6) (Fossen 2011 eq. 3.44)."""
        skew_rg = _skew_numpy(np.array(self.centre_of_gravity))
        return np.block(
            [
                [self.mass * np.eye(3), -self.mass * skew_rg],
                [self.mass * skew_rg, np.array(self.inertia)],
            ]
        )

    @property
    def added_mass_matrix(self) -> np.ndarray:
        """Added-mass matrix ``M_A`` (positive magnitudes), shape (6, 6)."""
        return np.array(self.added_mass)

    @property
    def mass_matrix(self) -> np.ndarray:
        """``M = M_RB + M_A``, shape (6, 6), symmetric positive definite."""
        return self.rigid_body_mass_matrix + self.added_mass_matrix

    @property
    def allocation(self) -> np.ndarray:
        """Thrust-allocation matrix ``T`` (6 × n) with ``τ = T f``; needs ``thrusters``.

        Raises
        ------
        AttributeError
            If the vehicle has no thrusters.
        """
        if self.thrusters is None:
            raise AttributeError(f"vehicle {self.name!r} has no thrusters, so no allocation matrix")
        return self.thrusters.allocation

    # ------------------------------------------------------------ top speeds
    def max_speed(self) -> np.ndarray:
        """Steady-state top speed on each axis alone under full force, no current (m/s, rad/s).

        Solves ``d_lin s + d_quad s² = max_thrust`` for each of the six axes, as
        ``2 τ_max / (d_lin + sqrt(d_lin² + 4 d_quad τ_max))`` (``inf`` without damping), like
        the 3-DOF :meth:`Vehicle.max_speed <uuv_ocp.model.planar.Vehicle.max_speed>`.  In pure
        motion along or about one axis the Coriolis terms put no force on that axis, so this is
        the exact on-axis balance; the restoring force (heave: weight minus buoyancy) is not
        counted.

        Returns
        -------
        numpy.ndarray, shape (6,)
            ``(u, v, w)`` in m/s and ``(p, q, r)`` in rad/s.
        """
        return steady_speed(self.linear_damping, self.quadratic_damping, self.max_thrust)

    def max_horizontal_speed(self, resolution: int = 9001) -> tuple[float, float]:
        """Top speed over ground at constant depth in still water, crabbing allowed: ``(m/s, rad)``.

        Level, straight, steady motion at speed ``s`` with crab angle ``β`` (body velocity
        ``ν = s (cos β, sin β, 0, 0, 0, 0)``, zero roll and pitch) needs the generalised force
        ``τ(s) = C(ν)ν + D(ν)ν + g(0, 0)`` of this model (Coriolis with the Munk moment, damping,
        and the restoring force that holds depth and attitude).  Each component is a quadratic
        in ``s``; for each β on a grid of ``resolution`` angles in ``[−π/2, π/2]`` the largest
        ``s`` with ``|τ_i(s)| <= max_thrust_i`` for every axis up to it is found from the roots,
        and the result is the best β.  The 3-DOF :meth:`Vehicle.max_horizontal_speed
        <uuv_ocp.model.planar.Vehicle.max_horizontal_speed>` is the planar case of the same
        balance.

        With ``thrusters`` the bound is the box ``max_thrust`` of the largest pure force per
        axis; the thrusters may not deliver two of them at once, so the figure can be higher
        than what they reach while crabbing (a reference faster than it is out of reach).

        Parameters
        ----------
        resolution : int
            Number of crab angles, >= 2.

        Returns
        -------
        tuple of float
            The top speed (m/s; 0 if the vehicle cannot even hold depth at rest) and its crab
            angle β (rad, positive to starboard).
        """
        resolution = check.positive_int("resolution", resolution, minimum=2)
        angles = np.linspace(-0.5 * np.pi, 0.5 * np.pi, resolution)
        coefficients = _steady_force_coefficients(self, angles)  # (3, 6, resolution): c, b, a
        limits = np.asarray(self.max_thrust, dtype=float)[:, None]
        constant, linear, quadratic = coefficients
        # the largest s before a component leaves [-limit, limit]: the first positive root of
        # τ_i(s) - limit (leaving through the top) or of -(τ_i(s) + limit) (through the bottom)
        upper = _first_positive_root(quadratic, linear, constant - limits)
        lower = _first_positive_root(-quadratic, -linear, -(constant + limits))
        speed = np.min(np.minimum(upper, lower), axis=0)
        speed = np.where(np.any(np.abs(constant) > limits, axis=0), 0.0, speed)
        best = int(np.argmax(speed))
        return float(speed[best]), float(angles[best])

    # ------------------------------------------------------------ model terms
    def rigid_body_coriolis_matrix(self, nu):
        """``C_RB(ν)``, independent of the linear velocity (Fossen 2011 eq. 3.60).

        Parameters
        ----------
        nu : casadi.SX, MX or DM, shape (6,)
            Body velocity ``[u, v, w, p, q, r]`` (m/s, rad/s).

        Returns
        -------
        casadi.SX, MX or DM, shape (6, 6)
            Skew-symmetric matrix (N·s/m, ...).
        """
        nu = _column(nu, 6)
        omega = nu[3:6]
        skew_omega = _skew(omega)
        skew_rg = ca.DM(_skew_numpy(np.array(self.centre_of_gravity)))
        inertia = ca.DM(np.array(self.inertia))
        m = self.mass
        return ca.vertcat(
            ca.horzcat(m * skew_omega, -m * skew_omega @ skew_rg),
            ca.horzcat(m * skew_rg @ skew_omega, -_skew(inertia @ omega)),
        )

    def added_mass_coriolis_matrix(self, nu):
        """``C_A(ν)`` from the added-mass matrix (Fossen 2011 eq. 6.43).

        Parameters
        ----------
        nu : casadi.SX, MX or DM, shape (6,)
            Velocity relative to the water ``[u_r, v_r, w_r, p, q, r]`` (m/s, rad/s).

        Returns
        -------
        casadi.SX, MX or DM, shape (6, 6)
            Skew-symmetric matrix.
        """
        return mass_coriolis_matrix(np.array(self.added_mass), _column(nu, 6))

    def coriolis_matrix(self, nu):
        """``C(ν) = C_RB(ν) + C_A(ν)``, shape (6, 6); see the two terms."""
        return self.rigid_body_coriolis_matrix(nu) + self.added_mass_coriolis_matrix(nu)

    def damping_matrix(self, nu):
        """``D(ν) = diag(d_lin) + diag(d_quad) diag(|ν|)``, shape (6, 6).

        Parameters
        ----------
        nu : casadi.SX, MX or DM, shape (6,)
            Velocity relative to the water (m/s, rad/s).
        """
        nu = _column(nu, 6)
        linear = ca.DM(self.linear_damping)
        quadratic = ca.DM(self.quadratic_damping)
        return ca.diag(linear + quadratic * ca.fabs(nu))

    def restoring_force(self, phi, theta):
        """Restoring force ``g(η)`` of weight and buoyancy (Fossen 2011 eq. 4.6), shape (6,).

        Parameters
        ----------
        phi, theta : casadi.SX, MX or float
            Roll and pitch (rad); ``g`` does not depend on position or yaw.

        Returns
        -------
        casadi.SX, MX or DM, shape (6,)
            ``[X, Y, Z, K, M, N]`` on the left-hand side of the equations of motion (N, N·m):
            the force acting on the vehicle is ``−g(η)``.
        """
        w, b = self.weight, self.buoyancy
        xg, yg, zg = self.centre_of_gravity
        xb, yb, zb = self.centre_of_buoyancy
        cphi, sphi = ca.cos(phi), ca.sin(phi)
        cth, sth = ca.cos(theta), ca.sin(theta)
        return ca.vertcat(
            (w - b) * sth,
            -(w - b) * cth * sphi,
            -(w - b) * cth * cphi,
            -(yg * w - yb * b) * cth * cphi + (zg * w - zb * b) * cth * sphi,
            (zg * w - zb * b) * sth + (xg * w - xb * b) * cth * cphi,
            -(xg * w - xb * b) * cth * sphi - (yg * w - yb * b) * sth,
        )

    # ----------------------------------------------------------------- dynamics
    def dynamics_expression(self, state, control, current=None):
        """Continuous-time right-hand side ``ẋ = f(x, τ, V_c)`` as a CasADi expression.

        Parameters
        ----------
        state : casadi.SX or MX, shape (12,)
            ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]`` (m, rad, m/s, rad/s).  ``θ`` must stay away
            from ±90°, where the Euler-rate transform is singular.
        control : casadi.SX or MX, shape (6,)
            Generalised force ``[X, Y, Z, K, M, N]`` (N, N·m), even with thrusters.
        current : casadi.SX or MX, shape (3,), optional
            Inertial (NED) current velocity ``[V_x, V_y, V_z]`` (m/s); ``None`` means still
            water.

        Returns
        -------
        casadi.SX or MX, shape (12,)
            Time derivative of the state.
        """
        state = _column(state, STATE_DIM)
        control = _column(control, FORCE_DIM)
        phi, theta, psi = state[3], state[4], state[5]
        linear, angular = state[6:9], state[9:12]
        rotation = rotation_matrix(phi, theta, psi)
        if current is None:
            current_body = ca.DM.zeros(3, 1)
        else:
            current_body = rotation.T @ _column(current, CURRENT_DIM)
        nu_r = ca.vertcat(linear - current_body, angular)
        forces = (
            control
            - self.coriolis_matrix(nu_r) @ nu_r
            - self.damping_matrix(nu_r) @ nu_r
            - self.restoring_force(phi, theta)
        )
        nu_r_dot = ca.DM(np.linalg.inv(self.mass_matrix)) @ forces
        # d/dt (Rᵀ V_c) = −S(ω) Rᵀ V_c for a constant inertial current
        current_body_dot = -_skew(angular) @ current_body
        nu_dot = nu_r_dot + ca.vertcat(current_body_dot, ca.DM.zeros(3, 1))
        eta_dot = ca.vertcat(rotation @ linear, euler_rate_matrix(phi, theta) @ angular)
        return ca.vertcat(eta_dot, nu_dot)

    def rhs(self, state, control, current=None):
        """Alias of :meth:`dynamics_expression` (the 3-DOF model's ``dynamics(state, control, current)``)."""
        return self.dynamics_expression(state, control, current)

    @built_once  # not cached_property + serialised: lock-order inversion (uuv_ocp._concurrency)
    def dynamics(self) -> ca.Function:
        """``dynamics(x[12], tau[6], current[3]) -> xdot[12]`` as a CasADi Function (SX graph).

        Inputs are named ``"x"``, ``"tau"``, ``"current"`` and the output ``"xdot"``.  Built on
        first access and cached on the instance.
        """
        state = ca.SX.sym("x", STATE_DIM)
        control = ca.SX.sym("tau", FORCE_DIM)
        current = ca.SX.sym("current", CURRENT_DIM)
        return ca.Function(
            "dynamics",
            [state, control, current],
            [self.dynamics_expression(state, control, current)],
            ["x", "tau", "current"],
            ["xdot"],
        )

    def dynamics_function(self) -> ca.Function:
        """Return the cached :attr:`dynamics` Function (same call as the 3-DOF model's method)."""
        return self.dynamics

    def _responding(self, state, forces, generalised, current):
        """``ẋ`` of a thruster vehicle: ``generalised(f)`` drives the 12 rigid-body states.

        Without a response ``f`` is the command; with one it is the delivered ``f_a`` (the state
        block after the pose) and ``ḟ_a = (f − f_a) / τ`` joins the derivative.
        """
        n = self.response_dim
        if n == 0:
            return self.dynamics_expression(state, generalised(forces), current)
        body = ca.vertcat(state[:6], state[6 + n :])
        delivered = state[6 : 6 + n]
        rate = (forces - delivered) / ca.DM(self.thrusters.time_constant)  # type: ignore[union-attr]
        derivative = self.dynamics_expression(body, generalised(delivered), current)
        return ca.vertcat(derivative[:6], rate, derivative[6:])

    @built_once  # not cached_property + serialised: lock-order inversion (uuv_ocp._concurrency)
    def thruster_dynamics(self) -> ca.Function:
        """``thruster_dynamics(x[nx], f[n], current[3]) -> xdot[nx]`` with ``τ = T f`` (nx = state_dim).

        Inputs are named ``"x"``, ``"f"``, ``"current"`` and the output ``"xdot"``.

        Raises
        ------
        AttributeError
            If the vehicle has no thrusters.
        """
        allocation = ca.DM(self.allocation)
        state = ca.SX.sym("x", self.state_dim)
        forces = ca.SX.sym("f", allocation.shape[1])
        current = ca.SX.sym("current", CURRENT_DIM)
        return ca.Function(
            "thruster_dynamics",
            [state, forces, current],
            [self._responding(state, forces, lambda delivered: allocation @ delivered, current)],
            ["x", "f", "current"],
            ["xdot"],
        )

    @built_once  # not cached_property + serialised: lock-order inversion (uuv_ocp._concurrency)
    def faulty_thruster_dynamics(self) -> ca.Function:
        """``(x[nx], f[n], current[3], health[n], thrust_offset[n]) -> xdot[nx]``, ``τ = T (h ∘ f + s)``.

        Inputs are named ``"x"``, ``"f"``, ``"current"``, ``"health"``, ``"thrust_offset"``;
        equal to :attr:`thruster_dynamics` at ``health = 1``, ``thrust_offset = 0`` (see
        :attr:`model_parameters`).

        Raises
        ------
        AttributeError
            If the vehicle has no thrusters.
        """
        allocation = ca.DM(self.allocation)
        count = allocation.shape[1]
        state = ca.SX.sym("x", self.state_dim)
        forces = ca.SX.sym("f", count)
        current = ca.SX.sym("current", CURRENT_DIM)
        health = ca.SX.sym("health", count)
        offset = ca.SX.sym("thrust_offset", count)
        # the fault acts on what the thruster delivers (after its response, if it has one)
        return ca.Function(
            "faulty_thruster_dynamics",
            [state, forces, current, health, offset],
            [self._responding(state, forces, lambda f: allocation @ (health * f + offset), current)],
            ["x", "f", "current", "health", "thrust_offset"],
            ["xdot"],
        )


def _steady_force_coefficients(vehicle: Vehicle6DOF, angles: np.ndarray) -> np.ndarray:
    """Coefficients ``(c, b, a)`` of ``τ(s) = c + b s + a s²`` for level steady motion at crab angles.

    ``τ`` is the generalised force that holds ``ν = s (cos β, sin β, 0, 0, 0, 0)`` steady at zero
    roll and pitch, from the model's own terms; it is exactly quadratic in ``s >= 0`` (``|ν|`` is
    ``s |ν(1)|``), so its values at ``s = 0, 1, 2`` give the coefficients.  Shape (3, 6, len(angles)).
    """
    nu = ca.SX.sym("nu", 6)
    force = (
        vehicle.coriolis_matrix(nu) @ nu + vehicle.damping_matrix(nu) @ nu + vehicle.restoring_force(0.0, 0.0)
    )
    required = ca.Function("steady_force", [nu], [force])
    unit = np.zeros((6, angles.size))
    unit[0], unit[1] = np.cos(angles), np.sin(angles)
    batch = required.map(angles.size)
    at0, at1, at2 = (np.array(batch(speed * unit)) for speed in (0.0, 1.0, 2.0))
    quadratic = 0.5 * (at2 - 2.0 * at1 + at0)
    return np.stack([at0, at1 - at0 - quadratic, quadratic])


def _first_positive_root(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Smallest ``s > 0`` with ``a s² + b s + c = 0`` where ``c <= 0`` (``inf`` if none), elementwise.

    With ``c <= 0`` the polynomial starts at or below zero, so its first positive root is where
    it first becomes positive.  The roots are ``q / a`` and ``c / q`` with
    ``q = −(b + sign(b) sqrt(b² − 4ac)) / 2`` (no cancellation); ``a = 0`` leaves ``c / q``.
    """
    a, b, c = np.broadcast_arrays(*(np.asarray(value, dtype=float) for value in (a, b, c)))
    with np.errstate(divide="ignore", invalid="ignore"):
        discriminant = b**2 - 4.0 * a * c
        q = -0.5 * (b + np.where(b >= 0.0, 1.0, -1.0) * np.sqrt(np.maximum(discriminant, 0.0)))
        roots = np.stack([q / a, c / q])
    roots = np.where(np.isfinite(roots) & (roots > 0.0) & (discriminant >= 0.0), roots, np.inf)
    return np.min(roots, axis=0)
