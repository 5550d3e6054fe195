"""Tests of the population optimisers in :mod:`uuv_ocp.optimize`."""

from __future__ import annotations

import numpy as np
import pytest

import uuv_ocp.optimize as swarm
from uuv_ocp.optimize import (
    MinimizeResult,
    available_methods,
    convergence_factor,
    gwo_update,
    igwo_update,
    minimize,
)
from uuv_ocp.optimize.benchmark_functions import (
    ackley,
    griewank,
    rastrigin,
    rosenbrock,
    shifted,
    sphere,
)

METHODS = ["gwo", "igwo", "mppi", "pso", "ssa"]
DIM = 10
LOWER, UPPER = -5.0 * np.ones(DIM), 5.0 * np.ones(DIM)
# optimum away from the origin and off the diagonal, so no origin/diagonal bias can help
CENTRE = np.linspace(-2.5, 3.1, DIM)


shifted_sphere = shifted(sphere, CENTRE)
shifted_rastrigin = shifted(rastrigin, 0.5 * CENTRE)


class Recorder:
    """Vectorised objective wrapper that records every call."""

    def __init__(self, fun):
        self.fun = fun
        self.shapes: list[tuple[int, ...]] = []

    def __call__(self, X: np.ndarray) -> np.ndarray:
        self.shapes.append(X.shape)
        return self.fun(X)

    @property
    def rows(self) -> int:
        return sum(shape[0] for shape in self.shapes)


# -- quality ------------------------------------------------------------------------------------


def test_available_methods_sorted():
    assert available_methods() == METHODS


@pytest.mark.parametrize("method", METHODS)
def test_sphere_10d_reaches_small_error(method):
    # origin-centred sphere, paper's default population × iterations per method
    errors = [minimize(sphere, LOWER, UPPER, method, seed=s).fun for s in range(5)]
    assert np.median(errors) < 1.0  # box [-5, 5]^10: a random point scores ~83
    # a larger budget on a sphere shifted off the origin and off the diagonal
    options = {"frame": "alpha"} if method == "igwo" else None
    shifted = [
        minimize(
            shifted_sphere,
            LOWER,
            UPPER,
            method,
            population=30,
            iterations=200,
            seed=s,
            options=options,
        ).fun
        for s in range(5)
    ]
    assert np.median(shifted) < 0.1  # a random point scores ~100


def test_igwo_paper_rule_is_biased_towards_origin():
    # documented property of the paper's update: w < 1 scales positions toward 0
    kwargs = {"population": 30, "iterations": 200}
    paper = [minimize(shifted_sphere, LOWER, UPPER, "igwo", seed=s, **kwargs).fun for s in range(5)]
    anchored = [
        minimize(
            shifted_sphere,
            LOWER,
            UPPER,
            "igwo",
            seed=s,
            options={"frame": "alpha"},
            **kwargs,
        ).fun
        for s in range(5)
    ]
    assert np.median(anchored) < 1e-2 * np.median(paper)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    "fun, bound",
    [(shifted_rastrigin, 5.12), (rastrigin, 5.12), (rosenbrock, 5.0)],
    ids=["shifted_rastrigin", "rastrigin", "rosenbrock"],
)
def test_beats_random_search_at_equal_budget(method, fun, bound):
    lower, upper = -bound * np.ones(DIM), bound * np.ones(DIM)
    ours, random = [], []
    for s in range(7):
        result = minimize(fun, lower, upper, method, seed=s)
        ours.append(result.fun)
        rng = np.random.default_rng(1000 + s)
        samples = lower + rng.random((result.evaluations, DIM)) * (upper - lower)
        random.append(fun(samples).min())
    assert np.median(ours) < np.median(random)
    assert np.mean(np.array(ours) < np.array(random)) >= 5 / 7


