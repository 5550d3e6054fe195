"""Real-time iteration on the obstacle tutorial's rock: what the judge refuses and what it costs.

``NMPC.step`` (the resident C step where the C step is built, else ``solve``) flies 60
steps of the RexROV past the rock of ``docs/tutorials/obstacles.py`` (N = 25, dt = 0.2 s).
Printed: the largest judged path-constraint violation of a plan applied (m), the steps that
took a C fast path, the steps whose one-QP plan was refused and iterated to convergence
(up to ``RTI_REFINEMENTS`` further ``solve`` calls), the fallbacks, and the median and largest step time (ms).

Run: ``python -m benchmarks.bench_rti_obstacles [--unjudged]``.
"""

from __future__ import annotations

import time

import numpy as np

import uuv_ocp as uo
from uuv_ocp.control.scenario import vehicle_plant


def main(steps: int = 60, unjudged: bool = False) -> dict[str, float]:
    """Fly the rock course by ``NMPC.step``; print and return the figures above.

    ``unjudged``: the controller skips its path-constraint judge (what it applied before the
    judge covered sqp-rti); the violations are still measured.
    """
    rock = uo.Obstacle.circle((5.0, 0.2), 0.6, margin=0.5, name="rock")
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=25, dt=0.2, terminal="cost", obstacles=(rock,)
    )
    controller = uo.NMPC(problem, "sqp-rti")
    if unjudged:
        controller._path_constrained = False  # the cached answer of NMPC.path_constrained
    refined = []
    solve = controller.backend.solve
    # only NMPC's refinement passes time_limit (the backend's own feedback does not)
    controller.backend.solve = lambda *a, **k: ("time_limit" in k and refined.append(1)) or solve(*a, **k)
    plant, _ = vehicle_plant(problem, None, problem.dt, 10)
    x, u = line.initial_state(0.0), np.zeros(3)
    controller.warm_up(x, 0.0, u)
    worst, fast, fallbacks, times = 0.0, 0, 0, []
    for k in range(steps):
        t = k * problem.dt
        start = time.perf_counter()
        output = controller.step(x, t, u)
        times.append(time.perf_counter() - start)
        fast += bool(output.fast_path)
        if output.fallback:
            fallbacks += 1
        else:
            worst = max(worst, uo.score(problem, controller.plan, x, t, u_prev=u)[1])
        u = output.control
        x = np.array(plant(x, u, np.zeros(2)))[:, -1]
    figures = {
        "worst_violation_m": worst,
        "fast_steps": fast,
        "refinement_calls": len(refined),
        "fallbacks": fallbacks,
        "median_ms": 1e3 * float(np.median(times)),
        "max_ms": 1e3 * float(np.max(times)),
    }
    print(" ".join(f"{key}={value:.3g}" for key, value in figures.items()))
    return figures


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--unjudged", action="store_true", help="apply sqp-rti plans without the judge")
    main(unjudged=parser.parse_args().unjudged)
