"""Swarm optimisers of :mod:`uuv_ocp.optimize.population` against mealpy's reference implementations.

For every test function × dimension × method the script runs our optimiser and mealpy's at the
*same number of objective evaluations* over ``seeds`` seeds and prints one table: median final
error (``f(x) - f*``), the ratio ours/mealpy (errors below ``FLOOR`` count as ``FLOOR``), the
measured evaluation counts and the mean wall time per run.  It also saves the paper's Figure 5
(convergence-factor shapes) to ``out/igwo_convergence_factor.png``.

Budgets are the paper's population × iterations per method (igwo 20×30, gwo 30×40, ssa 50×80,
pso 30×40); ``igwo`` has no mealpy counterpart (mealpy's ``IGWO`` is a different algorithm), so
it is compared with mealpy's ``OriginalGWO`` at igwo's budget; ``igwo-alpha`` is igwo with
``options={"frame": "alpha"}`` (an extension, see
:func:`uuv_ocp.optimize.population.igwo_update`).  ``shifted_rastrigin`` moves the optimum away
from the origin (and off the diagonal) to expose any origin bias.

Run from the repository root::

    python -m benchmarks.bench_swarm_functions
    python -m benchmarks.bench_swarm_functions --griewank   # GWO's solved share on Griewank
    python -m benchmarks.bench_swarm_functions --libraries  # uo.minimize vs mealpy, scipy, pymoo
    python -m benchmarks.bench_swarm_functions --libraries --only igwo,mppi,scipy_de  # some columns

mealpy is a benchmark-only dependency (``pip install -e ".[bench]"``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from uuv_ocp.optimize import (
    ALGORITHMS,
    PAPER_CONVERGENCE_LABELS,
    convergence_factor,
    minimize,
)
from uuv_ocp.optimize.benchmark_functions import ackley, griewank, rastrigin, rosenbrock, shifted, sphere

FLOOR = 1e-8
OUT = Path("out")


# -- test functions (vectorised over rows; all have f* = 0) -------------------------------------


def _shift(dim: int) -> np.ndarray:
    return np.random.default_rng(12345).uniform(-4.0, 4.0, dim)


shifted_rastrigin = shifted(rastrigin, _shift)


#: name -> (function, half-width of the box [-b, b]^d)
FUNCTIONS: dict[str, tuple[Callable[[np.ndarray], np.ndarray], float]] = {
    "sphere": (sphere, 100.0),
    "rastrigin": (rastrigin, 5.12),
    "rosenbrock": (rosenbrock, 30.0),
    "ackley": (ackley, 32.768),
    "shifted_rastrigin": (shifted_rastrigin, 5.12),
}

#: our method -> mealpy class path
MEALPY_REFERENCE = {
    "igwo": ("GWO", "OriginalGWO"),
    "gwo": ("GWO", "OriginalGWO"),
    "ssa": ("SSA", "OriginalSSA"),
    "pso": ("PSO", "OriginalPSO"),
}


#: table row -> (method, options); "igwo-alpha" is igwo with the alpha-anchored inertia,
#: "gwo-greedy" is gwo with mealpy's greedy selection (what mealpy calls OriginalGWO)
VARIANTS: dict[str, dict | None] = {
    "igwo": None,
    "igwo-alpha": {"frame": "alpha"},
    "gwo": None,
    "gwo-greedy": {"selection": "greedy"},
    "ssa": None,
    "pso": None,
}


def mealpy_epochs(method: str, population: int, budget: int) -> int:
    """Epochs of the mealpy reference that use at most ``budget`` evaluations.

    GWO and PSO evaluate ``population`` points per epoch; SSA evaluates the swarm and then
    ``population - int(0.1 population)`` danger-aware sparrows again.
    """
    per_epoch = population
    if method == "ssa":
        per_epoch = population + population - int(0.1 * population)
    return max(1, (budget - population) // per_epoch)


def run_mealpy(
    method: str,
    fun: Callable[[np.ndarray], np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    population: int,
    budget: int,
    seed: int,
) -> tuple[float, int]:
    """Best cost and the evaluation count of mealpy's reference at (at most) ``budget``."""
    import importlib

    from mealpy import FloatVar

    module, cls = MEALPY_REFERENCE[method]
    optimizer_cls = getattr(importlib.import_module(f"mealpy.swarm_based.{module}"), cls)
    count = [0]

    def objective(x: np.ndarray) -> float:
        count[0] += 1
        return float(fun(np.asarray(x, dtype=float)[None, :])[0])

    problem = {
        "bounds": FloatVar(lb=lower.tolist(), ub=upper.tolist()),
        "minmax": "min",
        "obj_func": objective,
        "log_to": None,
    }
    model = optimizer_cls(epoch=mealpy_epochs(method, population, budget), pop_size=population)
    best = model.solve(problem, seed=seed)
    return float(best.target.fitness), count[0]