# -- reproducibility, budget, seeding, history --------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_same_seed_bit_identical(method):
    a = minimize(rastrigin, LOWER, UPPER, method, iterations=15, seed=42)
    b = minimize(rastrigin, LOWER, UPPER, method, iterations=15, seed=42)
    c = minimize(rastrigin, LOWER, UPPER, method, iterations=15, seed=np.random.default_rng(42))
    d = minimize(rastrigin, LOWER, UPPER, method, iterations=15, seed=43)
    for other in (b, c):
        assert np.array_equal(a.x, other.x)
        assert a.fun == other.fun
        assert np.array_equal(a.history, other.history)
        assert np.array_equal(a.population, other.population)
    assert not np.array_equal(a.population, d.population)


@pytest.mark.parametrize("method", METHODS)
def test_max_evaluations_respected_exactly(method):
    f = Recorder(sphere)
    result = minimize(f, LOWER, UPPER, method, population=10, iterations=50, max_evaluations=55, seed=0)
    assert f.rows == 50 == result.evaluations  # 10 initial + 4 × 10; a 5th iteration → 60 > 55
    assert len(f.shapes) == 5
    assert result.iterations == 4
    assert len(result.history) == 5
    assert "max_evaluations" in result.message

    f = Recorder(sphere)
    result = minimize(f, LOWER, UPPER, method, population=10, iterations=6, max_evaluations=70, seed=0)
    assert f.rows == 70 == result.evaluations
    assert result.iterations == 6


@pytest.mark.parametrize("method", METHODS)
def test_fun_called_once_per_iteration_with_whole_population(method):
    f = Recorder(sphere)
    result = minimize(f, LOWER, UPPER, method, population=12, iterations=7, seed=3)
    assert f.shapes == [(12, DIM)] * 8
    assert result.evaluations == 12 * 8
    assert result.population.shape == (12, DIM)


@pytest.mark.parametrize("method", METHODS)
def test_initial_population_seed_is_evaluated(method):
    seeds = np.vstack([CENTRE, CENTRE + 1.0])
    f = Recorder(shifted_sphere)
    result = minimize(f, LOWER, UPPER, method, population=8, iterations=5, seed=0, initial_population=seeds)
    assert result.fun == 0.0
    assert result.history[0] == 0.0
    assert np.array_equal(result.x, CENTRE)


def test_initial_population_rows_come_first_and_are_clipped():
    seen = []

    def f(X):
        seen.append(X.copy())
        return sphere(X)

    seeds = np.array([[0.5] * DIM, [9.0] * DIM])
    minimize(f, LOWER, UPPER, "igwo", population=6, iterations=1, seed=0, initial_population=seeds)
    assert np.array_equal(seen[0][0], seeds[0])
    assert np.array_equal(seen[0][1], UPPER)
    assert np.all((seen[0] >= LOWER) & (seen[0] <= UPPER))


@pytest.mark.parametrize("method", METHODS)
def test_history_non_increasing_and_length(method):
    result = minimize(ackley, LOWER, UPPER, method, population=10, iterations=25, seed=5)
    assert isinstance(result, MinimizeResult)
    assert result.history.shape == (26,)
    assert np.all(np.diff(result.history) <= 0.0)
    assert result.history[-1] == result.fun == pytest.approx(ackley(result.x[None])[0], abs=0)
    assert np.all((result.x >= LOWER) & (result.x <= UPPER))
    assert result.method == method


@pytest.mark.parametrize("method", METHODS)
def test_non_finite_costs_are_infinite(method):
    def f(X):
        costs = sphere(X)
        costs[::2] = np.nan
        costs[1::4] = -np.inf
        return costs

    result = minimize(f, LOWER, UPPER, method, population=8, iterations=5, seed=1)
    assert np.isfinite(result.fun)
    assert np.all(np.isfinite(result.history))


def test_all_infinite_costs_do_not_crash():
    result = minimize(
        lambda X: np.full(len(X), np.inf), LOWER, UPPER, "igwo", population=5, iterations=3, seed=0
    )
    assert result.fun == np.inf
    assert result.x.shape == (DIM,)


@pytest.mark.parametrize("method", METHODS)
def test_all_nan_costs_report_failure(method):
    seeds = np.full((1, DIM), 0.25)
    result = minimize(
        lambda X: np.full(len(X), np.nan),
        LOWER,
        UPPER,
        method,
        population=6,
        iterations=4,
        seed=0,
        initial_population=seeds,
    )
    assert result.success is False
    assert result.fun == np.inf
    assert np.all(result.history == np.inf)
    assert "no finite value" in result.message
    assert "iteration budget" in result.message  # the stopping reason is kept
    assert result.iterations == 4 and result.evaluations == 30
    assert np.array_equal(result.x, seeds[0])  # documented: the first initial point


