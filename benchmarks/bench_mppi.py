"""MPPI beside IGWO and the exact solvers on the s2 NMPC (RexROV, N = 20, dt = 0.1 s).

* ``step``: one MPPI solve (256 samples × N = 20, the defaults) at a fixed s2 state, warm-started
  on its own shifted plan, repeated; the median wall time from Python, on the compiled batched
  fitness (the default wherever a C compiler exists); also the process CPU time per solve,
  which other jobs sharing the cores do not inflate.
* ``loop``: closed loop on s2 for ``duration`` seconds from the reference's initial state
  (t0 = 0), plant RK4 with 10 sub-steps, one run per seed; per controller the median over seeds
  of the step-time median and 90th percentile, of the paper's max-abs error after the 5 s
  transient (x and y) and of the RMS error over the whole run.

The machine's load average is printed with the table: the step times are wall times and grow
with it (other jobs share the cores).

Run: ``python -m benchmarks.bench_mppi`` (also part of ``make bench``).
"""

from __future__ import annotations

import os
import time

import numpy as np

import uuv_ocp as uo
from uuv_ocp.solvers import new_solver

CONTROLLERS: tuple[tuple[str, str, dict | None], ...] = (
    ("mppi", "mppi", None),
    ("mppi x3 iter", "mppi", {"iterations": 3}),
    ("igwo", "igwo", None),
    ("sqp-rti", "sqp-rti", None),
    ("fatrop", "fatrop", None),
)


def _problem() -> uo.TrackingProblem:
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)


def step_time(problem: uo.TrackingProblem, options: dict | None = None, repeats: int = 300) -> dict:
    """Median and p90 wall time of one warm-started MPPI solve at the s2 state of t0 = 3 s."""
    solver = new_solver(problem, "mppi", options)
    x0 = problem.reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    rng = np.random.default_rng(0)
    warm = solver.solve(p, None, rng).iterate.shift()  # builds outside the timing
    times = []
    cpu = time.process_time()
    for _ in range(repeats):
        start = time.perf_counter()
        result = solver.solve(p, warm, rng)
        times.append(time.perf_counter() - start)
    cpu = (time.process_time() - cpu) / repeats  # CPU time: what other jobs on the cores do not add
    return {
        "cpu": cpu,
        "median": float(np.median(times)),
        "p90": float(np.percentile(times, 90)),
        "evaluation": result.details["evaluation"],
        "samples": solver.samples,
        "iterations": solver.iterations,
    }


def closed_loop(problem: uo.TrackingProblem, name: str, options: dict | None, seeds: int, duration: float):
    """Metrics of ``seeds`` closed loops (median over seeds of each metric)."""
    x0 = problem.reference.initial_state(0.0)
    rows = []
    for seed in range(seeds):
        run = uo.simulate(
            uo.NMPC(problem, name, options=options, seed=seed), x0, duration=duration, seed=seed
        )
        rows.append(run.metrics())
    keys = (
        "solve_time_median",
        "solve_time_p90",
        "max_abs_ex_settled",
        "max_abs_ey_settled",
        "rms_ex",
        "rms_ey",
    )
    summary = {key: float(np.median([row[key] for row in rows])) for key in keys}
    summary["failures"] = int(sum(row["failures"] for row in rows))
    return summary


def main(seeds: int = 5, duration: float = 15.0) -> list[dict]:
    """Print the MPPI step time and the closed-loop table."""
    problem = _problem()
    load = os.getloadavg()
    step = step_time(problem)
    print(
        f"\nMPPI on s2, N = 20: one solve of {step['samples']} samples x {step['iterations']} iteration(s), "
        f"warm-started, {step['evaluation']} fitness: median {1e3 * step['median']:.3f} ms, "
        f"p90 {1e3 * step['p90']:.3f} ms, CPU time {1e3 * step['cpu']:.3f} ms per solve (goal <= 1 ms)"
    )
    rows = []
    for label, name, options in CONTROLLERS:
        rows.append({"label": label, **closed_loop(problem, name, options, seeds, duration)})
    print(
        f"closed loop s2, {duration:g} s from the initial state, {seeds} seeds (medians over seeds); "
        "errors in m, times in ms"
    )
    print(
        f"{'controller':<14}{'step med':>9}{'step p90':>9}{'|ex| 5s+':>10}{'|ey| 5s+':>10}"
        f"{'rms ex':>8}{'rms ey':>8}{'fail':>6}"
    )
    for row in rows:
        print(
            f"{row['label']:<14}{1e3 * row['solve_time_median']:>9.2f}{1e3 * row['solve_time_p90']:>9.2f}"
            f"{row['max_abs_ex_settled']:>10.4f}{row['max_abs_ey_settled']:>10.4f}"
            f"{row['rms_ex']:>8.3f}{row['rms_ey']:>8.3f}{row['failures']:>6d}"
        )
    end = os.getloadavg()
    print(
        f"load average (1 min) {load[0]:.2f} at the start, {end[0]:.2f} at the end, on {os.cpu_count()} CPUs"
    )
    return rows


if __name__ == "__main__":
    main()
