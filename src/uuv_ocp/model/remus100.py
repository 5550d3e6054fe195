r"""The REMUS 100 AUV: a torpedo steered by a rudder and stern planes, driven by one propeller.

The model is the one of Fossen's Python Vehicle Simulator, ``remus100.py`` (GitHub
``cybergalactic/PythonVehicleSimulator``, ``src/python_vehicle_simulator/vehicles/remus100.py``
at commit ``7e1db8edeafed3bdb24874013dd9259a10fb19ff``, with the helper functions ``m2c``,
``Hmtrx``, ``gvect``, ``crossFlowDrag``, ``Hoerner`` and ``forceLiftDrag`` of its ``gnc.py``),
which follows

* T. I. Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed., Wiley,
  2021, §8.4.2 (the cylinder-shaped AUV: spheroid mass and Lamb's k-factors, lift and drag,
  cross-flow drag) — "Fossen 2021" below;
* B. Allen, W. S. Vorus, T. Prestero, "Propulsion system performance enhancements on REMUS
  AUVs", OCEANS 2000 MTS/IEEE, pp. 1869-1873, doi:10.1109/OCEANS.2000.882209 (hull drag
  coefficient, propeller, wake) — "Allen et al. 2000";
* T. Prestero, *Verification of a six-degree of freedom simulation model for the REMUS
  autonomous underwater vehicle*, MSc thesis, MIT/WHOI, 2001 (the vehicle's geometry: 1.6 m
  long, 19 cm diameter; the fin layout).

Every number below is the source file's; where the file says where a number comes from, that
is repeated.  The source calls the vehicle "1.6 m long, 19 cm diameter, 31.9 kg" and states
that "the maximum speed of 2.5 m/s is obtained when the propeller runs at 1525 rpm in zero
currents" (its module docstring, and ``Ja_max = 0.944 * 2.5 / (0.14 * 1525/60)``).

State and controls
------------------
State ``x = [x, y, z, φ, θ, ψ, u, v, w, p, q, r]``, the package's 6-DOF order (pose first, as
:class:`~uuv_ocp.model.fossen6dof.Vehicle6DOF`; Fossen's ``[ν, η]`` reordered): NED position
(m), ZYX Euler angles (rad), body velocities (m/s) and rates (rad/s) about the body origin CO
(the centre of buoyancy; the centre of gravity is 2 cm below it).  Controls ``[δ_r, δ_s, n]``:
rudder angle (rad), stern-plane angle (rad), propeller speed (rpm) — the actuator commands.
Current ``V_c = [V_x, V_y, V_z]``: constant water velocity in NED (m/s), the package's 6-DOF
convention.

Equations (the source's ``dynamics``; Fossen 2021 eq. 10.139 with relative velocity)
----------------------------------------------------------------------------------------
With ``ν_c = [R_z(ψ)ᵀ V_c; 0, 0, 0]`` — the current is rotated by the heading only, as in the
source (``u_c = V cos(β_c − ψ)``, ``v_c = V sin(β_c − ψ)``); ``V_z`` enters as ``w_c`` unrotated
(the source has no vertical current, so ``V_z = 0`` is the published model) — and
``ν_r = ν − ν_c``::

    ν̇ = [r v_c, −r u_c, 0, 0, 0, 0]ᵀ + M⁻¹ (τ + τ_liftdrag + τ_crossflow − (C(ν_r) + D(ν_r)) ν_r − g(η))
    η̇ = J(Θ) ν

* ``M = M_RB + M_A``: ``M_RB = H(r_g)ᵀ diag(m, m, m, I_x, I_y, I_z) H(r_g)`` (the spheroid's
  mass ``m = 4/3 π ρ a b²`` with ``a = L/2``, ``b = D/2``; ``I_x = 2/5 m b²``,
  ``I_y = I_z = 1/5 m (a² + b²)``); ``M_A = diag(m k₁, m k₂, m k₂, 0.3 I_x, k' I_y, k' I_y)``
  with Lamb's k-factors of the prolate spheroid (Fossen 2021 §8.4.2).
* ``C = C_RB(ν_r) + C_A(ν_r)`` both from ``m2c`` (Fossen 2021 eq. 3.60/6.43), with the
  added-mass entries ``C_A[4,0], C_A[0,4], C_A[4,2], C_A[2,4], C_A[5,0], C_A[0,5], C_A[5,1],
  C_A[1,5]`` set to zero (the source: "CA-terms in roll, pitch and yaw can destabilize the
  model if quadratic rotational damping is missing"; this removes the Munk moment).
* ``D = diag(M₁₁/T_surge e^{−3U_r}, M₂₂/T_sway e^{−3U_r}, M₃₃/T_heave, 2ζ_roll ω_roll M₄₄,
  2ζ_pitch ω_pitch M₅₅, M₆₆/T_yaw)``, ``ω = √(W z_g / M₄₄)`` (roll), ``√(W z_g / M₅₅)`` (pitch):
  linear low-speed damping whose surge and sway terms vanish at speed.
* ``τ_liftdrag``: the hull as a wing of span ``D`` and area ``S = 0.7 L D`` at the angle of
  attack ``α = atan2(w_r, u_r)``: ``C_L = C_Lα α`` with ``C_Lα = π AR / (1 + √(1 + (AR/2)²))``,
  ``AR = D²/S``; ``C_D = C_D0 + C_L² / (π e AR)``, ``e = 0.7``; ``C_D0 = C_d π (D/2)² / S`` with
  the axial drag coefficient ``C_d = 0.42`` (Allen et al. 2000); forces ``½ ρ U_r² S C``
  rotated from flow to body axes (``forceLiftDrag``, after Beard and McLain 2012).  This is the
  axial drag of the hull.
* ``τ_crossflow``: strip theory over 21 stations ``x = −L/2 … L/2`` (spacing ``L/20``) with the
  2-D drag coefficient of Hoerner's curve at ``B/2T = 0.5`` (``crossFlowDrag``, ``Hoerner``):
  sway force and yaw moment from ``|v_r + x r| (v_r + x r)``.
* ``g(η)``: weight = buoyancy ``W = B = m g``, ``r_g = (0, 0, 0.02)`` m, ``r_b = 0``
  (``gvect``, Fossen 2021 eq. 4.6).
* ``τ``: fins at ``x_r = x_s = −L/2``, area ``A_r = A_s = 2 × 0.00665`` m², lift slopes
  ``C_Lδ,r = 0.5``, ``C_Lδ,s = 0.7``, with the horizontal and vertical relative speeds
  ``U_rh² = u_r² + v_r²``, ``U_rv² = u_r² + w_r²``: ``Y_r = −½ρ U_rh² A_r C_Lδ,r δ_r``,
  ``Z_s = −½ρ U_rv² A_s C_Lδ,s δ_s``, fin drag ``X_r = −½ρ U_rh² A_r C_Lδ,r δ_r²`` (and
  ``X_s``), moments ``M = −x_s Z_s``, ``N = x_r Y_r``.  Propeller (Allen et al. 2000; the
  source's linearised Wageningen B-series, 3 blades, blade-area ratio 0.718, diameter 0.14 m):
  with ``n_s = n/60`` (rev/s) and the advance speed ``V_a = 0.944 U`` (wake fraction 0.056,
  ``U = |ν₁|`` the speed over ground, as in the source),
  ``X_p = ρ D_p⁴ (K_T0 |n_s| n_s + (K_Tmax − K_T0)/J_max (V_a/D_p) max(n_s, 0))``,
  ``K_p = ρ D_p⁵ (K_Q0 |n_s| n_s + (K_Qmax − K_Q0)/J_max (V_a/D_p) max(n_s, 0))`` with
  ``K_T0 = 0.4566``, ``K_Q0 = 0.0700`` (``wageningen(0, 1, 0.718, 3)``), ``K_Tmax = 0.1798``,
  ``K_Qmax = 0.0312`` (``wageningen(0.6632, 1, 0.718, 3)``), ``J_max = 0.6632``; the surge force
  is ``(1 − t) X_p`` with thrust deduction ``t = 0.1`` and the roll moment ``K_p / 10`` (the
  source: "scaled down by a factor of 10 to match exp. results").  ``max(n_s, 0)`` is the
  source's ``if n_rps > 0`` branch written without a branch (equal for every ``n``).

Assumptions and departures from the source
------------------------------------------
* **Actuator dynamics.**  The source filters the commands through first-order lags (fins
  ``T_δ = 0.1`` s, propeller ``T_n = 1.0`` s) and integrates with forward Euler.  Here the
  controls act directly (no actuator states: the issue asks for the commands as controls) and
  the lags are replaced by rate bounds, the initial rate of each lag after a step from zero to
  its bound: ``δ_max / T_δ`` and ``n_max / T_n`` (:attr:`Remus100.control_rate_bound`).
* **Bounds.**  ``|δ_r|, |δ_s| <= 15°`` and ``|n| <= 1525`` rpm, the source's saturation
  (``deltaMax_r = deltaMax_s = 15°``, ``nMax = 1525``; an older revision of the file had 30°).
  The package's controls have symmetric bounds, and so does the source's saturation
  ``|n| <= nMax`` (its ``else`` branch is reverse thrust, "braking").  The model itself does not
  clip: the optimal-control problem bounds the controls.
* **Smoothness.**  ``U``, ``U_r`` and ``α`` are not differentiable at zero speed; there they
  are evaluated with guards (``sqrt`` of zero and ``atan2(0, 0)`` give a zero derivative
  instead of NaN) so that a solver may start from rest.  The values are unchanged.
* Valid for pitch away from ±90° (the Euler-rate transform ``T(Θ)`` is singular there).

Discretisation
--------------
The fastest mode is roll: ``λ = −1.94 ± 6.03i`` 1/s, the same at rest and at cruise (1.5 m/s).
Explicit RK4 is stable on it for steps ``h ≤ 0.446`` s; in one step of 0.5 s it amplifies the
mode by ``|R(λh)| = 1.80`` per interval, so with ``dt = 0.5`` s and ``substeps=1`` a plan far
from the optimum diverges along the horizon (measured in path following from a 10 m offset:
IPOPT's cold starts stop at its iteration limit, RTI steps blow up and the closed loop's
fallback chain takes those steps).  ``substeps=2`` (h = 0.25 s: 0.64) is stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import built_once
from uuv_ocp.model.base import VehicleLayout
from uuv_ocp.model.fossen6dof import (
    STATE_NAMES,
    STATE_UNITS,
    euler_rate_matrix,
    mass_coriolis_matrix,
    rotation_matrix,
)

CONTROL_NAMES = ("delta_r", "delta_s", "n")
CONTROL_UNITS = ("rad", "rad", "rpm")
CURRENT_DIM = 3

#: Hoerner's 2-D cross-flow drag coefficient against ``B / 2T`` (the source's ``gnc.Hoerner``,
#: digitised from S. F. Hoerner, *Fluid-Dynamic Drag*, 1965).
HOERNER_B_OVER_2T = (
    0.0109, 0.1766, 0.3530, 0.4519, 0.4728, 0.4929, 0.4933, 0.5585, 0.6464, 0.8336,
    0.9880, 1.3081, 1.6392, 1.8600, 2.3129, 2.6000, 3.0088, 3.4508, 3.7379, 4.0031,
)  # fmt: skip
HOERNER_CD = (
    1.9661, 1.9657, 1.8976, 1.7872, 1.5837, 1.2786, 1.2108, 1.0836, 0.9986, 0.8796,
    0.8284, 0.7599, 0.6914, 0.6571, 0.6307, 0.5962, 0.5868, 0.5859, 0.5599, 0.5593,
)  # fmt: skip
CROSSFLOW_STRIPS = 20  # crossFlowDrag: stations -L/2, -L/2 + L/20, ..., L/2 (21 of them)
OSWALD_EFFICIENCY = 0.7  # forceLiftDrag's e
LINEAR_DAMPING_DECAY = 3.0  # D_11, D_22 scaled by exp(-3 U_r) (s/m)
SPAN_AREA_FRACTION = 0.7  # S = 0.7 L D: 70 % of the rectangle L × D


def _coriolis(mass_matrix: np.ndarray, nu):
    """``m2c(M, ν)`` of the symmetric part of ``M``, as the source's ``m2c`` (Fossen 2021 eq. 3.60)."""
    return mass_coriolis_matrix(0.5 * (mass_matrix + mass_matrix.T), nu)


