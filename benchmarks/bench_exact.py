"""Per-step closed-loop cost of each exact backend on s2 (RexROV, N = 20, dt = 0.1 s).

Every backend runs the same 30 s closed loop from rest (warm-started, terminal equality with
the sticky soft fallback) in this one process, so the ratios to IPOPT are measured together.
``step`` is the wall time of ``NMPC.step`` (parameters, solve, bookkeeping); ``plugin`` is
the wall time of the bare ``casadi.nlpsol`` call(s) inside it, so ``step - plugin`` is the
wrapper's overhead.

Run: ``python -m benchmarks.bench_exact`` (or ``make bench``).
"""

from __future__ import annotations

import time

import numpy as np

import uuv_ocp as uo

SOLVERS = ("ipopt", "fatrop", "sqp")


def closed_loop_times(
    solver: str, reference: str = "s2", duration: float = 30.0, options: dict | None = None
) -> dict:
    """Run the closed loop and collect per-step timings and counts."""
    ref = uo.Reference.paper(reference)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), ref, horizon=20, dt=0.1)
    controller = uo.NMPC(problem, solver, options=options)
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    # build both NLP variants outside the timing (lazy nlpsol creation, JIT compilation)
    controller.step(ref.initial_state(0.0), 0.0)
    controller.step(ref.evaluate([3.0])[0], 3.0)
    controller.reset()
    state, control = ref.initial_state(0.0), np.zeros(3)
    steps = int(round(duration / problem.dt))
    step_times, plugin_times, iterations, failures, relaxed = [], [], [], 0, 0
    for k in range(steps):
        start = time.perf_counter()
        output = controller.step(state, k * problem.dt, control, np.zeros(2))
        step_times.append(time.perf_counter() - start)
        result = output.result
        plugin_times.append(result.details.get("plugin_time", np.nan) if result else np.nan)
        iterations.append(result.iterations if result else 0)
        failures += int(output.fallback)
        relaxed += int(bool(result and result.terminal_relaxed))
        control = output.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    step_times = np.array(step_times)
    return {
        "solver": solver,
        "median_ms": 1e3 * np.median(step_times),
        "p90_ms": 1e3 * np.percentile(step_times, 90),
        "max_ms": 1e3 * step_times.max(),
        "plugin_median_ms": 1e3 * np.nanmedian(plugin_times),
        "iterations_median": float(np.median(iterations)),
        "failures": failures,
        "relaxed": relaxed,
        "steps": steps,
    }


def main(duration: float = 30.0) -> list[dict]:
    """Measure every exact backend and print one table with ratios to IPOPT."""
    rows = [closed_loop_times(name, duration=duration) for name in SOLVERS]
    base = rows[0]["median_ms"]
    steps = rows[0]["steps"]
    print(f"\nExact backends, closed loop on s2, N = 20, {steps} steps from rest, warm-started")
    print(
        f"{'solver':<8}{'median ms':>10}{'p90 ms':>9}{'max ms':>9}{'plugin ms':>10}"
        f"{'iter':>6}{'fail':>6}{'soft':>6}{'/ipopt':>8}"
    )
    for row in rows:
        print(
            f"{row['solver']:<8}{row['median_ms']:>10.2f}{row['p90_ms']:>9.2f}{row['max_ms']:>9.1f}"
            f"{row['plugin_median_ms']:>10.2f}{row['iterations_median']:>6.0f}{row['failures']:>6d}"
            f"{row['relaxed']:>6d}{row['median_ms'] / base:>8.2f}"
        )
    return rows


if __name__ == "__main__":
    main()
