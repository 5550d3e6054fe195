r"""3-DOF horizontal-plane vehicle model (surge, sway, yaw) of the paper's Eqs. (1)-(7).

State ``x = [x, y, psi, u, v, r]`` (m, m, rad, m/s, m/s, rad/s), control
``tau = [F_u, F_v, F_r]`` (N, N, N·m).  With ``M_x = m + X_u̇``, ``M_y = m + Y_v̇`` and
``M_psi = I_z + N_ṙ`` (magnitudes of the added-mass derivatives), the dynamics are

.. math::

    M_x \\dot u_r &= M_y v_r r - X_u u_r - X_{u|u|} u_r |u_r| + F_u \\\\
    M_y \\dot v_r &= -M_x u_r r - Y_v v_r - Y_{v|v|} v_r |v_r| + F_v \\\\
    M_\\psi \\dot r &= (M_x - M_y) u_r v_r - N_r r - N_{r|r|} r |r| + F_r

with the kinematics ``ẋ = u cos ψ − v sin ψ``, ``ẏ = u sin ψ + v cos ψ``, ``ψ̇ = r``.
Without current ``u_r = u`` and ``v_r = v`` and this is exactly the paper's model.  With an
irrotational current of constant inertial velocity ``(V_x, V_y)`` the hydrodynamic terms act on
the velocity relative to the water, ``ν_r = ν − R(ψ)ᵀ V_c`` (Fossen 2011, §10.3 "equations of
relative motion"), and the body-frame current velocity changes as the vehicle turns:
``d/dt ν_c = r [v_c, −u_c, 0]``, so ``ν̇ = ν̇_r + r [v_c, −u_c, 0]``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import serialised
from uuv_ocp.model.base import VehicleLayout
from uuv_ocp.model.damping import steady_speed

STATE_NAMES = ("x", "y", "psi", "u", "v", "r")
STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")
CONTROL_NAMES = ("F_u", "F_v", "F_r")
CONTROL_UNITS = ("N", "N", "N·m")
STATE_DIM = 6
CONTROL_DIM = 3
CURRENT_DIM = 2
LAYOUT = VehicleLayout(
    state_names=STATE_NAMES,
    state_units=STATE_UNITS,
    control_names=CONTROL_NAMES,
    control_units=CONTROL_UNITS,
    positions=(0, 1),
    angles=(2,),
    heading=2,
    velocities=(3, 4, 5),
    current_dim=CURRENT_DIM,
    reference="planar",
)


@dataclass(frozen=True)
class Vehicle:
    """Parameters of a 3-DOF surge/sway/yaw underwater vehicle.

    Parameters
    ----------
    mass : float
        Rigid-body mass m (kg), in [1e-6, 1e9] (plausibility bounds: outside them the input is a
        unit or typing mistake, ``ValueError``).
    inertia : float
        Yaw moment of inertia I_z (kg·m²), in [1e-6, 1e9].
    added_mass : tuple of 3 floats
        Magnitudes of the added-mass derivatives (X_u̇, Y_v̇, N_ṙ) (kg, kg, kg·m²), >= 0.
    linear_damping : tuple of 3 floats
        Magnitudes of the linear damping (X_u, Y_v, N_r) (N·s/m, N·s/m, N·m·s/rad), >= 0.
    quadratic_damping : tuple of 3 floats
        Magnitudes of the quadratic damping (X_u|u|, Y_v|v|, N_r|r|) (N·s²/m², N·s²/m²,
        N·m·s²/rad²), >= 0.
    max_thrust : tuple of 3 floats
        Symmetric bounds |F_u|, |F_v| (N) and |F_r| (N·m), > 0.
    max_thrust_rate : tuple of 3 floats
        Bounds on the rate of change of the generalised thrust (N/s, N/s, N·m/s), > 0.
    name : str
        Label used in tables and plots.

    Notes
    -----
    Every number is at most 1e9 in magnitude (``uuv_ocp._validation.PLAUSIBLE_MAGNITUDE``).
    """

    mass: float
    inertia: float
    added_mass: tuple[float, float, float]
    linear_damping: tuple[float, float, float]
    quadratic_damping: tuple[float, float, float]
    max_thrust: tuple[float, float, float] = (2000.0, 2000.0, 1400.0)
    max_thrust_rate: tuple[float, float, float] = (4000.0, 4000.0, 2800.0)
    name: str = "vehicle"

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        set_field = object.__setattr__
        set_field(self, "mass", check.positive_float("mass", self.mass))
        set_field(self, "inertia", check.positive_float("inertia", self.inertia))
        set_field(self, "added_mass", check.vector("added_mass", self.added_mass, 3, nonnegative=True))
        set_field(
            self,
            "linear_damping",
            check.vector("linear_damping", self.linear_damping, 3, nonnegative=True),
        )
        set_field(
            self,
            "quadratic_damping",
            check.vector("quadratic_damping", self.quadratic_damping, 3, nonnegative=True),
        )
        set_field(self, "max_thrust", check.vector("max_thrust", self.max_thrust, 3, positive=True))
        set_field(
            self,
            "max_thrust_rate",
            check.vector("max_thrust_rate", self.max_thrust_rate, 3, positive=True),
        )
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a string, got {self.name!r}")
        check.plausible_parameter("mass", self.mass, "kg", minimum=check.SMALLEST_INERTIA)
        check.plausible_parameter("inertia", self.inertia, "kg·m²", minimum=check.SMALLEST_INERTIA)
        for field, unit in (
            ("added_mass", "kg or kg·m²"),
            ("linear_damping", "N·s/m or N·m·s/rad"),
            ("quadratic_damping", "N·s²/m² or N·m·s²/rad²"),
            ("max_thrust", "N or N·m"),
            ("max_thrust_rate", "N/s or N·m/s"),
        ):
            check.plausible_parameter(field, getattr(self, field), unit)

    # ------------------------------------------------------------------ presets
    @classmethod
    def rexrov(cls) -> Vehicle:
        """Return the RexROV of uuv_simulator, reduced to surge, sway and yaw.

        Values: mass 1862.87 kg and ``izz`` 691.23 kg·m² from
        ``uuv_descriptions/urdf/rexrov_base.xacro``; added mass (779.79, 1222, 224.32),
        linear damping (74.82, 69.48, 105) and quadratic damping (748.22, 992.53, 523.27) from
        ``rexrov.gazebo.xacro`` (listed there as negative derivatives; magnitudes here).  The
        coupling ``Y_ṙ = N_v̇ = 62.726`` of the full added-mass matrix is dropped, as in the
        paper's diagonal model.  Thrust box 2000 N / 2000 N / 1400 N·m, reachable by the
        simulator's eight 2000 N thrusters without saturating any of them.
        """
        return cls(
            mass=1862.87,
            inertia=691.23,
            added_mass=(779.79, 1222.0, 224.32),
            linear_damping=(74.82, 69.48, 105.0),
            quadratic_damping=(748.22, 992.53, 523.27),
            max_thrust=(2000.0, 2000.0, 1400.0),
            max_thrust_rate=(4000.0, 4000.0, 2800.0),
            name="rexrov",
        )

    @classmethod
    def rexrov_controller_model(cls) -> Vehicle:
        """RexROV with the rounded hydrodynamic values of uuv_simulator's controller config.

        Added mass (700, 1200, 200), linear damping (70, 70, 100), quadratic damping
        (700, 900, 500): a controller built on these against the exact :meth:`rexrov` plant is a
        realistic model mismatch.
        """
        return dataclasses.replace(
            cls.rexrov(),
            added_mass=(700.0, 1200.0, 200.0),
            linear_damping=(70.0, 70.0, 100.0),
            quadratic_damping=(700.0, 900.0, 500.0),
            name="rexrov-controller-model",
        )

    # ------------------------------------------------- the VehicleModel protocol
    @property
    def layout(self) -> VehicleLayout:
        """State ``[x, y, ψ, u, v, r]``, control ``[F_u, F_v, F_r]``, planar references."""
        return LAYOUT

    @property
    def control_bound(self) -> tuple[float, ...]:
        """Symmetric control bound: ``max_thrust`` (N, N, N·m)."""
        return tuple(self.max_thrust)

    @property
    def control_rate_bound(self) -> tuple[float, ...]:
        """Control rate bound: ``max_thrust_rate`` (N/s, N/s, N·m/s)."""
        return tuple(self.max_thrust_rate)

    def model_function(self) -> ca.Function:
        """Return the dynamics as a CasADi Function (:meth:`dynamics_function`)."""
        return self.dynamics_function()

    # --------------------------------------------------------------- properties
    @property
    def inertia_diagonal(self) -> np.ndarray:
        """Diagonal (M_x, M_y, M_psi) of the inertia matrix including added mass (kg, kg, kg·m²)."""
        rigid = np.array([self.mass, self.mass, self.inertia])
        return rigid + np.asarray(self.added_mass)

    def max_speed(self) -> np.ndarray:
        """Steady-state top speed on each axis under full thrust, no current (m/s, m/s, rad/s).

        Solves ``d_lin s + d_quad s² = tau_max`` for each axis, as
        ``2 tau_max / (d_lin + sqrt(d_lin² + 4 d_quad tau_max))`` (no cancellation when the
        linear damping dominates; ``tau_max / d_lin`` without quadratic damping; ``inf``
        without any damping).
        """
        return steady_speed(self.linear_damping, self.quadratic_damping, self.max_thrust)

    def max_horizontal_speed(self, resolution: int = 9001) -> tuple[float, float]:
        """Top speed over ground in still water, crabbing allowed: ``(speed m/s, crab angle rad)``.

        Straight steady motion at speed ``s`` with crab angle ``β`` (``u = s cos β``,
        ``v = s sin β``, ``r = 0``) needs surge force ``X_u u + X_u|u| u|u|``, sway force
        ``Y_v v + Y_v|v| v|v|`` and the yaw moment ``(M_x − M_y) u v`` (Munk moment) to be held
        within ``max_thrust``; for each β on a grid of ``resolution`` angles in ``[0, π/2]`` the
        largest such ``s`` is the smallest of the three per-axis limits, and the result is the
        best β.  ``max_speed()[0]`` is the special case β = 0 (surge only).
        """
        resolution = check.positive_int("resolution", resolution, minimum=2)
        angles = np.linspace(0.0, 0.5 * np.pi, resolution)
        cosine, sine = np.cos(angles), np.sin(angles)
        d_lin = np.asarray(self.linear_damping, dtype=float)
        d_quad = np.asarray(self.quadratic_damping, dtype=float)
        tau = np.asarray(self.max_thrust, dtype=float)

        def axis_limit(share: np.ndarray, linear: float, quadratic: float, force: float) -> np.ndarray:
            # largest s with linear (s share) + quadratic (s share)² <= force
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                # the root of quadratic s² + linear s = force without cancellation (as max_speed)
                denominator = linear + math.sqrt(linear**2 + 4.0 * quadratic * force)
                root = np.full_like(share, 2.0 * force / denominator if denominator > 0 else np.inf)
                return np.where(share > 0, root / share, np.inf)

        limits = [
            axis_limit(cosine, d_lin[0], d_quad[0], tau[0]),
            axis_limit(sine, d_lin[1], d_quad[1], tau[1]),
        ]
        m_x, m_y, _ = self.inertia_diagonal
        munk = abs(m_x - m_y) * cosine * sine
        with np.errstate(divide="ignore"):
            limits.append(np.where(munk > 0, np.sqrt(tau[2] / munk), np.inf))
        speed = np.min(limits, axis=0)
        best = int(np.argmax(speed))
        return float(speed[best]), float(angles[best])

    # ----------------------------------------------------------------- dynamics
    def dynamics(self, state: ca.SX, control: ca.SX, current: ca.SX | None = None) -> ca.SX:
        """Continuous-time right-hand side ``ẋ = f(x, tau, V_c)`` as a CasADi expression.

        Parameters
        ----------
        state : casadi.SX or MX, shape (6,)
            ``[x, y, psi, u, v, r]`` (m, m, rad, m/s, m/s, rad/s).
        control : casadi.SX or MX, shape (3,)
            ``[F_u, F_v, F_r]`` (N, N, N·m).
        current : casadi.SX or MX, shape (2,), optional
            Inertial current velocity ``[V_x, V_y]`` (m/s); ``None`` means still water.

        Returns
        -------
        casadi.SX or MX, shape (6,)
            Time derivative of the state.
        """
        psi, u, v, r = state[2], state[3], state[4], state[5]
        cos_psi, sin_psi = ca.cos(psi), ca.sin(psi)
        u_current: ca.SX | float
        v_current: ca.SX | float
        if current is None:
            u_current = v_current = 0.0
        else:
            u_current = cos_psi * current[0] + sin_psi * current[1]
            v_current = -sin_psi * current[0] + cos_psi * current[1]
        u_rel, v_rel = u - u_current, v - v_current
        m_x, m_y, m_psi = (float(value) for value in self.inertia_diagonal)
        x_u, y_v, n_r = self.linear_damping
        x_uu, y_vv, n_rr = self.quadratic_damping
        u_rel_dot = (m_y * v_rel * r - x_u * u_rel - x_uu * u_rel * ca.fabs(u_rel) + control[0]) / m_x
        v_rel_dot = (-m_x * u_rel * r - y_v * v_rel - y_vv * v_rel * ca.fabs(v_rel) + control[1]) / m_y
        r_dot = ((m_x - m_y) * u_rel * v_rel - n_r * r - n_rr * r * ca.fabs(r) + control[2]) / m_psi
        return ca.vertcat(
            u * cos_psi - v * sin_psi,
            u * sin_psi + v * cos_psi,
            r,
            u_rel_dot + r * v_current,
            v_rel_dot - r * u_current,
            r_dot,
        )

    @serialised
    def dynamics_function(self) -> ca.Function:
        """``f(x[6], tau[3], current[2]) -> xdot[6]`` as a CasADi Function (SX graph)."""
        state = ca.SX.sym("x", STATE_DIM)
        control = ca.SX.sym("tau", CONTROL_DIM)
        current = ca.SX.sym("current", CURRENT_DIM)
        return ca.Function(
            "dynamics",
            [state, control, current],
            [self.dynamics(state, control, current)],
            ["x", "tau", "current"],
            ["xdot"],
        )
