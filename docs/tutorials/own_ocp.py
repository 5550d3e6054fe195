"""Your own Ocp: park a RexROV at a goal pose with little thrust, around a no-go disc.

No preset: the problem is declared with :class:`uuv_ocp.Ocp` on the vehicle's own dynamics.

* states ``eta = (x, y, ψ)`` (m, m, rad) and ``nu = (u, v, r)`` (m/s, m/s, rad/s), control
  ``tau = (F_u, F_v, F_r)`` (N, N, N·m) in the vehicle's thrust box and rate bound;
* stage cost: distance to the goal plus a thrust penalty (least-squares residuals, so ``sqp``
  can use its Gauss–Newton Hessian);
* a hard keep-out disc around a ``hazard`` parameter and the terminal equalities
  ``eta_N = goal``, ``nu_N = 0``.

Solved open loop by three exact solvers, then run in closed loop with NMPC.
``examples/custom_ocp.py`` is a longer example (a double integrator with a soft speed limit,
solved by a swarm too).

Run: ``python docs/tutorials/own_ocp.py``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np

import uuv_ocp as uo

VEHICLE = uo.Vehicle.rexrov()
GOAL = np.array([6.0, 2.0, 0.5])  # x (m), y (m), ψ (rad)
HAZARD = np.array([3.0, 0.8])  # m, centre of the no-go disc (on the straight line to the goal)
RADIUS = 0.7  # m
START = np.zeros(6)  # at rest at the origin, heading along x


def parking_ocp(horizon: int = 30, dt: float = 0.33) -> uo.Ocp:
    """Declare the problem: nothing is built until a solver needs it."""
    ocp = uo.Ocp(horizon=horizon, dt=dt, name="parking")
    eta = ocp.state("eta", 3)
    nu = ocp.state("nu", 3)
    limit = np.asarray(VEHICLE.max_thrust)
    tau = ocp.control("tau", 3, lower=-limit, upper=limit, max_rate=np.asarray(VEHICLE.max_thrust_rate))
    goal = ocp.parameter("goal", 3)
    hazard = ocp.parameter("hazard", 2)
    # the vehicle's model as an expression of the Ocp's symbols (no current)
    xdot = VEHICLE.dynamics(ca.vertcat(eta, nu), tau)
    ocp.set_der(eta, xdot[:3])
    ocp.set_der(nu, xdot[3:])
    ocp.add_stage_cost(residual=ca.vertcat(eta[:2] - goal[:2], tau / limit), weight=[1.0, 1.0, 0.1, 0.1, 0.1])
    ocp.subject_to(ca.sumsqr(eta[:2] - hazard) >= RADIUS**2)  # hard, nodes 1..N
    ocp.subject_to(eta == goal, at="terminal")
    ocp.subject_to(nu == 0, at="terminal")
    return ocp


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (tests/system/test_docs.py checks it)."""

    ocp: uo.Ocp
    parameters: dict
    plans: dict  # solver -> SolveResult
    run: uo.ClosedLoopResult


def main(
    horizon: int = 30, dt: float = 0.33, duration: float = 10.0, closed_loop_solver: str = "fatrop"
) -> Outcome:
    """Solve one instance with ipopt, fatrop and sqp; then run NMPC for ``duration`` seconds."""
    ocp = parking_ocp(horizon, dt)
    parameters = {"goal": GOAL, "hazard": HAZARD}
    plans = {}
    for name in ("ipopt", "fatrop", "sqp"):
        plan = uo.solve(ocp, name, x0=START, parameters=parameters)
        plans[name] = plan
        gap = np.min(np.linalg.norm(plan.states[1:, :2] - HAZARD, axis=1)) - RADIUS
        print(
            f"{name:<7} cost {plan.cost:.6g}  violation {plan.max_violation:.1e}  clearance {gap:+.1e} m  "
            f"success {plan.success}  {plan.status}"
        )
    run = uo.simulate(uo.NMPC(ocp, closed_loop_solver), START, duration, parameters=parameters)
    distance = np.linalg.norm(run.states[:, :2] - HAZARD, axis=1)
    print(
        f"closed loop ({closed_loop_solver}, {run.controls.shape[0]} steps): failures {run.failures}, "
        f"closest approach to the hazard {distance.min():.3f} m (radius {RADIUS} m), "
        f"final pose error {np.linalg.norm(run.states[-1, :3] - GOAL):.1e}"
    )
    return Outcome(ocp, parameters, plans, run)


if __name__ == "__main__":
    main()
    sys.exit(0)
