"""``options={"deadline": seconds}``: every backend stops at it, closed loops count the misses.

Swarms return their best so far, exact solvers stop, the NMPC falls back.  Wall-clock bounds
here are loose on purpose (20× the deadline plus a fixed overhead): the tests check that a
deadline stops the work, not how precisely.
"""

import math
import re
import time

import numpy as np
import pytest

import uuv_ocp as uo
from conftest import needs_compiler
from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.judge import instance_parameters
from uuv_ocp.optimize import minimize
from uuv_ocp.solvers import get_solver
from uuv_ocp.solvers.hybrid import SWARM_SHARE

SWARMS = ["igwo", "gwo", "ssa", "pso"]
OVERHEAD = 1.0  # s: fixed allowance on top of 20× the deadline (a loaded machine, Python)
BAD_DEADLINES = [0, 0.0, -1.0, math.nan, math.inf, -math.inf, "0.1", True, [0.1]]


def loosely_within(elapsed: float, deadline: float) -> bool:
    return elapsed < 20.0 * deadline + OVERHEAD


@pytest.fixture(scope="module")
def from_rest(s2_problem):
    """s2 from rest at t = 0 with the terminal equality: a hard instance (hard NLP infeasible).

    Without a deadline IPOPT needs ~340 iterations over two attempts here, sqp ~20 over two,
    fatrop ~500 over three.
    """
    return instance_parameters(s2_problem, np.zeros(6), 0.0)


@pytest.fixture(scope="module")
def moving(s2_problem, feasible_start):
    """Return a moving start with a nonzero last control, so that the first rate bound is active."""
    x0, t0 = feasible_start
    u_prev = np.array([900.0, -700.0, 400.0])
    return instance_parameters(s2_problem, x0, t0, u_prev=u_prev), u_prev


# --------------------------------------------------------------------- minimize (generic loop)
def test_minimize_time_limit_stops_a_slow_objective_with_the_best_so_far():
    calls = []

    def slow(population):
        time.sleep(0.005)
        costs = np.sum((population - 0.3) ** 2, axis=1)
        calls.append(costs.min())
        return costs

    limit = 0.1
    start = time.perf_counter()
    result = minimize(slow, -np.ones(4), np.ones(4), "pso", iterations=10_000, seed=0, time_limit=limit)
    elapsed = time.perf_counter() - start
    assert result.deadline_hit
    assert 1 <= result.iterations < 10_000
    assert len(calls) == result.iterations + 1  # the initial population and each iteration
    assert "deadline" in result.message and "time_limit" in result.message
    assert loosely_within(elapsed, limit)
    # the best so far: the least cost ever evaluated, at x
    assert result.fun == pytest.approx(min(calls), rel=0, abs=0)
    assert result.fun == pytest.approx(float(np.sum((result.x - 0.3) ** 2)), rel=1e-12)
    assert result.history[-1] == result.fun and len(result.history) == result.iterations + 1


def test_minimize_time_limit_not_reached_changes_nothing():
    def sphere(population):
        return np.sum(population**2, axis=1)

    free = minimize(sphere, -np.ones(3), np.ones(3), "igwo", iterations=30, seed=4)
    limited = minimize(sphere, -np.ones(3), np.ones(3), "igwo", iterations=30, seed=4, time_limit=1e6)
    assert not free.deadline_hit and not limited.deadline_hit
    assert limited.iterations == free.iterations == 30
    np.testing.assert_array_equal(limited.x, free.x)
    np.testing.assert_array_equal(limited.history, free.history)


@pytest.mark.parametrize("bad", BAD_DEADLINES)
def test_minimize_rejects_a_bad_time_limit(bad):
    with pytest.raises(ValueError, match="time_limit"):
        minimize(lambda x: np.sum(x**2, axis=1), -np.ones(2), np.ones(2), time_limit=bad)


# ------------------------------------------------------------------------------------ swarms
def assert_box_and_rate(problem, controls, u_prev, tolerance=1e-9):
    """Box and rate bounds of a plan; ``tolerance`` relative (an exact solver's: ~1e-8)."""
    vehicle = problem.vehicle
    assert np.all(np.abs(controls) <= np.asarray(vehicle.max_thrust) * (1 + 1e-12))
    bound = np.asarray(vehicle.max_thrust_rate) * problem.dt
    increments = np.abs(np.diff(np.vstack([u_prev, controls]), axis=0))
    assert np.max(increments - bound) <= tolerance * np.max(bound)


