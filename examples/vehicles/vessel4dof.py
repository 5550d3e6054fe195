"""A user's own vehicle in one file: a small 4-DOF vessel (surge, sway, yaw and roll).

The structure of Fossen's 4-DOF manoeuvring model (Fossen 2011, *Handbook of Marine Craft
Hydrodynamics and Motion Control*, §7.3): diagonal mass with added mass, linear damping on the
velocity relative to the water, a roll restoring moment and the sway force acting ``z_t`` below
the centre of gravity.  Nothing in the package is touched: it is used by the Python API and by
the CLI as ``--vehicle examples/vehicles/vessel4dof.py:Vessel4DOF`` (docs/vehicles.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

import uuv_ocp as uo

LAYOUT = uo.VehicleLayout(
    state_names=("x", "y", "psi", "phi", "u", "v", "r", "p"),
    state_units=("m", "m", "rad", "rad", "m/s", "m/s", "rad/s", "rad/s"),
    control_names=("X", "Y", "N"),
    control_units=("N", "N", "N·m"),
    positions=(0, 1),
    angles=(2, 3),
    heading=2,
    velocities=(4, 5, 6, 7),
    current_dim=2,
    reference="planar",
)


@dataclass(frozen=True)
class Vessel4DOF:
    """A small 4-DOF vessel (SI units; hydrodynamic derivatives as magnitudes)."""

    mass: float = 100.0  # kg
    roll_inertia: float = 10.0  # I_x, kg·m²
    yaw_inertia: float = 20.0  # I_z, kg·m²
    added_mass: tuple[float, float, float, float] = (10.0, 50.0, 10.0, 2.0)  # X_u̇, Y_v̇, N_ṙ, K_ṗ
    damping: tuple[float, float, float, float] = (20.0, 60.0, 20.0, 60.0)  # X_u, Y_v, N_r, K_p
    restoring: float = 490.5  # W GM_T = m g GM_T with GM_T = 0.5 m, N·m/rad
    sway_arm: float = 0.1  # z_t: the sway force acts this far below the centre of gravity, m
    control_bound: tuple[float, ...] = (200.0, 200.0, 80.0)  # N, N, N·m
    control_rate_bound: tuple[float, ...] = (400.0, 400.0, 160.0)  # per second
    name: str = "vessel4dof"

    @property
    def layout(self) -> uo.VehicleLayout:
        """State ``[x, y, ψ, φ, u, v, r, p]``, controls ``[X, Y, N]``, a horizontal current."""
        return LAYOUT

    def model_function(self) -> ca.Function:
        """Dynamics ``(x[8], tau[3], current[2]) -> xdot[8]``."""
        x, tau, current = ca.SX.sym("x", 8), ca.SX.sym("tau", 3), ca.SX.sym("current", 2)
        psi, phi, u, v, r, p = x[2], x[3], x[4], x[5], x[6], x[7]
        # damping acts on the velocity relative to the water (horizontal current, inertial frame)
        u_r = u - (ca.cos(psi) * current[0] + ca.sin(psi) * current[1])
        v_r = v - (-ca.sin(psi) * current[0] + ca.cos(psi) * current[1])
        m_u, m_v = self.mass + self.added_mass[0], self.mass + self.added_mass[1]
        m_r, m_p = self.yaw_inertia + self.added_mass[2], self.roll_inertia + self.added_mass[3]
        d_u, d_v, d_r, d_p = self.damping
        xdot = ca.vertcat(
            u * ca.cos(psi) - v * ca.cos(phi) * ca.sin(psi),
            u * ca.sin(psi) + v * ca.cos(phi) * ca.cos(psi),
            r * ca.cos(phi),
            p,
            (m_v * v * r - d_u * u_r + tau[0]) / m_u,
            (-m_u * u * r - d_v * v_r + tau[1]) / m_v,
            (-d_r * r + tau[2]) / m_r,
            (-d_p * p - self.restoring * ca.sin(phi) * ca.cos(phi) - self.sway_arm * tau[1]) / m_p,
        )
        return ca.Function("vessel", [x, tau, current], [xdot], ["x", "tau", "current"], ["xdot"])


if __name__ == "__main__":
    problem = uo.TrackingProblem(Vessel4DOF(), uo.Reference.paper("s2"), horizon=10, dt=0.1, terminal="cost")
    x0 = problem.reference_window(0.0)[0].copy()  # on the path, moving with it, upright
    x0[:2] += (0.4, -0.3)  # 0.5 m off
    x0[3] = 0.1  # heeled
    run = uo.simulate(uo.NMPC(problem, solver="ipopt"), x0=x0, duration=3.0, seed=1)
    error = run.errors[-1]
    print(f"position error {float((error**2).sum()) ** 0.5:.3g} m after 3 s (0.5 m at the start)")