@pytest.mark.parametrize("method", METHODS)
def test_success_iff_a_finite_cost_was_seen(method):
    def mostly_nan(X):
        costs = np.full(len(X), np.nan)
        costs[-1] = sphere(X[-1:])[0]
        return costs

    assert minimize(sphere, LOWER, UPPER, method, population=6, iterations=2, seed=0).success is True
    result = minimize(mostly_nan, LOWER, UPPER, method, population=6, iterations=2, seed=0)
    assert result.success is True
    assert np.isfinite(result.fun)
    assert "no finite" not in result.message


def test_result_repr_is_short_and_hides_the_arrays():
    result = MinimizeResult(
        x=np.full(4, 987654.321),
        fun=1.5,
        history=np.full(3, 24680.1357),
        evaluations=60,
        iterations=2,
        method="gwo",
        population=np.full((20, 4), 123456.789),
        message="reached the iteration budget (2)",
    )
    text = repr(result)
    for number in ("987654", "24680", "123456"):
        assert number not in text
    for part in ("'gwo'", "fun=1.5", "evaluations=60", "iterations=2", "success=True", "(4,)"):
        assert part in text
    assert "reached the iteration budget (2)" in text
    real = minimize(sphere, LOWER, UPPER, "pso", population=30, iterations=3, seed=0)
    assert "\n" not in repr(real) and len(repr(real)) < 250


def test_scalar_bound_broadcasts():
    a = minimize(sphere, -5.0, UPPER, "gwo", population=6, iterations=3, seed=2)
    b = minimize(sphere, LOWER, 5.0, "gwo", population=6, iterations=3, seed=2)
    assert np.array_equal(a.x, b.x)


# -- the pure update functions (C-port contract) ------------------------------------------------


@pytest.mark.parametrize("method, planes", [("gwo", 6), ("igwo", 8)])
def test_first_iteration_reproduced_from_documented_draw_layout(method, planes):
    n, d, k = 7, 4, 2
    lower, upper = -np.ones(d), 2.0 * np.ones(d)
    seeds = np.array([[0.1, 0.2, 0.3, 0.4], [-0.5, 0.5, 1.5, -0.9]])
    result = minimize(
        sphere, lower, upper, method, population=n, iterations=1, seed=11, initial_population=seeds
    )

    rng = np.random.default_rng(11)
    X0 = np.vstack([seeds, lower + rng.random((n - k, d)) * (upper - lower)])
    draws = rng.random((planes, n, d))
    order = np.argsort(sphere(X0), kind="stable")
    alpha, beta, delta = X0[order[:3]]
    if method == "gwo":
        expected = gwo_update(X0, alpha, beta, delta, 2.0, draws)
    else:
        expected = igwo_update(X0, X0, alpha, beta, delta, alpha, 2.0, 0.9, draws)
    assert np.array_equal(result.population, np.clip(expected, lower, upper))


def test_griewank_matches_its_scalar_formula():
    import math

    X = np.random.default_rng(4).uniform(-600.0, 600.0, (5, 7))
    expected = [
        1.0
        + sum(x * x for x in row) / 4000.0
        - math.prod(math.cos(x / math.sqrt(i + 1)) for i, x in enumerate(row))
        for row in X
    ]
    assert np.allclose(griewank(X), expected, rtol=1e-13, atol=0.0)
    assert griewank(np.zeros((1, 30)))[0] == 0.0