def ratio(ours: float, reference: float, floor: float = FLOOR) -> float:
    """``max(ours, floor) / max(reference, floor)`` (< 1: ours better)."""
    return max(ours, floor) / max(reference, floor)


def plot_convergence_factor(path: Path = OUT / "igwo_convergence_factor.png") -> Path:
    """Save the paper's Figure 5: a(t) for the linear and three nonlinear schedules."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = 500
    t = np.arange(T + 1)
    fig, ax = plt.subplots(figsize=(6, 4))
    for kind in ("linear", "faster", "slower", "cosine"):
        ax.plot(t, convergence_factor(t, T, kind), label=PAPER_CONVERGENCE_LABELS[kind])
    ax.set_xlabel("iteration t")
    ax.set_ylabel("convergence factor a")
    ax.set_xlim(0, T)
    ax.set_ylim(0, 2.05)
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title("Decay of the convergence factor (T = 500)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(seeds: int = 20, dims: tuple[int, ...] = (10, 30)) -> list[dict]:
    """Run the comparison, print one table and return its rows."""
    rows: list[dict] = []
    header = (
        f"{'function':<18}{'dim':>4} {'method':<11}{'budget':>7}{'nfe ref':>8}"
        f"{'ours':>11}{'mealpy':>11}{'ratio':>9}{'ms ours':>9}{'ms ref':>9}"
    )
    print(header)
    print("-" * len(header))
    for name, (fun, bound) in FUNCTIONS.items():
        for dim in dims:
            lower, upper = -bound * np.ones(dim), bound * np.ones(dim)
            for method, options in VARIANTS.items():
                cls = ALGORITHMS[method.split("-")[0]]
                n, T = cls.default_population, cls.default_iterations
                budget = n * (T + 1)
                ours, theirs, t_ours, t_ref, nfe_ref = [], [], 0.0, 0.0, []
                for seed in range(seeds):
                    start = time.perf_counter()
                    ours.append(minimize(fun, lower, upper, cls.name, seed=seed, options=options).fun)
                    t_ours += time.perf_counter() - start
                    start = time.perf_counter()
                    best, nfe = run_mealpy(cls.name, fun, lower, upper, n, budget, seed)
                    t_ref += time.perf_counter() - start
                    theirs.append(best)
                    nfe_ref.append(nfe)
                row = {
                    "function": name,
                    "dim": dim,
                    "method": method,
                    "reference": ".".join(MEALPY_REFERENCE[cls.name]),
                    "budget": budget,
                    "evaluations_reference": int(np.max(nfe_ref)),
                    "median_ours": float(np.median(ours)),
                    "median_mealpy": float(np.median(theirs)),
                    "ratio": ratio(float(np.median(ours)), float(np.median(theirs))),
                    "ms_per_run_ours": 1e3 * t_ours / seeds,
                    "ms_per_run_mealpy": 1e3 * t_ref / seeds,
                }
                rows.append(row)
                print(
                    f"{name:<18}{dim:>4} {method:<11}{budget:>7}{row['evaluations_reference']:>8}"
                    f"{row['median_ours']:>11.3g}{row['median_mealpy']:>11.3g}"
                    f"{row['ratio']:>9.3g}{row['ms_per_run_ours']:>9.1f}"
                    f"{row['ms_per_run_mealpy']:>9.1f}",
                    flush=True,
                )
    print(
        f"\nmedian over {seeds} seeds of f(x_best) - f*; ratio = ours/mealpy with errors "
        f"< {FLOOR:g} counted as equal; igwo rows are compared with mealpy OriginalGWO at "
        "igwo's budget."
    )
    print(f"figure: {plot_convergence_factor()}")
    return rows


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for ``z = 1.96``)."""
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * np.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return float(centre - half), float(centre + half)