@pytest.mark.parametrize("method", SWARMS)
def test_swarm_deadline_returns_the_best_so_far_inside_box_and_rate_bounds(s2_problem, moving, method):
    p, u_prev = moving
    deadline, budget = 0.05, 100_000
    backend = get_solver(s2_problem, method, {"iterations": budget, "deadline": deadline})
    result = backend.solve(p, None, np.random.default_rng(3))
    assert result.details["deadline_hit"] is True
    assert 0 <= result.iterations < budget
    assert "deadline" in result.status
    assert loosely_within(result.solve_time, deadline)
    assert_box_and_rate(s2_problem, result.controls, u_prev)
    # the best so far: the fitness is the last (and least) entry of the best-so-far history
    assert result.details["fitness"] == result.history[-1] == np.min(result.history)
    assert len(result.history) == result.iterations + 1


def test_swarm_without_deadline_reports_no_hit(s2_problem, moving):
    p, _ = moving
    result = get_solver(s2_problem, "igwo", {"iterations": 5}).solve(p, None, np.random.default_rng(0))
    assert result.details["deadline_hit"] is False
    assert result.iterations == 5 and "deadline" not in result.status


@needs_compiler
def test_compiled_igwo_with_a_deadline_runs_the_python_loop_on_the_compiled_fitness(tmp_path, monkeypatch):
    """With a deadline, compiled IGWO runs the Python loop on the same compiled fitness.

    The all-C step cannot stop between iterations.  The loop draws the same random numbers (the
    same result when the deadline is not reached) and stops at a tiny deadline.
    """
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "cache"))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4)
    p = instance_parameters(problem, problem.reference.initial_state(0.0), 0.0)
    native = get_solver(problem, "igwo", {"compiled": True, "seed": 0})
    assert native.native is not None
    loose = get_solver(problem, "igwo", {"compiled": True, "seed": 0, "deadline": 1e6})
    expected = native.solve(p, None, np.random.default_rng(5))
    actual = loose.solve(p, None, np.random.default_rng(5))
    assert "compiled C step" in expected.status and "compiled C step" not in actual.status
    assert actual.details["deadline_hit"] is False and actual.iterations == expected.iterations
    np.testing.assert_allclose(actual.history, expected.history, rtol=1e-12)
    # a full search took far less than half the deadline: the next one may run the C step
    again = loose.solve(p, None, np.random.default_rng(5))
    assert "compiled C step" in again.status and again.details["deadline_hit"] is False
    np.testing.assert_allclose(again.history, expected.history, rtol=1e-12)
    tight = get_solver(problem, "igwo", {"compiled": True, "seed": 0, "iterations": 10**7, "deadline": 0.02})
    stopped = tight.solve(p, None, np.random.default_rng(5))
    assert stopped.details["deadline_hit"] is True and stopped.iterations < 10**7
    assert loosely_within(stopped.solve_time, 0.02)


# ------------------------------------------------------------------------------ exact solvers
@pytest.mark.parametrize("name", ["ipopt", "sqp"])
def test_exact_solver_stops_inside_an_attempt_at_the_deadline(s2_problem, from_rest, name):
    """IPOPT and sqpmethod stop between two iterations (CasADi's iteration_callback)."""
    free = get_solver(s2_problem, name).solve(from_rest)
    assert free.success and len(free.details["attempts"]) >= 2
    deadline = 1e-3
    backend = get_solver(s2_problem, name, {"deadline": deadline})
    backend.solve(from_rest)  # builds the plugin, which the timed solve must not include
    start = time.perf_counter()
    result = backend.solve(from_rest)
    elapsed = time.perf_counter() - start
    assert loosely_within(elapsed, deadline)
    assert result.success is False
    assert result.status.startswith("deadline")
    assert result.details["deadline_hit"] is True
    # one attempt, stopped inside: fewer iterations than the free solve's first attempt
    ((variant, status, iterations),) = result.details["attempts"]
    assert variant == "hard" and "stopped by the deadline" in status
    assert iterations < free.details["attempts"][0][2]
    assert result.details["attempts_skipped"] >= 1