def test_greedy_gwo_two_iterations_reproduced_wolf_by_wolf():
    # mealpy's OriginalGWO selection written as its per-wolf loop (get_better_agent: ties keep
    # the old wolf), fed the documented draw layout; leaders are the best three points seen.
    n, d = 6, 3
    lower, upper = -np.ones(d), 2.0 * np.ones(d)
    result = minimize(
        rastrigin, lower, upper, "gwo", population=n, iterations=2, seed=5, options={"selection": "greedy"}
    )

    rng = np.random.default_rng(5)
    wolves = lower + rng.random((n, d)) * (upper - lower)
    costs = rastrigin(wolves)
    seen_x, seen_f = wolves.copy(), costs.copy()
    for a in (2.0, 1.0):  # linear a(t) = 2 (1 - t/T) at t = 0, 1 of T = 2
        draws = rng.random((6, n, d))
        order = np.argsort(seen_f, kind="stable")[:3]
        alpha, beta, delta = seen_x[order]
        moved = np.clip(gwo_update(wolves, alpha, beta, delta, a, draws), lower, upper)
        moved_costs = rastrigin(moved)
        seen_x, seen_f = np.vstack([seen_x, moved]), np.concatenate([seen_f, moved_costs])
        for i in range(n):
            if moved_costs[i] < costs[i]:
                wolves[i], costs[i] = moved[i], moved_costs[i]
    assert np.array_equal(result.population, wolves)
    assert result.fun == seen_f.min()


def test_greedy_gwo_never_moves_a_wolf_to_a_worse_point():
    # Runs of 1..T iterations share their draws (the documented layout) and, with a constant
    # a, their schedule, so consecutive runs' final populations are one pack a step apart.
    lower, upper = -5.12 * np.ones(5), 5.12 * np.ones(5)

    def packs(**selection):
        options = {"a_initial": 1.0, "a_final": 1.0, **selection}
        start = lower + np.random.default_rng(3).random((8, 5)) * (upper - lower)
        runs = [
            minimize(rastrigin, lower, upper, "gwo", population=8, iterations=t, seed=3, options=options)
            for t in range(1, 9)
        ]
        return [rastrigin(start)] + [rastrigin(run.population) for run in runs]

    greedy, plain = packs(selection="greedy"), packs()
    assert all(np.all(after <= before) for before, after in zip(greedy[:-1], greedy[1:], strict=True))
    assert any(np.any(after > before) for before, after in zip(plain[:-1], plain[1:], strict=True))


def test_update_functions_elementwise_formula():
    rng = np.random.default_rng(0)
    n, d = 3, 2
    X, P = rng.normal(size=(n, d)), rng.normal(size=(n, d))
    L = rng.normal(size=(3, d))
    r = rng.random((8, n, d))
    a, w = 1.3, 0.6
    moves = [L[j] - (2 * a * r[2 * j] - a) * np.abs(2 * r[2 * j + 1] * L[j] - X) for j in range(3)]
    G = sum(moves) / 3
    assert np.allclose(gwo_update(X, *L, a, r[:6]), G, rtol=1e-15, atol=0)
    g = L[0] + 0.1
    expected = w * G + 0.5 * r[6] * (P - X) + 0.5 * r[7] * (g - X)
    assert np.allclose(igwo_update(X, P, *L, g, a, w, r), expected, rtol=1e-14, atol=1e-15)
    # frame centred on the anchor: GWO moves and inertia act on X - anchor
    Lc, Xc = L - L[0], X - L[0]
    Gc = sum(Lc[j] - (2 * a * r[2 * j] - a) * np.abs(2 * r[2 * j + 1] * Lc[j] - Xc) for j in range(3)) / 3
    anchored = L[0] + w * Gc + 0.5 * r[6] * (P - X) + 0.5 * r[7] * (g - X)
    got = igwo_update(X, P, *L, g, a, w, r, anchor=L[0])
    assert np.allclose(got, anchored, rtol=1e-13, atol=1e-14)


# -- convergence factor -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kind, quarter",
    [
        ("linear", 1.5),
        ("cosine", 1.0 + np.cos(np.pi / 4)),
        ("faster", 2 * (1 - 1 / 16)),
        ("slower", 2 * (3 / 4) ** 2),
    ],
)
def test_convergence_factor_values(kind, quarter):
    T = 40
    assert convergence_factor(0, T, kind) == pytest.approx(2.0, abs=1e-15)
    assert convergence_factor(T, T, kind) == pytest.approx(0.0, abs=1e-15)
    half = {"linear": 1.0, "cosine": 1.0, "faster": 1.5, "slower": 0.5}[kind]
    assert convergence_factor(T / 2, T, kind) == pytest.approx(half, abs=1e-15)
    assert convergence_factor(T / 4, T, kind) == pytest.approx(quarter, abs=1e-15)
    curve = convergence_factor(np.arange(T + 1), T, kind)
    assert curve.shape == (T + 1,)
    assert np.all(np.diff(curve) <= 0)