def griewank_solved(
    seeds: int = 60,
    dim: int = 30,
    settings: tuple[tuple[float, int, int], ...] = ((600.0, 30, 200), (100.0, 30, 200), (600.0, 30, 500)),
    solved_below: float = 1e-6,
) -> list[dict]:
    """Share of seeds that reach Griewank's global basin: gwo, gwo-greedy, mealpy OriginalGWO.

    GWO on Griewank ends either at the optimum (< 1e-8) or in a local minimum (about 7e-3
    and up), so a median over a handful of seeds flips between the two; the solved share with
    its Wilson interval is the comparison that means something.  ``settings`` holds
    (half-width of the box, population, iterations).
    """
    rows = []
    print(f"\nGriewank, dim {dim}, {seeds} seeds: share with f < {solved_below:g} [95 % Wilson]")
    for bound, population, iterations in settings:
        lower, upper = -bound * np.ones(dim), bound * np.ones(dim)
        budget = population * (iterations + 1)
        finals = {
            "gwo": [
                minimize(
                    griewank, lower, upper, "gwo", population=population, iterations=iterations, seed=s
                ).fun
                for s in range(seeds)
            ],
            "gwo-greedy": [
                minimize(
                    griewank,
                    lower,
                    upper,
                    "gwo",
                    population=population,
                    iterations=iterations,
                    seed=s,
                    options={"selection": "greedy"},
                ).fun
                for s in range(seeds)
            ],
            "mealpy": [
                run_mealpy("gwo", griewank, lower, upper, population, budget, s)[0] for s in range(seeds)
            ],
        }
        cells = []
        for name, values in finals.items():
            solved = int(np.sum(np.asarray(values) < solved_below))
            low, high = wilson(solved, seeds)
            rows.append(
                {
                    "bound": bound,
                    "population": population,
                    "iterations": iterations,
                    "method": name,
                    "solved": solved,
                    "seeds": seeds,
                    "median": float(np.median(values)),
                }
            )
            cells.append(
                f"{name} {solved / seeds:.2f} [{low:.2f}, {high:.2f}] median {np.median(values):.2g}"
            )
        print(f"  box ±{bound:g}, {population}x{iterations}: " + "; ".join(cells), flush=True)
    return rows