def _norm(squared):
    """``√s`` with a zero derivative at ``s = 0`` (CasADi's would be NaN there; the value is the same)."""
    return ca.if_else(squared > 0, ca.sqrt(squared), 0)


@dataclass(frozen=True)
class Remus100:
    """The REMUS 100 after Fossen's ``remus100.py`` (module docstring: equations and sources).

    Every default is the source file's (``cybergalactic/PythonVehicleSimulator`` commit
    ``7e1db8ed``); a field changed by hand makes another torpedo of the same structure.

    Parameters
    ----------
    length : float
        Hull length L = 1.6 m (the source; Prestero 2001), > diameter.
    diameter : float
        Hull diameter D = 0.19 m (the source; Prestero 2001), > 0.
    water_density : float
        ρ = 1026 kg/m³ (the source; ``gnc.crossFlowDrag`` and ``forceLiftDrag`` hard-code the same).
    gravity : float
        g = 9.81 m/s².
    centre_of_gravity : tuple of 3 floats
        ``r_g = (0, 0, 0.02)`` m from the body origin (the source's ``r_bg``).  ``z_g − z_b``
        must be > 0 m: the roll and pitch natural frequencies of the damping need it.
    centre_of_buoyancy : tuple of 3 floats
        ``r_b = (0, 0, 0)`` m: the body origin (the source's ``r_bb``).
    axial_drag_coefficient : float
        Hull drag coefficient ``C_d = 0.42`` on the frontal area π(D/2)² (Allen et al. 2000).
    roll_added_inertia_ratio : float
        ``A₄₄ = 0.3 I_x`` (the source's ``r44``).
    fin_area : float
        Area of one fin, 0.00665 m²; the rudder and the stern plane each count two
        (``A_r = A_s = 2 S_fin``).
    rudder_lift_slope : float
        Rudder lift slope ``C_Lδ,r = 0.5`` (1/rad).
    stern_plane_lift_slope : float
        Stern-plane lift slope ``C_Lδ,s = 0.7`` (1/rad).
    surge_time_constant : float
        Linear surge damping ``M₁₁ / T``, T = 20 s.
    sway_time_constant : float
        Linear sway and heave damping ``M₂₂ / T``, ``M₃₃ / T``, T = 20 s.
    yaw_time_constant : float
        Linear yaw damping ``M₆₆ / T``, T = 1 s.
    roll_damping_ratio : float
        Relative damping ratio in roll, 0.3.
    pitch_damping_ratio : float
        Relative damping ratio in pitch, 0.8.
    propeller_diameter : float
        0.14 m ("5.5 inches").
    thrust_deduction : float
        ``t = 0.1``, in [0, 1).
    wake_fraction : float
        ``w = 0.056``: ``V_a = (1 − w) U = 0.944 U`` (Allen et al. 2000), in [0, 1).
    max_advance_ratio : float
        ``J_max = 0.6632 = 0.944 × 2.5 / (0.14 × 1525/60)``.
    thrust_coefficients : tuple of 2 floats
        ``(K_T0, K_Tmax) = (0.4566, 0.1798)`` at ``J = 0`` and ``J_max`` (MSS ``wageningen``,
        3 blades, blade-area ratio 0.718).
    torque_coefficients : tuple of 2 floats
        ``(K_Q0, K_Qmax) = (0.0700, 0.0312)``, likewise.
    roll_torque_scale : float
        Factor 0.1 on the propeller's roll moment ("to match exp. results").
    max_rudder : float
        Rudder bound, 15° (rad), in (0, π/2).
    max_stern_plane : float
        Stern-plane bound, 15° (rad), in (0, π/2).
    max_propeller_speed : float
        Propeller bound, 1525 rpm.
    fin_time_constant : float
        The source's fin lag, 0.1 s; here it gives the fins' rate bound only.
    propeller_time_constant : float
        The source's propeller lag, 1.0 s; here it gives the propeller's rate bound only.
    name : str
        Label in tables and plots.
    """

    length: float = 1.6
    diameter: float = 0.19
    water_density: float = 1026.0
    gravity: float = 9.81
    centre_of_gravity: tuple[float, float, float] = (0.0, 0.0, 0.02)
    centre_of_buoyancy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axial_drag_coefficient: float = 0.42
    roll_added_inertia_ratio: float = 0.3
    fin_area: float = 0.00665
    rudder_lift_slope: float = 0.5
    stern_plane_lift_slope: float = 0.7
    surge_time_constant: float = 20.0
    sway_time_constant: float = 20.0
    yaw_time_constant: float = 1.0
    roll_damping_ratio: float = 0.3
    pitch_damping_ratio: float = 0.8
    propeller_diameter: float = 0.14
    thrust_deduction: float = 0.1
    wake_fraction: float = 0.056
    max_advance_ratio: float = 0.6632
    thrust_coefficients: tuple[float, float] = (0.4566, 0.1798)
    torque_coefficients: tuple[float, float] = (0.0700, 0.0312)
    roll_torque_scale: float = 0.1
    max_rudder: float = math.radians(15.0)
    max_stern_plane: float = math.radians(15.0)
    max_propeller_speed: float = 1525.0
    fin_time_constant: float = 0.1
    propeller_time_constant: float = 1.0
    name: str = "remus100"

    def __post_init__(self) -> None:
        """Check every field (``ValueError`` names it) and store vectors as tuples of floats."""
        set_field = object.__setattr__
        vectors = {
            "centre_of_gravity": 3,
            "centre_of_buoyancy": 3,
            "thrust_coefficients": 2,
            "torque_coefficients": 2,
        }
        nonnegative = {"thrust_deduction", "wake_fraction", "roll_added_inertia_ratio", "roll_torque_scale"}
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "name":
                if not isinstance(value, str) or not value:
                    raise ValueError(f"name must be a non-empty string, got {check.shown(value)}")
            elif item.name in vectors:
                entries = check.vector(item.name, value, vectors[item.name])
                check.plausible_parameter(item.name, entries, "m or 1")
                set_field(self, item.name, entries)
            elif item.name in nonnegative:
                set_field(self, item.name, check.nonnegative_float(item.name, value))
            else:
                set_field(self, item.name, check.positive_float(item.name, value))
                check.plausible_parameter(item.name, getattr(self, item.name), "(its unit)")
        if self.diameter >= self.length:
            raise ValueError(
                f"diameter must be smaller than length = {self.length} m (a prolate spheroid), "
                f"got {self.diameter} m"
            )
        if self.thrust_deduction >= 1.0 or self.wake_fraction >= 1.0:
            raise ValueError(
                "thrust_deduction and wake_fraction must be in [0, 1), got "
                f"{self.thrust_deduction} and {self.wake_fraction}"
            )
        height = self.centre_of_gravity[2] - self.centre_of_buoyancy[2]
        if height <= 0.0:
            raise ValueError(
                "centre_of_gravity must lie below centre_of_buoyancy (z_g − z_b > 0 m, z down), got "
                f"z_g − z_b = {height} m"
            )
        for name in ("max_rudder", "max_stern_plane"):
            if getattr(self, name) >= 0.5 * math.pi:
                raise ValueError(f"{name} must be an angle in (0, π/2) rad, got {getattr(self, name)}")

    def __getstate__(self) -> dict:
        """Pickle the parameters only; the cached CasADi Function is rebuilt on demand."""
        return {key: value for key, value in self.__dict__.items() if key not in ("dynamics", "layout")}

    # ------------------------------------------------------------------ protocol
    @cached_property
    def layout(self) -> VehicleLayout:
        """State ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]``, controls ``[δ_r, δ_s, n]``, spatial references."""
        return VehicleLayout(
            state_names=STATE_NAMES,
            state_units=STATE_UNITS,
            control_names=CONTROL_NAMES,
            control_units=CONTROL_UNITS,
            positions=(0, 1, 2),
            angles=(3, 4, 5),
            heading=5,
            velocities=tuple(range(6, 12)),
            current_dim=CURRENT_DIM,
            reference="spatial",
        )

    @property
    def control_bound(self) -> tuple[float, ...]:
        """``(δ_r,max, δ_s,max, n_max)`` = (15°, 15°, 1525 rpm) in (rad, rad, rpm)."""
        return (self.max_rudder, self.max_stern_plane, self.max_propeller_speed)

    @property
    def control_rate_bound(self) -> tuple[float, ...]:
        """``(δ_r,max/T_δ, δ_s,max/T_δ, n_max/T_n)`` (rad/s, rad/s, rpm/s): 150°/s and 1525 rpm/s.

        The initial rate of the source's first-order actuator after a step from zero to its
        bound, standing in for the lag the model leaves out (a convention, not a measured slew
        rate).
        """
        fin = self.fin_time_constant
        return (
            self.max_rudder / fin,
            self.max_stern_plane / fin,
            self.max_propeller_speed / self.propeller_time_constant,
        )

    def model_function(self) -> ca.Function:
        """Return the cached :attr:`dynamics` Function ``(x[12], u[3], current[3]) -> xdot[12]``."""
        return self.dynamics

    # ------------------------------------------------------------ derived numbers
    @property
    def mass(self) -> float:
        """Mass of the spheroid ``m = 4/3 π ρ (L/2)(D/2)²`` (kg); 31.0 kg for the preset."""
        return 4.0 / 3.0 * math.pi * self.water_density * (0.5 * self.length) * (0.5 * self.diameter) ** 2

    @property
    def weight(self) -> float:
        """``W = B = m g`` (N): the vehicle is neutrally buoyant."""
        return self.mass * self.gravity

    @property
    def rigid_body_mass_matrix(self) -> np.ndarray:
        """``M_RB = H(r_g)ᵀ diag(m, m, m, I_x, I_y, I_z) H(r_g)`` about the origin, shape (6, 6)."""
        m, a, b = self.mass, 0.5 * self.length, 0.5 * self.diameter
        inertia = (0.4 * m * b**2, 0.2 * m * (a**2 + b**2), 0.2 * m * (a**2 + b**2))
        transform = np.eye(6)
        rg = np.asarray(self.centre_of_gravity)
        transform[0:3, 3:6] = np.array([[0.0, -rg[2], rg[1]], [rg[2], 0.0, -rg[0]], [-rg[1], rg[0], 0.0]]).T
        return transform.T @ np.diag([m, m, m, *inertia]) @ transform

    @property
    def added_mass_matrix(self) -> np.ndarray:
        """``M_A = diag(m k₁, m k₂, m k₂, r₄₄ I_x, k' I_y, k' I_y)`` (Lamb's k-factors), shape (6, 6)."""
        m, a, b = self.mass, 0.5 * self.length, 0.5 * self.diameter
        e = math.sqrt(1.0 - (b / a) ** 2)
        log = math.log((1.0 + e) / (1.0 - e))
        alpha0 = 2.0 * (1.0 - e**2) / e**3 * (0.5 * log - e)
        beta0 = 1.0 / e**2 - (1.0 - e**2) / (2.0 * e**3) * log
        k1, k2 = alpha0 / (2.0 - alpha0), beta0 / (2.0 - beta0)
        k_prime = e**4 * (beta0 - alpha0) / ((2.0 - e**2) * (2.0 * e**2 - (2.0 - e**2) * (beta0 - alpha0)))
        ix, iy = 0.4 * m * b**2, 0.2 * m * (a**2 + b**2)
        return np.diag(
            [m * k1, m * k2, m * k2, self.roll_added_inertia_ratio * ix, k_prime * iy, k_prime * iy]
        )

    @property
    def mass_matrix(self) -> np.ndarray:
        """``M = M_RB + M_A``, shape (6, 6)."""
        return self.rigid_body_mass_matrix + self.added_mass_matrix

    @property
    def linear_damping(self) -> np.ndarray:
        """Diagonal of ``D`` at zero relative speed (N·s/m, N·m·s/rad).

        Surge and sway decay as ``e^{−3U_r}`` with the relative speed ``U_r`` (m/s).
        """
        mass = self.mass_matrix
        height = self.centre_of_gravity[2] - self.centre_of_buoyancy[2]
        roll = math.sqrt(self.weight * height / mass[3, 3])
        pitch = math.sqrt(self.weight * height / mass[4, 4])
        return np.array(
            [
                mass[0, 0] / self.surge_time_constant,
                mass[1, 1] / self.sway_time_constant,
                mass[2, 2] / self.sway_time_constant,  # T_heave = T_sway for a cylinder
                mass[3, 3] * 2.0 * self.roll_damping_ratio * roll,
                mass[4, 4] * 2.0 * self.pitch_damping_ratio * pitch,
                mass[5, 5] / self.yaw_time_constant,
            ]
        )

    # ------------------------------------------------------------------ dynamics
    def dynamics_expression(self, state, control, current):
        """Continuous-time right-hand side ``ẋ = f(x, u, V_c)`` as a CasADi expression.

        Parameters
        ----------
        state : casadi.SX, shape (12,)
            ``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]`` (m, rad, m/s, rad/s).
        control : casadi.SX, shape (3,)
            ``[δ_r, δ_s, n]`` (rad, rad, rpm), applied as they are (no lag, no clipping).
        current : casadi.SX, shape (3,)
            Water velocity in NED (m/s).

        Returns
        -------
        casadi.SX, shape (12,)
        """
        rho, length, diameter = self.water_density, self.length, self.diameter
        phi, theta, psi = state[3], state[4], state[5]
        nu = state[6:12]
        rudder, stern, rpm = control[0], control[1], control[2]

        # the current in the heading-rotated frame (the source's u_c, v_c) and its derivative
        # for a constant current, with ψ̇ taken as r as in the source
        u_c = current[0] * ca.cos(psi) + current[1] * ca.sin(psi)
        v_c = -current[0] * ca.sin(psi) + current[1] * ca.cos(psi)
        nu_r = nu - ca.vertcat(u_c, v_c, current[2], 0, 0, 0)
        current_dot = ca.vertcat(nu[5] * v_c, -nu[5] * u_c, 0, 0, 0, 0)
        u_r, v_r, w_r = nu_r[0], nu_r[1], nu_r[2]
        speed_r2 = u_r**2 + v_r**2 + w_r**2
        speed_r = _norm(speed_r2)
        speed = _norm(nu[0] ** 2 + nu[1] ** 2 + nu[2] ** 2)  # over ground: the source's U
        alpha = ca.if_else(u_r**2 + w_r**2 > 0, ca.atan2(w_r, u_r), 0)

        # propeller: linearised K_T(J), K_Q(J); the J-term only for forward thrust (n > 0)
        kt0, kt_max = self.thrust_coefficients
        kq0, kq_max = self.torque_coefficients
        d_p, j_max = self.propeller_diameter, self.max_advance_ratio
        n_s = rpm / 60.0
        advance = (1.0 - self.wake_fraction) * speed / d_p * ca.fmax(n_s, 0.0)
        thrust = rho * d_p**4 * (kt0 * ca.fabs(n_s) * n_s + (kt_max - kt0) / j_max * advance)
        torque = rho * d_p**5 * (kq0 * ca.fabs(n_s) * n_s + (kq_max - kq0) / j_max * advance)

        # Coriolis: C_RB and C_A of the relative velocity, C_A without its Munk/pitch terms
        coriolis_a = _coriolis(self.added_mass_matrix, nu_r)
        for row, column in ((4, 0), (0, 4), (4, 2), (2, 4), (5, 0), (0, 5), (5, 1), (1, 5)):
            coriolis_a[row, column] = 0
        coriolis = _coriolis(self.rigid_body_mass_matrix, nu_r) + coriolis_a
        decay = ca.exp(-LINEAR_DAMPING_DECAY * speed_r)
        d = self.linear_damping
        damping = ca.vertcat(d[0] * decay, d[1] * decay, d[2], d[3], d[4], d[5]) * nu_r

        # hull lift and drag at the angle of attack (a wing of span D and area S)
        area = SPAN_AREA_FRACTION * length * diameter
        aspect = diameter**2 / area
        cd0 = self.axial_drag_coefficient * math.pi * (0.5 * diameter) ** 2 / area
        lift_coefficient = math.pi * aspect / (1.0 + math.sqrt(1.0 + (0.5 * aspect) ** 2)) * alpha
        drag_coefficient = cd0 + lift_coefficient**2 / (math.pi * OSWALD_EFFICIENCY * aspect)
        drag = 0.5 * rho * speed_r2 * area * drag_coefficient
        lift = 0.5 * rho * speed_r2 * area * lift_coefficient
        liftdrag = ca.vertcat(
            -ca.cos(alpha) * drag + ca.sin(alpha) * lift,
            0,
            -ca.sin(alpha) * drag - ca.cos(alpha) * lift,
            0,
            0,
            0,
        )

        # cross-flow drag by strips along the hull (the source sums 21 stations, each × L/20)
        hoerner = float(np.interp(0.5, HOERNER_B_OVER_2T, HOERNER_CD))  # B/2T with B = T = D
        dx = length / CROSSFLOW_STRIPS
        sway, yaw = 0, 0
        for index in range(CROSSFLOW_STRIPS + 1):
            x_strip = -0.5 * length + index * dx
            flow = v_r + x_strip * nu_r[5]
            local = 0.5 * rho * diameter * hoerner * ca.fabs(flow) * flow * dx
            sway -= local
            yaw -= x_strip * local
        crossflow = ca.vertcat(0, sway, 0, 0, 0, yaw)

        # restoring forces (W = B) about the origin, Fossen 2021 eq. 4.6
        w = b = self.weight
        xg, yg, zg = self.centre_of_gravity
        xb, yb, zb = self.centre_of_buoyancy
        cphi, sphi, cth, sth = ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta)
        restoring = ca.vertcat(
            (w - b) * sth,
            -(w - b) * cth * sphi,
            -(w - b) * cth * cphi,
            -(yg * w - yb * b) * cth * cphi + (zg * w - zb * b) * cth * sphi,
            (zg * w - zb * b) * sth + (xg * w - xb * b) * cth * cphi,
            -(xg * w - xb * b) * cth * sphi - (yg * w - yb * b) * sth,
        )

        # fins at the tail, x = -L/2: lift and drag with the in-plane relative speed
        fin_area = 2.0 * self.fin_area
        x_fin = -0.5 * length
        horizontal2 = u_r**2 + v_r**2
        vertical2 = u_r**2 + w_r**2
        rudder_force = -0.5 * rho * horizontal2 * fin_area * self.rudder_lift_slope * rudder
        stern_force = -0.5 * rho * vertical2 * fin_area * self.stern_plane_lift_slope * stern
        fin_drag = (
            -0.5
            * rho
            * fin_area
            * (
                horizontal2 * self.rudder_lift_slope * rudder**2
                + vertical2 * self.stern_plane_lift_slope * stern**2
            )
        )
        actuators = ca.vertcat(
            (1.0 - self.thrust_deduction) * thrust + fin_drag,
            rudder_force,
            stern_force,
            self.roll_torque_scale * torque,
            -x_fin * stern_force,
            x_fin * rudder_force,
        )

        forces = actuators + liftdrag + crossflow - coriolis @ nu_r - damping - restoring
        nu_dot = current_dot + ca.DM(np.linalg.inv(self.mass_matrix)) @ forces
        eta_dot = ca.vertcat(
            rotation_matrix(phi, theta, psi) @ nu[0:3], euler_rate_matrix(phi, theta) @ nu[3:6]
        )
        return ca.vertcat(eta_dot, nu_dot)

    def propeller_power(self, controls: object, states: object) -> np.ndarray:
        """Propeller shaft power ``P = 2π n_s Q`` (W) of commands and states, row by row.

        ``Q = ρ D_p⁵ (K_Q0 |n_s| n_s + (K_Qmax − K_Q0)/J_max (1 − w) U/D_p max(n_s, 0))``, the
        model's propeller torque (:meth:`dynamics_expression`) with ``n_s`` = rpm / 60 and ``U``
        the speed over ground ``‖(u, v, w)‖``.

        Parameters
        ----------
        controls : array_like, shape (n, 3)
            ``[δ_r, δ_s, n]`` (rad, rad, rpm).
        states : array_like, shape (n, 12)
            The states the commands act at.
        """
        u = np.atleast_2d(np.asarray(controls, dtype=float))
        x = np.atleast_2d(np.asarray(states, dtype=float))
        if u.shape[1:] != (3,) or x.shape != (u.shape[0], 12):
            raise ValueError(
                f"controls and states must have shapes (n, 3) and (n, 12), got {u.shape} and {x.shape}"
            )
        n_s = u[:, 2] / 60.0
        d_p, j_max = self.propeller_diameter, self.max_advance_ratio
        kq0, kq_max = self.torque_coefficients
        advance = (1.0 - self.wake_fraction) * np.linalg.norm(x[:, 6:9], axis=1) / d_p * np.maximum(n_s, 0.0)
        torque = self.water_density * d_p**5 * (kq0 * np.abs(n_s) * n_s + (kq_max - kq0) / j_max * advance)
        return 2.0 * math.pi * n_s * torque

    @built_once  # not cached_property + serialised: lock-order inversion (uuv_ocp._concurrency)
    def dynamics(self) -> ca.Function:
        """``dynamics(x[12], u[3], current[3]) -> xdot[12]`` (SX graph), built once per instance."""
        state = ca.SX.sym("x", 12)
        control = ca.SX.sym("u", 3)
        current = ca.SX.sym("current", CURRENT_DIM)
        return ca.Function(
            "remus100",
            [state, control, current],
            [self.dynamics_expression(state, control, current)],
            ["x", "u", "current"],
            ["xdot"],
        )