def test_convergence_factor_cosine_slower_than_linear_early_faster_late():
    T = 100
    assert convergence_factor(10, T, "cosine") > convergence_factor(10, T, "linear")
    assert convergence_factor(90, T, "cosine") < convergence_factor(90, T, "linear")
    assert convergence_factor(50, T, "cosine", a_initial=3.0, a_final=1.0) == pytest.approx(2.0)


# -- validation ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"population": 3}, "population"),
        ({"population": 0}, "population"),
        ({"population": 20.0}, "population"),
        ({"population": True}, "population"),
        ({"iterations": 0}, "iterations"),
        ({"iterations": -5}, "iterations"),
        ({"iterations": 2.5}, "iterations"),
        ({"iterations": True}, "iterations"),
        ({"max_evaluations": 10.0}, "max_evaluations"),
        ({"max_evaluations": True}, "max_evaluations"),
        ({"max_evaluations": 5}, "max_evaluations"),
        ({"method": "bat"}, "method"),
        ({"initial_population": np.zeros((2, 3))}, "initial_population"),
        ({"initial_population": np.zeros(DIM)}, "initial_population"),
        ({"initial_population": np.zeros((21, DIM))}, "initial_population"),
        ({"initial_population": np.full((1, DIM), np.nan)}, "initial_population"),
        ({"options": {"w_start": 0.9}}, "options"),
        ({"options": {"c1": "big"}}, "options"),
        ({"options": {"convergence": "cubic"}}, "options"),
        ({"seed": True}, "seed"),
    ],
)
def test_bad_options_raise_naming_parameter(kwargs, name):
    kwargs = {"population": 20, **kwargs}
    with pytest.raises(ValueError, match=name) as info:
        minimize(sphere, LOWER, UPPER, **kwargs)
    message = str(info.value)
    if name == "method":
        for valid in METHODS:
            assert valid in message
    if name in ("population", "iterations", "max_evaluations"):
        assert repr(kwargs[name]) in message  # the value received
        assert ">=" in message  # the expected range


@pytest.mark.parametrize(
    "lower, upper, name",
    [
        (np.zeros(3), np.ones(4), "lower and upper"),
        (np.zeros((2, 2)), np.ones((2, 2)), "lower"),
        (np.zeros(0), np.ones(0), "lower"),
        (0.0, 1.0, "lower and upper"),
        (np.ones(3), np.ones(3), "lower"),
        (np.array([0.0, 2.0]), np.array([1.0, 1.0]), "lower"),
        (np.array([0.0, -np.inf]), np.ones(2), "lower and upper"),
        (np.zeros(2), np.array([1.0, np.nan]), "lower and upper"),
        ("a", np.ones(2), "lower"),
    ],
)
def test_bad_bounds_raise(lower, upper, name):
    with pytest.raises(ValueError, match=name):
        minimize(sphere, lower, upper, "igwo", population=5, iterations=2)


def test_bad_fun_output_raises():
    with pytest.raises(ValueError, match="fun"):
        minimize(lambda X: np.zeros(3), LOWER, UPPER, "gwo", population=5, iterations=2)
    with pytest.raises(ValueError, match="fun"):
        minimize(None, LOWER, UPPER)


@pytest.mark.parametrize(
    "output, shape",
    [
        (lambda X: np.zeros(3), "(3,)"),
        (lambda X: np.zeros(len(X) + 1), "(6,)"),
        (lambda X: np.zeros((len(X), 2)), "(5, 2)"),
        (lambda X: 1.0, "()"),
    ],
    ids=["short", "long", "two_columns", "scalar"],
)
def test_wrong_fun_output_shape_names_fun_and_both_shapes(output, shape):
    with pytest.raises(ValueError, match="fun") as info:
        minimize(output, LOWER, UPPER, "gwo", population=5, iterations=2)
    message = str(info.value)
    assert "(5,)" in message  # expected
    assert f"got shape {shape}" in message  # actual


