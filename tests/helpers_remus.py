"""Independent numpy reference of the REMUS 100 AUV for the tests (no uuv_ocp code inside).

The model is Fossen's REMUS 100 of the Python Vehicle Simulator, followed term by term in plain
numpy so that a test comparing uuv_ocp's CasADi model with :func:`remus100_derivative` compares two
implementations of one published model:

- ``cybergalactic/PythonVehicleSimulator``, ``src/python_vehicle_simulator/vehicles/remus100.py``
  at commit ``7e1db8edeafed3bdb24874013dd9259a10fb19ff`` (class ``remus100``: ``__init__`` for the
  coefficients, ``dynamics`` for ν̇), see :data:`SOURCE`;
- the helpers it imports from ``python_vehicle_simulator.lib.gnc`` (``Smtrx``, ``Hmtrx``, ``m2c``,
  ``Hoerner``, ``crossFlowDrag``, ``forceLiftDrag``, ``gvect``, ``Rzyx``, ``Tzyx`` as used by
  ``attitudeEuler``), read from the stored ``src/python_vehicle_simulator/gnc.py`` at commit
  ``09495a839ca3dc1d4b7004a13fc845740756d606`` (the ``lib/`` copy was not in the index; every
  Python copy of these functions found there is the same).

The source cites Prestero (2001), Allen, Vorus and Prestero (2000, OCEANS, doi
10.1109/OCEANS.2000.882209) and Fossen (2021), *Handbook of Marine Craft Hydrodynamics and Motion
Control*, 2nd ed., Section 8.4.2.  Nothing here imports uuv_ocp.

Where this reference departs from the source on purpose (nowhere in the equations):

- the source steps ν with forward Euler inside ``dynamics`` and steps the actuators with
  first-order lags; here only the instantaneous derivative given the *actual* actuator values is
  returned (the saturation the source applies to those values is kept, see
  :func:`remus100_derivative`);
- the source inverts ``M`` once with ``np.linalg.inv``; here ``np.linalg.solve`` is used
  (identical to rounding, ~1e-16 relative).

Other versions of "the" REMUS 100 model differ, so an implementation compared with this one must
follow the same file: older commits of remus100.py (e.g. 25b1e153) have ±30° fins, fin areas
0.10 × 0.05 m², T_yaw = 5 s with the exp(−3 U_r) factor on yaw too, four C_A entries zeroed, the
full K_prop in roll, pitch moment +x_s Z_s and a misplaced bracket in Lamb's β_0; MSS
``VESSELS/models/remus100.m`` (2025) scales a and b by 1.0096 (m = 31.9 kg), limits the fins to
±20°, uses gravity at 63.4° N and a cross-flow drag with heave and pitch terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.integrate import solve_ivp

SOURCE = (
    "cybergalactic/PythonVehicleSimulator src/python_vehicle_simulator/vehicles/remus100.py "
    "@ 7e1db8edeafed3bdb24874013dd9259a10fb19ff; gnc helpers from "
    "src/python_vehicle_simulator/gnc.py @ 09495a839ca3dc1d4b7004a13fc845740756d606"
)

# ----------------------------------------------------------------- published constants
RHO = 1026.0  # density of water (kg/m³), remus100.py `self.rho`; gnc.py uses 1026 too
GRAVITY = 9.81  # acceleration of gravity (m/s²), remus100.py `g`
LENGTH = 1.6  # length L (m), remus100.py `self.L`
DIAMETER = 0.19  # cylinder diameter (m), remus100.py `self.diam`

MAX_FIN = 15.0 * math.pi / 180.0  # rad; remus100.py `deltaMax_r = deltaMax_s = 15 * D2R`
MAX_RPM = 1525.0  # rpm; remus100.py `self.nMax = 1525  # max propeller revolution (rpm)`
FIN_TIME_CONSTANT = 0.1  # s; remus100.py `self.T_delta = 0.1  # rudder/stern plane time constant`
PROPELLER_TIME_CONSTANT = 1.0  # s; remus100.py `self.T_n = 1.0  # propeller time constant (s)`

# remus100.py module docstring: "The maximum speed of 2.5 m/s is obtained when the propeller
# runs at 1525 rpm in zero currents."  (Also in the source's Ja_max comment:
# "Ja_max = 0.944 * 2.5 / (0.14 * 1525/60) = 0.6632".)
STEADY_RPM = 1525.0  # rpm
STEADY_SPEED = 2.5  # m/s
STEADY_SPEED_QUOTE = (
    "The maximum speed of 2.5 m/s is obtained when the propeller runs at 1525 rpm in zero currents."
)

# Propeller (remus100.py `dynamics`): "D_prop = 0.14 # propeller diameter corresponding to
# 5.5 inches", "t_prop = 0.1 # thrust deduction number", "Va = 0.944 * U", and the
# Wageningen B-series values the source took from MSS `wageningen(Ja, 1, 0.718, 3)`.
PROP_DIAMETER = 0.14  # m
THRUST_DEDUCTION = 0.1  # -
WAKE_FACTOR = 0.944  # Va = 0.944 U (Allen et al. 2000)
JA_MAX = 0.6632  # advance number at 2.5 m/s and 1525 rpm
KT_0, KQ_0 = 0.4566, 0.0700  # wageningen(0, 1, 0.718, 3)
KT_MAX, KQ_MAX = 0.1798, 0.0312  # wageningen(0.6632, 1, 0.718, 3)
ROLL_TORQUE_SCALE = 0.1  # tau[3] = K_prop / 10, "scaled down by a factor of 10 to match exp. results"

# Fins (remus100.py `__init__`): S_fin = 0.00665 (fin area), rudder CL 0.5, stern plane CL 0.7,
# both areas 2 * S_fin, both at x = -a (the tail).
FIN_AREA = 0.00665  # m²
CL_RUDDER = 0.5
CL_STERN = 0.7

# Drag (remus100.py `__init__`): "Cd = 0.42 # from Allen et al. (2000)"; gnc.py forceLiftDrag's
# Oswald efficiency e = 0.7; Hoerner's 2-D cross-flow curve in gnc.py.
CD_AXIAL = 0.42
OSWALD = 0.7

# Low-speed linear damping (remus100.py `__init__`).
T_SURGE, T_SWAY, T_YAW = 20.0, 20.0, 1.0  # s (T_heave = T_sway)
ZETA_ROLL, ZETA_PITCH = 0.3, 0.8

# gnc.py Hoerner(B, T): digitised [B/2T, C_D] (Leite et al. 1998).
_HOERNER_X = (
    0.0109, 0.1766, 0.3530, 0.4519, 0.4728, 0.4929, 0.4933, 0.5585, 0.6464, 0.8336,
    0.9880, 1.3081, 1.6392, 1.8600, 2.3129, 2.6000, 3.0088, 3.4508, 3.7379, 4.0031,
)  # fmt: skip
_HOERNER_Y = (
    1.9661, 1.9657, 1.8976, 1.7872, 1.5837, 1.2786, 1.2108, 1.0836, 0.9986, 0.8796,
    0.8284, 0.7599, 0.6914, 0.6571, 0.6307, 0.5962, 0.5868, 0.5859, 0.5599, 0.5593,
)  # fmt: skip


# ------------------------------------------------------------------- gnc.py helpers
def skew(a) -> np.ndarray:
    """S(a) with S(a) b = a × b (gnc.py ``Smtrx``)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def transform_h(r) -> np.ndarray:
    """H(r) = [[I, S(r)ᵀ], [0, I]] (gnc.py ``Hmtrx``); M_CO = H(r_bg)ᵀ M_CG H(r_bg)."""
    h = np.eye(6)
    h[0:3, 3:6] = skew(r).T
    return h


