"""Closed-loop step of a 6-DOF BlueROV2 Heavy tracking depth and heading (N = 20, dt = 0.1 s).

The vehicle follows ``x = 0.3 t``, ``y = sin(0.2 t)``, ``z = 1 + 0.5 sin(0.1 t)`` (NED, m) with
roll and pitch regulated to zero, from rest on the path, 10 s (100 steps), warm-started; every
backend runs the same loop in this one process, so the ratios to fatrop are measured together.

Run: ``python -m benchmarks.bench_6dof`` (part of ``make bench``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF

SOLVERS = ("fatrop", "sqp", "igwo")


def problem() -> uo.TrackingProblem:
    """Build the BlueROV2 Heavy depth-and-heading problem."""
    ref = uo.Reference.from_xyz(
        lambda t: 0.3 * t, lambda t: ca.sin(0.2 * t), lambda t: 1.0 + 0.5 * ca.sin(0.1 * t), name="dive"
    )
    return uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), ref, horizon=20, dt=0.1)


def main(duration: float = 10.0) -> None:
    """Print median / p90 ms per step, failures and the settled depth error per backend."""
    tracking = problem()
    x0 = tracking.reference.initial_state(0.0)
    print(f"\n6-DOF BlueROV2 Heavy, depth + heading, N = 20, {duration:g} s closed loop from rest")
    print(
        f"{'solver':8s} {'median ms':>10s} {'p90 ms':>8s} {'fail':>5s} {'max|e_z| t>2':>13s} {'/fatrop':>8s}"
    )
    reference_median = None
    for solver in SOLVERS:
        controller = uo.NMPC(tracking, solver, seed=1)
        controller.step(x0, 0.0)  # build outside the timing
        run = uo.simulate(controller, x0, duration=duration, seed=1)
        times = 1e3 * run.solve_times
        median = float(np.median(times))
        reference_median = reference_median or median
        settled = run.t > 2.0
        depth_error = float(np.max(np.abs(run.states[settled, 2] - run.reference[settled, 2])))
        print(
            f"{solver:8s} {median:10.2f} {np.percentile(times, 90):8.2f} {run.failures:5d} "
            f"{depth_error:13.2e} {median / reference_median:8.2f}"
        )


if __name__ == "__main__":
    main()
