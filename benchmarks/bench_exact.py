"""Per-step closed-loop cost of each exact backend on s2 (RexROV, N = 20, dt = 0.1 s).

Every backend runs the same 30 s closed loop from rest (warm-started, terminal equality with
the sticky soft fallback) in this one process, so the ratios to IPOPT are measured together.
``step`` is the wall time of ``NMPC.step`` (parameters, solve, bookkeeping); ``plugin`` is
the wall time of the bare ``casadi.nlpsol`` call(s) inside it, so ``step - plugin`` is the
wrapper's overhead.

A second table steps fatrop with and without the still-water specialisation in turn on the
states of one closed loop (``interleaved_times``), so that this machine's speed drift, which
can exceed the difference between two runs, hits both alike.

Run: ``python -m benchmarks.bench_exact`` (or ``make bench``).
"""

from __future__ import annotations

import time

import numpy as np

import uuv_ocp as uo

SOLVERS = ("ipopt", "fatrop", "sqp", "sqp-rti")


def _problem(reference: str) -> uo.TrackingProblem:
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper(reference), horizon=20, dt=0.1)


def closed_loop_times(
    solver: str, reference: str = "s2", duration: float = 30.0, options: dict | None = None
) -> dict:
    """Run the closed loop and collect per-step timings and counts (and the visited states)."""
    problem = _problem(reference)
    ref = problem.reference
    controller = uo.NMPC(problem, solver, options=options)
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    # build both NLP variants outside the timing (lazy nlpsol creation, JIT compilation)
    controller.step(ref.initial_state(0.0), 0.0)
    controller.step(ref.evaluate([3.0])[0], 3.0)
    controller.reset()
    state, control = ref.initial_state(0.0), np.zeros(3)
    steps = int(round(duration / problem.dt))
    step_times, plugin_times, iterations, failures, relaxed, visited = [], [], [], 0, 0, []
    for k in range(steps):
        visited.append((state, k * problem.dt, control))
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
        "visited": visited,
    }


def interleaved_times(
    solver: str, variants: dict[str, dict | None], reference: str = "s2", rounds: int = 2
) -> dict[str, dict]:
    """Median step and plugin time (ms) of several option sets of one backend, stepped in turn.

    The states, times and last controls are those of one closed loop of ``solver`` with its
    defaults; each variant keeps its own warm start.  ``rounds`` passes over the loop.
    """
    problem = _problem(reference)
    visited = closed_loop_times(solver, reference)["visited"]
    controllers = {name: uo.NMPC(problem, solver, options=options) for name, options in variants.items()}
    samples: dict[str, list[tuple[float, float]]] = {name: [] for name in variants}
    for _ in range(rounds):
        for controller in controllers.values():
            controller.reset()
        for state, t, control in visited:
            for name, controller in controllers.items():
                start = time.perf_counter()
                output = controller.step(state, t, control, np.zeros(2))
                elapsed = time.perf_counter() - start
                samples[name].append((elapsed, output.result.details.get("plugin_time", np.nan)))
    summary = {}
    for name, pairs in samples.items():
        step, plugin = np.array(pairs).T
        summary[name] = {"median_ms": 1e3 * np.median(step), "plugin_median_ms": 1e3 * np.nanmedian(plugin)}
    return summary


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
    variants = {"still water (default)": None, "general NLP": {"still_water": False}}
    paired = interleaved_times("fatrop", variants)
    print("\nfatrop on the states of that loop, the two NLPs stepped in turn (ms)")
    print(f"{'NLP':<24}{'median':>8}{'plugin':>8}")
    for name, row in paired.items():
        print(f"{name:<24}{row['median_ms']:>8.2f}{row['plugin_median_ms']:>8.2f}")
    return rows


if __name__ == "__main__":
    main()