def test_non_numeric_fun_output_raises_naming_fun():
    with pytest.raises(ValueError, match="fun must return 5 real costs"):
        minimize(lambda X: ["cheap"] * len(X), LOWER, UPPER, "igwo", population=5, iterations=2)


def test_fun_output_with_population_elements_is_flattened():
    # e.g. a CasADi map returns a (1, population) row: accepted, same result as (population,)
    flat = minimize(sphere, LOWER, UPPER, "igwo", population=6, iterations=3, seed=4)
    for fun in (lambda X: sphere(X)[None, :], lambda X: sphere(X)[:, None]):
        other = minimize(fun, LOWER, UPPER, "igwo", population=6, iterations=3, seed=4)
        assert np.array_equal(other.population, flat.population)
        assert other.fun == flat.fun


def test_convergence_factor_validation():
    with pytest.raises(ValueError, match="kind"):
        convergence_factor(1, 10, "exponential")
    with pytest.raises(ValueError, match="iterations"):
        convergence_factor(1, 0, "linear")


def test_registry_classes_share_the_base_loop():
    for name, cls in swarm.ALGORITHMS.items():
        assert issubclass(cls, swarm.PopulationAlgorithm)
        assert cls.name == name
        assert "run" not in vars(cls)  # one loop, in the base class


# -- against mealpy's reference implementations (slow) ------------------------------------------

# our method -> (mealpy module, class); igwo has no mealpy counterpart and is held to GWO
MEALPY = {
    "igwo": ("GWO", "OriginalGWO"),
    "gwo": ("GWO", "OriginalGWO"),
    "ssa": ("SSA", "OriginalSSA"),
    "pso": ("PSO", "OriginalPSO"),
}


def _mealpy_best(method, fun, bound, population, budget, seed):
    import importlib

    from mealpy import FloatVar

    module, cls = MEALPY[method]
    optimizer_cls = getattr(importlib.import_module(f"mealpy.swarm_based.{module}"), cls)
    per_epoch = population if method != "ssa" else 2 * population - int(0.1 * population)
    count = [0]

    def objective(x):
        count[0] += 1
        return float(fun(np.asarray(x, dtype=float)[None, :])[0])

    problem = {
        "bounds": FloatVar(lb=[-bound] * DIM, ub=[bound] * DIM),
        "minmax": "min",
        "obj_func": objective,
        "log_to": None,
    }
    model = optimizer_cls(epoch=(budget - population) // per_epoch, pop_size=population)
    best = model.solve(problem, seed=seed)
    assert count[0] <= budget
    return float(best.target.fitness)


@pytest.mark.slow
@pytest.mark.parametrize("method", sorted(MEALPY))  # mppi has no mealpy counterpart: see test_mppi.py
def test_against_mealpy_reference(method):
    pytest.importorskip("mealpy")
    seeds = 20
    floor = 1e-8
    # reduced budgets (the benchmark script runs the paper's): population × iterations
    population, iterations = {"igwo": (20, 30), "gwo": (20, 30), "ssa": (30, 30), "pso": (20, 30)}[method]
    budget = population * (iterations + 1)
    failures = []
    for fun, bound in [(sphere, 100.0), (rastrigin, 5.12), (rosenbrock, 30.0), (ackley, 32.768)]:
        ours = [
            minimize(
                fun,
                -bound * np.ones(DIM),
                bound * np.ones(DIM),
                method,
                population=population,
                iterations=iterations,
                seed=s,
            ).fun
            for s in range(seeds)
        ]
        theirs = [_mealpy_best(method, fun, bound, population, budget, s) for s in range(seeds)]
        ratio = max(np.median(ours), floor) / max(np.median(theirs), floor)
        if ratio > 10.0:
            failures.append((fun.__name__, np.median(ours), np.median(theirs), ratio))
    assert not failures, failures
