"""Your own vehicle: a 3-DOF and a 6-DOF model from constructor arguments, tracked by NMPC.

Both vehicles are small survey AUVs made up for this tutorial (the numbers are plausible, not a
real product's).  For each one: its top speed under full thrust, a reference it can fly, a
tracking problem and a short closed loop; printed are the settled errors.

Run: ``python docs/tutorials/own_vehicle.py``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF

# --- a 3-DOF (surge, sway, yaw) vehicle: every field in SI units, damping as magnitudes
PLANAR = uo.Vehicle(
    mass=60.0,  # kg
    inertia=8.0,  # kg·m², yaw
    added_mass=(6.0, 45.0, 4.0),  # X_u̇, Y_v̇, N_ṙ (kg, kg, kg·m²)
    linear_damping=(12.0, 40.0, 6.0),  # X_u, Y_v, N_r
    quadratic_damping=(25.0, 120.0, 8.0),  # X_u|u|, Y_v|v|, N_r|r|
    max_thrust=(60.0, 30.0, 15.0),  # |F_u|, |F_v| (N), |F_r| (N·m)
    max_thrust_rate=(120.0, 60.0, 30.0),  # per second
    name="survey-auv-3dof",
)

# --- a 6-DOF vehicle in Fossen's model: diagonal inertia and added mass, weight and buoyancy
G = 9.81  # m/s², the user's gravity constant: weight and buoyancy are given in N
SPATIAL = Vehicle6DOF(
    mass=30.0,  # kg
    inertia=(0.6, 1.8, 1.8),  # I_x, I_y, I_z about the body origin (kg·m²)
    added_mass=(3.0, 25.0, 25.0, 0.1, 1.5, 1.5),  # X_u̇, Y_v̇, Z_ẇ, K_ṗ, M_q̇, N_ṙ (magnitudes)
    linear_damping=(8.0, 30.0, 30.0, 1.0, 6.0, 6.0),
    quadratic_damping=(20.0, 90.0, 90.0, 0.5, 10.0, 10.0),
    weight=30.0 * G,  # N
    buoyancy=30.3 * G,  # N: 1 % positively buoyant
    centre_of_gravity=(0.0, 0.0, 0.02),  # m, body frame (z down: below the origin)
    centre_of_buoyancy=(0.0, 0.0, 0.0),  # m
    max_thrust=(40.0, 20.0, 30.0, 3.0, 8.0, 8.0),  # |X|, |Y|, |Z| (N), |K|, |M|, |N| (N·m)
    name="survey-auv-6dof",
)


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (tests/system/test_docs.py checks it)."""

    planar_run: uo.ClosedLoopResult
    spatial_run: uo.ClosedLoopResult
    top_speed: float  # m/s, PLANAR's steady surge speed under full thrust
    planar_settled: float  # m, largest horizontal error after `settle` s (3-DOF)
    spatial_settled: float  # m, largest position error (x, y, z) after `settle` s (6-DOF)


def main(duration: float = 20.0, horizon: int = 20, settle: float = 10.0, solver: str = "sqp") -> Outcome:
    """Track a gentle sine with the 3-DOF model and a slow descent with the 6-DOF one."""
    top_speed = float(PLANAR.max_speed()[0])  # where damping equals full surge thrust
    print(f"{PLANAR.name}: top speeds (surge, sway, yaw) {np.round(PLANAR.max_speed(), 3)} (m/s, m/s, rad/s)")

    # a path flown at 0.5 m/s, well inside the top speed (a faster one would be untrackable)
    sine = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0.5 * ca.sin(0.2 * t), name="sine")
    planar = uo.TrackingProblem(PLANAR, sine, horizon=horizon, dt=0.1)
    planar_run = uo.simulate(uo.NMPC(planar, solver), sine.initial_state(0.0), duration)
    settled = planar_run.t >= settle
    planar_settled = float(np.max(np.linalg.norm(planar_run.errors[settled], axis=1)))
    print(
        f"  NMPC + {solver}, N = {horizon}: max horizontal error after {settle:g} s "
        f"{planar_settled:.2e} m, failures {planar_run.failures}"
    )

    # the 6-DOF vehicle descends from 1 m to 2 m depth while it flies a straight line
    dive = uo.Reference.from_xyz(
        lambda t: 0.3 * t, lambda t: 0 * t, lambda t: 1.5 - 0.5 * ca.cos(np.pi * t / duration), name="dive"
    )
    spatial = uo.TrackingProblem(SPATIAL, dive, horizon=horizon, dt=0.1)
    spatial_run = uo.simulate(uo.NMPC(spatial, solver), dive.initial_state(0.0), duration)
    error = spatial_run.states[:, :3] - spatial_run.reference[:, :3]
    spatial_settled = float(np.max(np.linalg.norm(error[spatial_run.t >= settle], axis=1)))
    print(
        f"{SPATIAL.name}: net buoyancy {SPATIAL.buoyancy - SPATIAL.weight:.2f} N; NMPC + {solver}: "
        f"max position error after {settle:g} s {spatial_settled:.2e} m, "
        f"max |roll| {np.max(np.abs(spatial_run.states[:, 3])):.1e} rad, failures {spatial_run.failures}"
    )
    return Outcome(planar_run, spatial_run, top_speed, planar_settled, spatial_settled)


if __name__ == "__main__":
    main()
    sys.exit(0)