@pytest.mark.parametrize("name", ["ipopt", "sqp"])
def test_time_limit_of_one_solve_is_enforced_inside_the_attempt(s2_problem, from_rest, name):
    """``solve(time_limit=)`` (what a hybrid's exact stage gets) below the built-in deadline.

    IPOPT's own ``max_wall_time`` is the 10 s deadline here: only the iteration callback, which
    reads what is left of this call's limit, can stop the attempt.
    """
    free = get_solver(s2_problem, name).solve(from_rest)
    backend = get_solver(s2_problem, name, {"deadline": 10.0})
    backend.solve(from_rest, time_limit=1e-3)  # builds the plugin
    result = backend.solve(from_rest, time_limit=1e-3)
    assert result.success is False and result.details["deadline_hit"] is True
    ((variant, status, iterations),) = result.details["attempts"]
    assert "stopped by the deadline" in status
    assert iterations < free.details["attempts"][0][2]
    assert loosely_within(result.solve_time, 1e-3)


def test_ipopt_gets_its_own_wall_and_cpu_time_limits(s2_problem):
    backend = get_solver(s2_problem, "ipopt", {"deadline": 0.25})
    options = backend.plugin_defaults(backend.variants["hard"])
    assert options["ipopt.max_wall_time"] == options["ipopt.max_cpu_time"] == 0.25
    assert "ipopt.max_wall_time" not in get_solver(s2_problem, "ipopt").plugin_defaults(
        backend.variants["hard"]
    )


def test_a_solve_that_succeeds_after_the_deadline_is_a_miss(s2_problem, feasible_start):
    """Fatrop cannot be stopped: its attempt converges, but too late to be used."""
    x0, t0 = feasible_start
    p = instance_parameters(s2_problem, x0, t0)
    backend = get_solver(s2_problem, "fatrop", {"deadline": 1e-7})
    result = backend.solve(p)
    ((variant, status, _),) = result.details["attempts"]
    assert get_solver(s2_problem, "fatrop").solve(p).success  # the same attempt converges
    assert result.success is False and result.details["deadline_hit"] is True
    assert result.status.startswith("deadline") and result.details["attempts_skipped"] == 0


def test_fatrop_deadline_starts_no_new_attempt(s2_problem, from_rest):
    """Fatrop finishes the attempt that runs, but no further attempt starts after the deadline.

    CasADi 3.8's fatrop interface offers no time limit and calls no iteration callback.
    """
    free = get_solver(s2_problem, "fatrop").solve(from_rest)
    assert len(free.details["attempts"]) >= 2
    result = get_solver(s2_problem, "fatrop", {"deadline": 1e-3}).solve(from_rest)
    assert result.success is False and result.details["deadline_hit"] is True
    assert result.status.startswith("deadline")
    assert len(result.details["attempts"]) == 1
    assert result.iterations < free.iterations


@pytest.mark.parametrize("name", ["ipopt", "fatrop", "sqp"])
def test_exact_solver_deadline_not_reached_changes_nothing(s2_problem, feasible_start, name):
    x0, t0 = feasible_start
    p = instance_parameters(s2_problem, x0, t0)
    free = get_solver(s2_problem, name).solve(p)
    limited = get_solver(s2_problem, name, {"deadline": 1e3}).solve(p)
    assert free.success and limited.success
    assert limited.details["deadline_hit"] is False and free.details["deadline_hit"] is False
    assert limited.status == free.status and limited.iterations == free.iterations
    np.testing.assert_allclose(limited.controls, free.controls, rtol=1e-9, atol=1e-9)


def test_stopped_hard_attempt_hands_the_next_solve_to_the_soft_nlp(s2_problem, from_rest):
    """A stopped hard attempt's iterate sends the next solve to the soft NLP (sticky).

    A closed loop keeps a stopped solve's iterate: a hard NLP that never finishes in time must
    not block the always-feasible soft NLP forever.
    """
    backend = get_solver(s2_problem, "ipopt", {"deadline": 1e-3})
    first = backend.solve(from_rest)
    assert first.details["attempts"][0][0] == "hard" and first.iterate.terminal_relaxed
    second = backend.solve(from_rest, first.iterate)
    assert second.details["attempts"][0][0] == "soft"