def _scipy_de(
    fun: Callable, lower: np.ndarray, upper: np.ndarray, population: int, iterations: int, seed: int
):
    """Run scipy's differential_evolution, vectorised, no polishing, about ``population`` members."""
    from scipy.optimize import differential_evolution

    dim = lower.size
    multiplier = max(1, round(population / dim)) if dim >= 5 else max(5, population // dim)
    result = differential_evolution(
        lambda X: fun(np.asarray(X).T),
        list(zip(lower, upper, strict=True)),
        popsize=multiplier,
        maxiter=iterations,
        tol=0.0,
        polish=False,
        vectorized=True,
        updating="deferred",
        seed=seed,
    )
    return float(result.fun), int(result.nfev)


def _pymoo(
    kind: str,
    fun: Callable,
    lower: np.ndarray,
    upper: np.ndarray,
    population: int,
    iterations: int,
    seed: int,
):
    """Run pymoo's DE or PSO on the vectorised objective (one call per generation)."""
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize as pymoo_minimize

    if kind == "de":
        from pymoo.algorithms.soo.nonconvex.de import DE as Algorithm
    else:
        from pymoo.algorithms.soo.nonconvex.pso import PSO as Algorithm

    class Vectorised(Problem):
        def _evaluate(self, x, out, *args, **kwargs):
            out["F"] = fun(np.asarray(x, dtype=float))

    problem = Vectorised(n_var=lower.size, n_obj=1, xl=lower, xu=upper)
    result = pymoo_minimize(
        problem, Algorithm(pop_size=population), ("n_gen", iterations + 1), seed=seed, verbose=False
    )
    return float(np.min(result.F)), int(result.algorithm.evaluator.n_eval)


def libraries(
    seeds: int = 20,
    dims: tuple[int, ...] = (10, 30),
    population: int = 30,
    iterations: int = 200,
    only: tuple[str, ...] | None = None,
) -> list[dict]:
    """``uo.minimize`` beside mealpy, scipy and pymoo on a user's vectorised objective.

    Every method gets about ``population × (iterations + 1)`` evaluations (the column ``nfe``
    gives the largest count measured); the table is the median final error over ``seeds`` and
    the mean wall time per run (ms).  The package's loop is numpy over the population, as is
    pymoo's and scipy's (``vectorized=True``); mealpy calls the objective once per individual.
    ``only``: the column names to run (``--only igwo,mppi``), all by default.
    """
    griewank_box = {"griewank": (griewank, 600.0)}
    cases = {**FUNCTIONS, **griewank_box}

    def ours(method: str) -> Callable:
        return lambda f, lo, up, s: (
            minimize(f, lo, up, method, population=population, iterations=iterations, seed=s).fun,
            population * (iterations + 1),
        )

    methods: dict[str, Callable] = {
        **{method: ours(method) for method in ("igwo", "gwo", "pso", "mppi")},
        "mealpy gwo": lambda f, lo, up, s: run_mealpy(
            "gwo", f, lo, up, population, population * (iterations + 1), s
        ),
        "scipy de": lambda f, lo, up, s: _scipy_de(f, lo, up, population, iterations, s),
        "pymoo de": lambda f, lo, up, s: _pymoo("de", f, lo, up, population, iterations, s),
        "pymoo pso": lambda f, lo, up, s: _pymoo("pso", f, lo, up, population, iterations, s),
    }
    if only is not None:
        methods = {name: run for name, run in methods.items() if name in only}
    rows = []
    print(
        f"\nmedian final error over {seeds} seeds / mean ms per run, "
        f"~{population}x{iterations + 1} evaluations"
    )
    print(f"{'function':<18}{'dim':>4} " + "".join(f"{name:>21}" for name in methods))
    for name, (fun, bound) in cases.items():
        for dim in dims:
            lower, upper = -bound * np.ones(dim), bound * np.ones(dim)
            cells = []
            for method, run in methods.items():
                finals, counts, started = [], [], time.perf_counter()
                for seed in range(seeds):
                    value, count = run(fun, lower, upper, seed)
                    finals.append(value)
                    counts.append(count)
                ms = 1e3 * (time.perf_counter() - started) / seeds
                row = {
                    "function": name,
                    "dim": dim,
                    "method": method,
                    "median": float(np.median(finals)),
                    "ms": ms,
                    "nfe": int(max(counts)),
                }
                rows.append(row)
                cells.append(f"{row['median']:>10.2g} /{ms:>7.1f}ms")
            print(f"{name:<18}{dim:>4} " + " ".join(f"{cell:>20}" for cell in cells), flush=True)
    return rows


if __name__ == "__main__":
    import sys

    if "--griewank" in sys.argv:
        griewank_solved()
    elif "--libraries" in sys.argv:
        chosen = sys.argv[sys.argv.index("--only") + 1].split(",") if "--only" in sys.argv else None
        libraries(only=None if chosen is None else tuple(name.replace("_", " ") for name in chosen))
    else:
        main()