def coriolis_from_mass(mass: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(ν) of a 6×6 mass matrix (gnc.py ``m2c``, Fossen 2021 Ch. 3), after symmetrising M."""
    m = 0.5 * (mass + mass.T)
    momentum_lin = m[0:3, 0:3] @ nu[0:3] + m[0:3, 3:6] @ nu[3:6]
    momentum_ang = m[3:6, 0:3] @ nu[0:3] + m[3:6, 3:6] @ nu[3:6]
    c = np.zeros((6, 6))
    c[0:3, 3:6] = -skew(momentum_lin)
    c[3:6, 0:3] = -skew(momentum_lin)
    c[3:6, 3:6] = -skew(momentum_ang)
    return c


def hoerner(beam: float, draft: float) -> float:
    """2-D cross-flow drag coefficient at B/(2T), linear interpolation (gnc.py ``Hoerner``)."""
    return float(np.interp(beam / (2.0 * draft), _HOERNER_X, _HOERNER_Y))


def cross_flow_drag(length: float, beam: float, draft: float, nu_r: np.ndarray) -> np.ndarray:
    """Strip-theory cross-flow drag [0, Y_h, 0, 0, 0, N_h] (N, N·m) (gnc.py ``crossFlowDrag``).

    As in the source: ``dx = L/20`` but the sum runs over the 21 stations x = −L/2, …, L/2
    (``for i in range(0, n+1)``), sway and yaw only, ρ = 1026 inside the function.
    """
    cd_2d = hoerner(beam, draft)
    dx = length / 20.0
    v_r, r = nu_r[1], nu_r[5]
    y_h = n_h = 0.0
    x = -length / 2.0
    for _ in range(21):
        flow = abs(v_r + x * r) * (v_r + x * r)
        y_h -= 0.5 * RHO * draft * cd_2d * flow * dx
        n_h -= 0.5 * RHO * draft * cd_2d * x * flow * dx
        x += dx  # accumulated as in the source, not i * dx
    return np.array([0.0, y_h, 0.0, 0.0, 0.0, n_h])


def lift_drag(span: float, area: float, cd_0: float, alpha: float, u_r: float) -> np.ndarray:
    """Hull lift and drag [X, 0, Z, 0, 0, 0] (N) from the angle of attack (gnc.py ``forceLiftDrag``).

    Beard and McLain (2012) wing model with linear lift (σ = 0): AR = b²/S,
    CL = π AR / (1 + √(1 + (AR/2)²)) α, CD = CD_0 + CL²/(π e AR), e = 0.7, rotated from flow to
    body axes by α.
    """
    aspect = span**2 / area
    cl = math.pi * aspect / (1.0 + math.sqrt(1.0 + (aspect / 2.0) ** 2)) * alpha
    cd = cd_0 + cl**2 / (math.pi * OSWALD * aspect)
    drag = 0.5 * RHO * u_r**2 * area * cd
    lift = 0.5 * RHO * u_r**2 * area * cl
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array([ca * (-drag) - sa * (-lift), 0.0, sa * (-drag) + ca * (-lift), 0.0, 0.0, 0.0])


def restoring(weight: float, buoyancy: float, theta: float, phi: float, r_bg, r_bb) -> np.ndarray:
    """g(η) of a submerged body about the CO (N, N·m) (gnc.py ``gvect``)."""
    sth, cth, sphi, cphi = math.sin(theta), math.cos(theta), math.sin(phi), math.cos(phi)
    wg = weight * np.asarray(r_bg, dtype=float) - buoyancy * np.asarray(r_bb, dtype=float)
    return np.array(
        [
            (weight - buoyancy) * sth,
            -(weight - buoyancy) * cth * sphi,
            -(weight - buoyancy) * cth * cphi,
            -wg[1] * cth * cphi + wg[2] * cth * sphi,
            wg[2] * sth + wg[0] * cth * cphi,
            -wg[0] * cth * sphi - wg[1] * sth,
        ]
    )


def rotation_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R(Θ) body → NED, zyx Euler angles (gnc.py ``Rzyx``)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth],
            [spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi],
            [-sth, cth * sphi, cth * cphi],
        ]
    )


def attitude_zyx(phi: float, theta: float) -> np.ndarray:
    """T(Θ) with Θ̇ = T(Θ) ω, zyx Euler angles, singular at θ = ±90° (gnc.py ``Tzyx``)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    return np.array(
        [[1.0, sphi * sth / cth, cphi * sth / cth], [0.0, cphi, -sphi], [0.0, sphi / cth, cphi / cth]]
    )


# -------------------------------------------------------------------- the vehicle
@dataclass(frozen=True)
class Remus100Matrices:
    """Constant quantities of remus100.py ``__init__`` (arrays are read-only).

    Attributes
    ----------
    mass : float
        Mass of the spheroid, m = 4/3 π ρ a b² (kg), a = L/2, b = diam/2.
    weight, buoyancy : float
        W = m g and B = W (N): neutrally buoyant, as in the source.
    r_bg, r_bb : numpy.ndarray
        CG [0, 0, 0.02] and CB [0, 0, 0] with respect to the CO (m).
    m_rb, m_a, m_total : numpy.ndarray
        Rigid-body mass in the CO, added mass diag(m k1, m k2, m k2, 0.3 I_x, k' I_y, k' I_y)
        (Lamb's k-factors of the prolate spheroid) and their sum (6×6, kg and kg·m²).
    damping : numpy.ndarray
        diag of the low-speed linear damping before the exp(−3 U_r) factor on surge and sway.
    area_s : float
        Planform area S = 0.7 L diam (m²), "S = 70% of rectangle L * diam".
    cd_0 : float
        Parasitic drag coefficient CD_0 = Cd π b² / S with Cd = 0.42 (-).
    """

    mass: float
    weight: float
    buoyancy: float
    r_bg: np.ndarray
    r_bb: np.ndarray
    m_rb: np.ndarray
    m_a: np.ndarray
    m_total: np.ndarray
    damping: np.ndarray
    area_s: float
    cd_0: float


@lru_cache(maxsize=1)
def remus100_matrices() -> Remus100Matrices:
    """Build the constant matrices of remus100.py ``__init__`` (cached, read-only arrays)."""
    a, b = LENGTH / 2.0, DIAMETER / 2.0
    area_s = 0.7 * LENGTH * DIAMETER  # "S = 70% of rectangle L * diam"
    cd_0 = CD_AXIAL * math.pi * b**2 / area_s
    r_bg = np.array([0.0, 0.0, 0.02])
    r_bb = np.zeros(3)

    mass = 4.0 / 3.0 * math.pi * RHO * a * b**2
    i_x = 2.0 / 5.0 * mass * b**2
    i_y = 1.0 / 5.0 * mass * (a**2 + b**2)
    h_rg = transform_h(r_bg)
    m_rb = h_rg.T @ np.diag([mass, mass, mass, i_x, i_y, i_y]) @ h_rg
    weight = mass * GRAVITY
    buoyancy = weight

    # Lamb's k-factors of a prolate spheroid (the source's 7e1db8ed form of beta_0: the log
    # multiplies, it does not divide as in older versions of the file).
    e = math.sqrt(1.0 - (b / a) ** 2)
    log_term = math.log((1.0 + e) / (1.0 - e))
    alpha_0 = 2.0 * (1.0 - e**2) / e**3 * (0.5 * log_term - e)
    beta_0 = 1.0 / e**2 - (1.0 - e**2) / (2.0 * e**3) * log_term
    k1 = alpha_0 / (2.0 - alpha_0)
    k2 = beta_0 / (2.0 - beta_0)
    k_prime = e**4 * (beta_0 - alpha_0) / ((2.0 - e**2) * (2.0 * e**2 - (2.0 - e**2) * (beta_0 - alpha_0)))
    m_a = np.diag([mass * k1, mass * k2, mass * k2, 0.3 * i_x, k_prime * i_y, k_prime * i_y])
    m_total = m_rb + m_a

    w_roll = math.sqrt(weight * (r_bg[2] - r_bb[2]) / m_total[3, 3])
    w_pitch = math.sqrt(weight * (r_bg[2] - r_bb[2]) / m_total[4, 4])
    damping = np.array(
        [
            m_total[0, 0] / T_SURGE,
            m_total[1, 1] / T_SWAY,
            m_total[2, 2] / T_SWAY,  # T_heave = T_sway
            m_total[3, 3] * 2.0 * ZETA_ROLL * w_roll,
            m_total[4, 4] * 2.0 * ZETA_PITCH * w_pitch,
            m_total[5, 5] / T_YAW,
        ]
    )
    for array in (r_bg, r_bb, m_rb, m_a, m_total, damping):
        array.setflags(write=False)
    return Remus100Matrices(mass, weight, buoyancy, r_bg, r_bb, m_rb, m_a, m_total, damping, area_s, cd_0)


def _propeller(n_rpm: float, speed: float) -> tuple[float, float]:
    """Thrust X_prop (N) and torque K_prop (N·m) before deduction/scaling (remus100.py).

    Linear K_T(J_a), K_Q(J_a) between J_a = 0 and J_a_max for forward thrust; J_a is not formed
    explicitly (the n in J_a = V_a/(n D) cancels one n of n|n|).  Reverse thrust uses K_T(0).
    """
    n_rps = n_rpm / 60.0
    d4, d5 = RHO * PROP_DIAMETER**4, RHO * PROP_DIAMETER**5
    if n_rps > 0.0:
        va_over_d = WAKE_FACTOR * speed / PROP_DIAMETER  # V_a / D, V_a = 0.944 U
        thrust = d4 * (KT_0 * abs(n_rps) * n_rps + (KT_MAX - KT_0) / JA_MAX * va_over_d * abs(n_rps))
        torque = d5 * (KQ_0 * abs(n_rps) * n_rps + (KQ_MAX - KQ_0) / JA_MAX * va_over_d * abs(n_rps))
    else:
        thrust = d4 * KT_0 * abs(n_rps) * n_rps
        torque = d5 * KQ_0 * abs(n_rps) * n_rps
    return thrust, torque


def _vector(value, size: int, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.shape != (size,):
        raise ValueError(f"{name}: expected a vector of {size} floats, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: expected finite values, got {array}")
    return array


def remus100_derivative(state, actuators, current=(0.0, 0.0)) -> np.ndarray:
    """State derivative of the REMUS 100 given the actual actuator values (remus100.py ``dynamics``).

    Parameters
    ----------
    state : array_like, shape (12,)
        ``[u, v, w, p, q, r, x, y, z, φ, θ, ψ]``: Fossen's ν (m/s, rad/s; body axes, *absolute*
        velocity over ground) then η (m in NED, z down; rad, zyx Euler angles).
    actuators : array_like, shape (3,)
        Actual ``[δ_r, δ_s, n]``: rudder (rad), stern plane (rad), propeller speed (rpm).  Values
        beyond ±:data:`MAX_FIN` / ±:data:`MAX_RPM` are clipped first, as the source does to
        ``u_actual`` ("Amplitude saturation of the control signals").  No actuator lag here.
    current : tuple of float
        ``(V_c, β_c)``: speed (m/s) and direction (rad, NED, from north towards east) of a
        horizontal, irrotational current.

    Returns
    -------
    numpy.ndarray, shape (12,)
        ``[ν̇, η̇]``.  Kinetics (source): with ν_c = [V_c cos(β_c − ψ), V_c sin(β_c − ψ), 0, 0, 0, 0]
        and ν_r = ν − ν_c, ``ν̇ = ν̇_c + M⁻¹ (τ + τ_liftdrag + τ_crossflow − (C(ν_r) + D(ν_r)) ν_r
        − g(η))`` where ν̇_c = [r v_c, −r u_c, 0, 0, 0, 0] (the source uses the yaw *rate* r, not
        ψ̇) and C = C_RB(ν_r) + C_A(ν_r) with the source's eight C_A entries zeroed.  Kinematics
        (source's ``attitudeEuler``): ``η̇ = [R(Θ) ν_1, T(Θ) ν_2]`` from the absolute ν: the
        current enters only through the kinetics.  The propeller's advance speed uses the
        absolute speed U = |ν_1| (source: ``Va = 0.944 * U``), the hydrodynamics the relative one.
    """
    state = _vector(state, 12, "state")
    delta_r, delta_s, n_rpm = _vector(actuators, 3, "actuators")
    v_c_speed, beta_c = _vector(current, 2, "current")
    mats = remus100_matrices()
    nu, eta = state[:6], state[6:]

    u_c = v_c_speed * math.cos(beta_c - eta[5])
    v_c = v_c_speed * math.sin(beta_c - eta[5])
    nu_r = nu - np.array([u_c, v_c, 0.0, 0.0, 0.0, 0.0])
    nu_c_dot = np.array([nu[5] * v_c, -nu[5] * u_c, 0.0, 0.0, 0.0, 0.0])
    alpha = math.atan2(nu_r[2], nu_r[0])
    speed = math.sqrt(nu[0] ** 2 + nu[1] ** 2 + nu[2] ** 2)
    speed_r = math.sqrt(nu_r[0] ** 2 + nu_r[1] ** 2 + nu_r[2] ** 2)

    delta_r = float(np.clip(delta_r, -MAX_FIN, MAX_FIN))
    delta_s = float(np.clip(delta_s, -MAX_FIN, MAX_FIN))
    n_rpm = float(np.clip(n_rpm, -MAX_RPM, MAX_RPM))
    x_prop, k_prop = _propeller(n_rpm, speed)

    c_a = coriolis_from_mass(mats.m_a, nu_r)
    # The source zeroes these added-mass Coriolis terms ("can destabilize the model if quadratic
    # rotational damping is missing"): pitching terms and the Munk moment in yaw.
    for i, j in ((4, 0), (0, 4), (4, 2), (2, 4), (5, 0), (0, 5), (5, 1), (1, 5)):
        c_a[i, j] = 0.0
    coriolis = coriolis_from_mass(mats.m_rb, nu_r) + c_a

    damping = np.array(mats.damping)
    damping[0:2] *= math.exp(-3.0 * speed_r)  # linear surge/sway damping vanishes at speed
    tau_liftdrag = lift_drag(DIAMETER, mats.area_s, mats.cd_0, alpha, speed_r)
    tau_crossflow = cross_flow_drag(LENGTH, DIAMETER, DIAMETER, nu_r)
    g_eta = restoring(mats.weight, mats.buoyancy, eta[4], eta[3], mats.r_bg, mats.r_bb)

    u_rh2 = nu_r[0] ** 2 + nu_r[1] ** 2  # horizontal-plane relative speed squared
    u_rv2 = nu_r[0] ** 2 + nu_r[2] ** 2  # vertical-plane relative speed squared
    fin = 2.0 * FIN_AREA
    x_r = -0.5 * RHO * u_rh2 * fin * CL_RUDDER * delta_r**2
    x_s = -0.5 * RHO * u_rv2 * fin * CL_STERN * delta_s**2
    y_r = -0.5 * RHO * u_rh2 * fin * CL_RUDDER * delta_r
    z_s = -0.5 * RHO * u_rv2 * fin * CL_STERN * delta_s
    x_fin = -LENGTH / 2.0  # rudder and stern planes at x = −a
    tau = np.array(
        [
            (1.0 - THRUST_DEDUCTION) * x_prop + x_r + x_s,
            y_r,
            z_s,
            ROLL_TORQUE_SCALE * k_prop,
            -x_fin * z_s,
            x_fin * y_r,
        ]
    )

    forces = tau + tau_liftdrag + tau_crossflow - coriolis @ nu_r - damping * nu_r - g_eta
    nu_dot = nu_c_dot + np.linalg.solve(mats.m_total, forces)
    eta_dot = np.concatenate(
        [
            rotation_zyx(eta[3], eta[4], eta[5]) @ nu[0:3],
            attitude_zyx(eta[3], eta[4]) @ nu[3:6],
        ]
    )
    return np.concatenate([nu_dot, eta_dot])


def remus100_steady_speed(
    n_rpm: float, *, tol: float = 1e-10, settle: float = 1e-9, chunk: float = 20.0, t_max: float = 2000.0
) -> float:
    """Settled surge speed u (m/s) of a straight run from rest at constant propeller speed.

    Integrates :func:`remus100_derivative` with scipy's DOP853 (rtol = atol = ``tol``), fins at
    zero, no current, in chunks of ``chunk`` s until |u̇| < ``settle`` m/s² and u moved less than
    ``settle`` m/s over the last chunk; raises ``RuntimeError`` if that has not happened by
    ``t_max`` s.
    """
    if not np.isfinite(n_rpm):
        raise ValueError(f"n_rpm: expected a finite propeller speed in rpm, got {n_rpm!r}")
    actuators = np.array([0.0, 0.0, float(n_rpm)])
    x = np.zeros(12)
    t = 0.0
    while t < t_max:
        solution = solve_ivp(
            lambda _t, y: remus100_derivative(y, actuators),
            (0.0, chunk),
            x,
            method="DOP853",
            rtol=tol,
            atol=tol,
        )
        if not solution.success:
            raise RuntimeError(f"solve_ivp failed at t = {t} s: {solution.message}")
        previous, x = x, solution.y[:, -1]
        t += chunk
        if abs(x[0] - previous[0]) < settle and abs(remus100_derivative(x, actuators)[0]) < settle:
            return float(x[0])
    raise RuntimeError(f"surge speed not settled within {t_max} s at n = {n_rpm} rpm (u = {x[0]})")