# ------------------------------------------------------------------------------------ hybrids
class Spy:
    """Wrap a backend and record the ``time_limit`` each solve gets."""

    def __init__(self, backend, sleep=0.0):
        self.backend, self.sleep, self.limits = backend, sleep, []
        self.name, self.problem = backend.name, backend.problem

    def solve(self, p, warm_start=None, rng=None, *, time_limit=None):
        self.limits.append(time_limit)
        time.sleep(self.sleep)
        return self.backend.solve(p, warm_start, rng, time_limit=time_limit)


def test_hybrid_gives_its_swarm_a_share_and_the_exact_stage_the_rest(s2_problem, moving):
    p, u_prev = moving
    deadline = 0.2
    hybrid = get_solver(s2_problem, "pso+ipopt", {"deadline": deadline, "swarm": {"iterations": 100_000}})
    hybrid.second.solve(p)  # build the exact stage's plugin outside the timed solve
    swarm, exact = Spy(hybrid.first), Spy(hybrid.second)
    hybrid.first, hybrid.second = swarm, exact
    try:
        result = hybrid.solve(p, None, np.random.default_rng(0))
    finally:
        hybrid.first, hybrid.second = swarm.backend, exact.backend
    assert swarm.limits == [pytest.approx(SWARM_SHARE * deadline)]
    assert result.details["swarm_deadline_hit"] is True
    (rest,) = exact.limits
    assert 0.0 < rest <= (1.0 - SWARM_SHARE) * deadline + 1e-9
    assert loosely_within(result.solve_time, deadline)
    if result.details["deadline_hit"]:  # the exact stage was stopped: its iterate is no plan
        assert result.success is False and result.status.startswith("deadline")
    else:  # an interior-point plan holds the rate bound to IPOPT's tolerance
        assert_box_and_rate(s2_problem, result.controls, u_prev, tolerance=1e-7)


def test_hybrid_starts_no_exact_stage_when_the_swarm_used_the_deadline(s2_problem, moving):
    p, _ = moving
    hybrid = get_solver(s2_problem, "igwo+fatrop", {"deadline": 0.01, "swarm": {"iterations": 3}})
    swarm, exact = Spy(hybrid.first, sleep=0.05), Spy(hybrid.second)
    hybrid.first, hybrid.second = swarm, exact
    try:
        result = hybrid.solve(p, None, np.random.default_rng(0))
    finally:
        hybrid.first, hybrid.second = swarm.backend, exact.backend
    assert exact.limits == []
    assert result.details["deadline_hit"] is True and result.status.startswith("deadline")
    assert result.solver == "igwo+fatrop"


def test_hybrid_deadline_needs_halves_that_take_a_time_limit(s2_problem):
    from uuv_ocp.solvers import REGISTRY

    class Plain:
        name = "plain"

        def __init__(self, problem, options=None):
            self.problem = problem

        def solve(self, p, warm_start=None, rng=None):
            raise AssertionError("never called")

    REGISTRY.register("plain-exact-for-deadline", Plain, kind="exact", overwrite=True)
    try:
        get_solver(s2_problem, "igwo+plain-exact-for-deadline")  # fine without a deadline
        with pytest.raises(ValueError, match=r"options\['deadline'\].*time_limit"):
            get_solver(s2_problem, "igwo+plain-exact-for-deadline", {"deadline": 0.1})
    finally:
        REGISTRY._factories.pop("plain-exact-for-deadline", None)


# -------------------------------------------------------------------------------- multistart
def test_multistart_starts_nothing_after_the_deadline(s2_problem, from_rest):
    deadline = 0.05
    backend = get_solver(s2_problem, "multistart-ipopt", {"starts": 8, "deadline": deadline})
    spy = Spy(backend.exact)
    backend.exact = spy
    try:
        backend.solve(from_rest)  # builds the plugins
        spy.limits.clear()
        result = backend.solve(from_rest)
    finally:
        backend.exact = spy.backend
    assert result.details["deadline_hit"] is True
    assert 1 <= len(result.details["starts"]) < 8
    assert result.details["starts_skipped"] == 8 - len(result.details["starts"])
    # each start gets what is left: decreasing, never more than the deadline
    assert spy.limits == sorted(spy.limits, reverse=True) and spy.limits[0] <= deadline
    assert loosely_within(result.solve_time, deadline)


def test_multistart_deadline_not_reached_reports_no_hit(s2_problem, feasible_start):
    x0, t0 = feasible_start
    p = instance_parameters(s2_problem, x0, t0)
    result = get_solver(s2_problem, "multistart-fatrop", {"starts": 2, "deadline": 1e3}).solve(p)
    assert result.success and result.details["deadline_hit"] is False
    assert len(result.details["starts"]) == 2 and result.details["starts_skipped"] == 0


