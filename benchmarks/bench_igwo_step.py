"""Issue 30's IGWO table: the default 20 × 30 step from Python against mealpy's GWO, one run.

``uo.get_solver(problem, "igwo").solve(p, None, rng)`` on :mod:`benchmarks.bench_swarm`'s s2
problem (N = 20) at a fixed state: median wall time and the calling thread's CPU time of 200
seeded solves per round, interleaved with mealpy's OriginalGWO at the same budget on the same
cost (:func:`benchmarks.bench_swarm.mealpy_cold_step`, 3 seeds per round), three rounds, the
load printed beside each: only the ratio within one run means anything on a shared machine.

Run: ``OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_igwo_step`` (mealpy from ``.venv-bench``).
"""

from __future__ import annotations

import os
import time

import numpy as np

import uuv_ocp as uo
from benchmarks.bench_swarm import _problem, mealpy_cold_step


def main(rounds: int = 3, solves: int = 200) -> dict:
    """Print one line per round and the overall medians; return them (seconds)."""
    problem = _problem()
    x0 = problem.reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    solver = uo.get_solver(problem, "igwo")
    first = solver.solve(p, None, np.random.default_rng(0))  # builds and loads the C step
    print(f"\nIGWO 20 x 30 default step ({first.details['evaluation']}, rng_thread={solver.rng_thread})")
    walls: list[float] = []
    cpus: list[float] = []
    mealpy: list[float] = []
    for round_ in range(rounds):
        wall, cpu, late = [], [], 0
        for seed in range(solves):
            start, started = time.perf_counter(), time.thread_time()
            result = solver.solve(p, None, np.random.default_rng(seed))
            wall.append(time.perf_counter() - start)
            cpu.append(time.thread_time() - started)
            late += "late with" in result.status
        reference = mealpy_cold_step(problem, seeds=3)
        other = float(np.median(reference["times"])) if reference else float("nan")
        walls += wall
        cpus += cpu
        mealpy.append(other)
        print(
            f"  round {round_}: igwo {1e3 * np.median(wall):.3f} ms wall"
            f" (p90 {1e3 * np.quantile(wall, 0.9):.3f}),"
            f" {1e3 * np.median(cpu):.3f} ms thread CPU, late solves {late}/{solves};"
            f" mealpy GWO {1e3 * other:.1f} ms, ratio {other / np.median(wall):.1f}x; load {os.getloadavg()}"
        )
    summary = {
        "igwo_wall": float(np.median(walls)),
        "igwo_cpu": float(np.median(cpus)),
        "mealpy": float(np.median(mealpy)),
    }
    print(
        f"  all: igwo {1e3 * summary['igwo_wall']:.3f} ms wall, {1e3 * summary['igwo_cpu']:.3f} ms CPU;"
        f" mealpy {1e3 * summary['mealpy']:.1f} ms; ratio {summary['mealpy'] / summary['igwo_wall']:.1f}x"
    )
    return summary


if __name__ == "__main__":
    main()
