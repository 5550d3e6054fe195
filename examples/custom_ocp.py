"""A user's own optimal-control problem: a planar double integrator around a keep-out disc.

The problem is declared with :class:`uuv_ocp.Ocp` (no vehicle, no preset):

* states ``pos`` (m) and ``vel`` (m/s) in the plane, control ``acc`` (m/s²) in the box
  ``[-1, 1]²`` with the rate bound ``|Δacc| ≤ 2 m/s³ · dt``;
* a stagewise reference ``ref`` (one point per node ``k = 0..N``) tracked by a least-squares
  stage cost, plus a small control weight;
* a **hard** keep-out disc ``‖pos − centre‖ ≥ radius`` on nodes 1..N, a **soft** speed limit
  ``‖vel‖² ≤ v_max²`` (exact L1 penalty, weight ``SPEED_PENALTY``) and the **terminal**
  equalities ``pos_N = goal``, ``vel_N = 0``.

One instance (a straight-line reference from the start to the goal, through the disc) is
solved by three exact solvers and a swarm and printed as a comparison table judged by
:func:`uuv_ocp.score`; then the same Ocp runs as an NMPC controller in closed loop, with the
reference held at the goal on every node (a regulation task: :func:`uuv_ocp.simulate` holds the
parameters for the whole run).

Run: ``python examples/custom_ocp.py``.  The swarm compiles its cost on first use where a C
compiler exists (about 20 s, then cached on disk); ``UUV_OCP_COMPILED=0`` keeps it on CasADi's
virtual machine.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np

import uuv_ocp as uo

DT = 0.25  # s
RADIUS = 0.6  # m, radius of the keep-out disc
SPEED_PENALTY = 1.0  # exact L1 weight of the speed-limit excess, per (m/s)² and node
START = np.zeros(4)  # pos (m), vel (m/s)
GOAL = np.array([4.0, 1.0])  # m
CENTRE = np.array([2.0, 0.3])  # m: the straight line from START to GOAL crosses the disc
V_MAX = 1.0  # m/s


def keep_out_ocp(horizon: int = 24) -> uo.Ocp:
    """Declare the problem (nothing is built until a solver first needs it)."""
    ocp = uo.Ocp(horizon=horizon, dt=DT, name="keep_out")
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    goal = ocp.parameter("goal", 2)
    centre = ocp.parameter("centre", 2)
    v_max = ocp.parameter("v_max")
    ref = ocp.parameter("ref", 2, stagewise=True)  # one value per node k = 0..N
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(pos - ref, 0.3 * acc))  # Σ_k ‖pos−ref‖² + 0.09 ‖acc‖²
    ocp.subject_to(ca.sumsqr(pos - centre) >= RADIUS**2)  # hard, nodes 1..N
    ocp.subject_to(ca.sumsqr(vel) <= v_max**2, soft=SPEED_PENALTY)  # soft, nodes 1..N
    ocp.subject_to(pos == goal, at="terminal")
    ocp.subject_to(vel == 0, at="terminal")
    return ocp


def line_reference(horizon: int) -> np.ndarray:
    """``(N+1, 2)``: the straight line from the start to the goal, at constant speed."""
    fraction = np.linspace(0.0, 1.0, horizon + 1)[:, None]
    return START[:2] + fraction * (GOAL - START[:2])


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (the tests check it against independent computations)."""

    ocp: uo.Ocp
    parameters: dict
    rows: list
    plans: dict  # solver name -> SolveResult of the compared instance
    run: uo.ClosedLoopResult
    closed_loop_parameters: dict


def main(
    horizon: int = 24,
    duration: float = 8.0,
    swarm: str = "igwo",
    swarm_options: dict | None = None,
) -> Outcome:
    """Compare ``ipopt``, ``fatrop``, ``sqp`` and ``swarm`` on one instance, then run NMPC."""
    ocp = keep_out_ocp(horizon)
    parameters = {"goal": GOAL, "centre": CENTRE, "v_max": V_MAX, "ref": line_reference(horizon)}
    solvers = ["ipopt", "fatrop", "sqp", swarm]
    options = {swarm: dict(swarm_options)} if swarm_options else None
    rows = uo.compare(ocp, solvers, x0=START, parameters=parameters, seed=1, options=options)
    print(f"One instance, N = {horizon}, dt = {DT} s (cost and violation from uo.score):")
    print(uo.format_comparison(rows))
    # the backends are cached on the Ocp: these solves reuse what compare() built
    plans = {
        name: uo.solve(ocp, name, x0=START, parameters=parameters, options=(options or {}).get(name))
        for name in solvers
    }
    for name, plan in plans.items():
        clearance = np.min(np.linalg.norm(plan.states[1:, :2] - CENTRE, axis=1)) - RADIUS
        print(
            f"  {name:<7} clearance {clearance:+.2e} m, |x_N - goal| "
            f"{np.linalg.norm(plan.states[-1, :2] - GOAL):.1e} m, status {plan.status}"
        )

    held = {**parameters, "ref": GOAL}  # a (2,) value is held on every node
    run = uo.simulate(uo.NMPC(ocp, "fatrop"), START, duration, parameters=held)
    distance = np.linalg.norm(run.states[:, :2] - CENTRE, axis=1)
    speed = np.linalg.norm(run.states[:, 2:], axis=1)
    print(
        f"Closed loop (NMPC + fatrop, {run.controls.shape[0]} steps): failures {run.failures}, "
        f"smallest distance to the disc centre {distance.min():.4f} m (radius {RADIUS} m), "
        f"top speed {speed.max():.2f} m/s (soft limit {V_MAX} m/s), "
        f"final distance to the goal {np.linalg.norm(run.states[-1, :2] - GOAL):.1e} m"
    )
    return Outcome(ocp, parameters, rows, plans, run, held)


if __name__ == "__main__":
    main()
    sys.exit(0)