# ------------------------------------------------------------------------------- closed loop
def test_closed_loop_with_a_deadline_too_small_counts_misses_and_never_crashes(s2_problem, tmp_path):
    controller = uo.NMPC(s2_problem, "sqp", options={"deadline": 1e-4})
    run = uo.simulate(controller, np.zeros(6), 1.0)
    steps = run.controls.shape[0]
    assert steps == 10 and not run.interrupted
    assert run.deadline_steps.dtype == bool and run.deadline_steps.shape == (steps,)
    assert run.deadline_misses == int(np.sum(run.deadline_steps)) >= steps - 1
    # an exact solver's miss is a failure: the fallback control was applied
    assert np.all(run.fallback_steps[run.deadline_steps])
    assert all(
        status.startswith("deadline")
        for status, hit in zip(run.statuses, run.deadline_steps, strict=True)
        if hit
    )
    assert_box_and_rate(s2_problem, run.controls, np.zeros(3))
    metrics = run.metrics()
    assert isinstance(metrics["deadline_misses"], int) and metrics["deadline_misses"] == run.deadline_misses
    path = tmp_path / "run.npz"
    run.save(str(path))
    loaded = ClosedLoopResult.load(str(path))
    np.testing.assert_array_equal(loaded.deadline_steps, run.deadline_steps)
    assert loaded.deadline_misses == run.deadline_misses


def test_a_miss_keeps_the_stopped_iterate_as_the_next_warm_start(s2_problem):
    controller = uo.NMPC(s2_problem, "ipopt", options={"deadline": 1e-3})
    output = controller.step(np.zeros(6), 0.0, np.zeros(3))
    assert output.deadline_hit and output.fallback
    np.testing.assert_array_equal(controller.iterate.primal, output.result.iterate.shift().primal)


def test_closed_loop_swarm_deadline_hits_are_counted_and_feasible_plans_applied(s2_problem):
    controller = uo.NMPC(s2_problem, "pso", options={"iterations": 100_000, "deadline": 0.02}, seed=0)
    run = uo.simulate(controller, s2_problem.reference.initial_state(0.0), 0.5)
    assert run.deadline_misses == run.controls.shape[0] == 5
    assert not np.any(run.fallback_steps)  # the best plan so far is feasible and applied
    assert run.metrics()["deadline_misses"] == 5


def test_closed_loop_without_a_deadline_has_no_misses(s2_problem, tmp_path):
    run = uo.simulate(uo.NMPC(s2_problem, "fatrop"), s2_problem.reference.initial_state(0.0), 0.3)
    assert run.deadline_misses == 0 and run.metrics()["deadline_misses"] == 0
    assert not np.any(run.deadline_steps)
    # a result saved before deadline_steps existed loads with no misses
    path = tmp_path / "old.npz"
    run.save(str(path))
    with np.load(path) as data:
        arrays = {key: data[key] for key in data.files if key != "deadline_steps"}
    np.savez_compressed(path, **arrays)
    old = ClosedLoopResult.load(str(path))
    assert old.deadline_misses == 0 and old.deadline_steps.shape == run.fallback_steps.shape


# ---------------------------------------------------------------------------------- validation
@pytest.mark.parametrize("name", ["ipopt", "fatrop", "sqp", "igwo", "pso", "igwo+ipopt", "multistart-ipopt"])
@pytest.mark.parametrize("bad", BAD_DEADLINES)
def test_bad_deadline_raises_naming_the_option(s2_problem, name, bad):
    # a hybrid or a multistart checks its own option (naming itself) before it builds a backend
    composite = "+" in name or name.startswith("multistart-")
    expected = r"options\['deadline'\]" + (f" of '{re.escape(name)}'" if composite else "")
    with pytest.raises(ValueError, match=expected):
        get_solver(s2_problem, name, {"deadline": bad})


@pytest.mark.parametrize("name", ["ipopt", "igwo"])
def test_bad_time_limit_of_one_solve_raises(s2_problem, from_rest, name):
    backend = get_solver(s2_problem, name)
    with pytest.raises(ValueError, match="time_limit"):
        backend.solve(from_rest, time_limit=-1.0)
