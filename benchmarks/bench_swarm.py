"""Swarm backends on the s2 NMPC (RexROV, N = 20): step time, evaluations/s and quality.

Quality is judged on one merit for every plan: the swarm fitness ``J + ρ_T Σ|x_N − x_R,N| +
ρ_R Σ rate excess`` (the exact penalty of the soft problem), divided by the same merit of the
exact optimum (IPOPT, sticky soft terminal) at the *same* state — 1.0 means optimal.

* ``cold``: one step from the reference state at t0 = 3 s, no warm start, 10 seeds.
* ``loop``: a 100-step closed loop (10 s) started on the reference (moving) at t0 = 0, the
  swarm warm-started from its shifted previous plan; at every step IPOPT solves the same
  instance for the ratio.
* ``mealpy GWO``: mealpy's OriginalGWO with the same 20 × 30 budget calling the cost once per
  individual (the way mealpy works), timed on the cold step only (skipped if mealpy is absent).

Run: ``python -m benchmarks.bench_swarm`` (``make bench`` installs mealpy).
"""

from __future__ import annotations

import time

import numpy as np

import uuv_ocp as uo
from uuv_ocp.solvers.swarm import batched_fitness

SWARMS = ("igwo", "gwo", "ssa", "pso")
PAPER_BUDGET = {"igwo": (20, 30), "gwo": (30, 40), "ssa": (50, 80), "pso": (30, 40)}


def _merit(problem: uo.TrackingProblem, controls: np.ndarray, p: np.ndarray) -> float:
    objective, penalty = problem.build().cost(problem.scaled_from_controls(controls), p)
    return float(objective) + float(penalty)


def _problem() -> uo.TrackingProblem:
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)


def evaluations_per_second(problem: uo.TrackingProblem, population: int = 20, repeats: int = 200) -> float:
    """Batched-cost throughput from Python (CasADi virtual machine)."""
    fitness = batched_fitness(problem, population)
    p = problem.parameters(problem.reference.evaluate([3.0])[0], 3.0)
    candidates = np.random.default_rng(0).uniform(-1, 1, (problem.control_dim, population))
    fitness(candidates, p)
    start = time.perf_counter()
    for _ in range(repeats):
        fitness(candidates, p)
    return population * repeats / (time.perf_counter() - start)


def cold_step(problem: uo.TrackingProblem, method: str, seeds: int = 10) -> dict:
    """Single step from the reference state at t0 = 3 s, no warm start."""
    x0 = problem.reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    exact = uo.solve(problem, "ipopt", x0=x0, t0=3.0)
    optimum = _merit(problem, exact.controls, p)
    solver = uo.get_solver(problem, method)
    solver.solve(p, None, np.random.default_rng(0))  # build outside the timing
    times, ratios = [], []
    for seed in range(seeds):
        start = time.perf_counter()
        result = solver.solve(p, None, np.random.default_rng(seed))
        times.append(time.perf_counter() - start)
        ratios.append(_merit(problem, result.controls, p) / optimum)
    return {"times": np.array(times), "ratios": np.array(ratios), "evaluations": result.evaluations}


def closed_loop(problem: uo.TrackingProblem, method: str, steps: int = 100) -> dict:
    """Warm-started swarm NMPC; IPOPT on the same instance at each step for the ratio."""
    reference = problem.reference
    controller = uo.NMPC(problem, method, seed=1)
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    exact = uo.get_solver(problem, "ipopt")
    state, control = reference.evaluate([0.0])[0], np.zeros(3)
    exact_warm = None
    times, ratios = [], []
    for k in range(steps):
        t = k * problem.dt
        start = time.perf_counter()
        output = controller.step(state, t, control, np.zeros(2))
        times.append(time.perf_counter() - start)
        p = problem.parameters(state, t, control)
        optimal = exact.solve(p, exact_warm)
        exact_warm = optimal.iterate.shift()
        if output.result is not None:
            ratios.append(_merit(problem, output.result.controls, p) / _merit(problem, optimal.controls, p))
        control = output.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    errors = state[:2] - reference.evaluate([steps * problem.dt])[0][:2]
    return {
        "times": np.array(times),
        "ratios": np.array(ratios),
        "final_error": float(np.hypot(*errors)),
    }


def mealpy_cold_step(problem: uo.TrackingProblem, seeds: int = 3) -> dict | None:
    """Time a cold step of mealpy's OriginalGWO, 20 × 30, objective called once per individual."""
    try:
        from mealpy import GWO, FloatVar
    except ImportError:
        return None
    x0 = problem.reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    cost = problem.build().cost
    optimum = _merit(problem, uo.solve(problem, "ipopt", x0=x0, t0=3.0).controls, p)

    def objective(candidate: np.ndarray) -> float:
        objective_value, penalty = cost(candidate, p)
        return float(objective_value) + float(penalty)

    times, ratios = [], []
    for seed in range(seeds):
        task = {
            "obj_func": objective,
            "bounds": FloatVar(lb=[-1.0] * problem.control_dim, ub=[1.0] * problem.control_dim),
            "minmax": "min",
            "log_to": None,
        }
        model = GWO.OriginalGWO(epoch=30, pop_size=20)
        start = time.perf_counter()
        best = model.solve(task, seed=seed)
        times.append(time.perf_counter() - start)
        ratios.append(objective(best.solution) / optimum)
    return {"times": np.array(times), "ratios": np.array(ratios)}


def main(steps: int = 100) -> list[dict]:
    """Print one table; ratios are to IGWO's cold step time measured in the same run."""
    problem = _problem()
    rate = evaluations_per_second(problem)
    print(f"\nSwarm backends on s2, N = 20. Batched cost (VM, population 20): {rate:,.0f} evaluations/s")
    rows = []
    for method in SWARMS:
        cold = cold_step(problem, method)
        loop = closed_loop(problem, method, steps)
        rows.append({"method": method, "cold": cold, "loop": loop})
    meal = mealpy_cold_step(problem)
    header = (
        f"{'method':<11}{'budget':>8}{'cold ms':>9}{'loop med':>9}{'loop p90':>9}"
        f"{'cold ratio':>11}{'loop med':>9}{'loop p90':>9}{'final err m':>12}"
    )
    print("step times in ms; ratio = merit / exact optimum at the same state (1 = optimal)")
    print(header)
    for row in rows:
        population, iterations = PAPER_BUDGET[row["method"]]
        cold, loop = row["cold"], row["loop"]
        print(
            f"{row['method']:<11}{population:>4}x{iterations:<3}{1e3 * np.median(cold['times']):>9.2f}"
            f"{1e3 * np.median(loop['times']):>9.2f}{1e3 * np.percentile(loop['times'], 90):>9.2f}"
            f"{np.median(cold['ratios']):>11.1f}{np.median(loop['ratios']):>9.2f}"
            f"{np.percentile(loop['ratios'], 90):>9.2f}{loop['final_error']:>12.3f}"
        )
    if meal is not None:
        print(
            f"{'mealpy GWO':<11}{20:>4}x{30:<3}{1e3 * np.median(meal['times']):>9.2f}{'-':>9}{'-':>9}"
            f"{np.median(meal['ratios']):>11.1f}"
        )
        speedup = np.median(meal["times"]) / np.median(rows[0]["cold"]["times"])
        print(f"igwo cold step is {speedup:.1f}x faster than mealpy GWO at the same 20 x 30 budget")
    else:
        print("mealpy not installed: `pip install -e .[bench]` to add its GWO to the table")
    return rows


if __name__ == "__main__":
    main()
