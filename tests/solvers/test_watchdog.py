"""``options={"deadline": seconds}``: every backend stops at it, closed loops count the misses.

Swarms return their best so far, exact solvers stop, the NMPC falls back.  No test asserts a
wall-clock time (a loaded machine makes any bound flaky): the exact solvers' and the hybrids'
deadlines run on :func:`uuv_ocp.solvers.watchdog.now`, which the tests replace by a fake
clock, so a deadline expires at a known clock read; how precisely a deadline holds in wall
time is measured by ``benchmarks/bench_deadline.py``.
"""

import math
import os
import re
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.judge import instance_parameters
from uuv_ocp.optimize import minimize
from uuv_ocp.solvers import get_solver, new_solver, watchdog
from uuv_ocp.solvers.hybrid import SWARM_SHARE
from uuv_ocp.solvers.result import Stage

SWARMS = ["igwo", "gwo", "ssa", "pso"]
BAD_DEADLINES = [0, 0.0, -1.0, math.nan, math.inf, -math.inf, "0.1", True, [0.1]]


class FakeClock:
    """A stand-in for ``watchdog.now``: ``tick`` seconds pass at every read, plus ``advance``."""

    def __init__(self, tick: float = 0.0) -> None:
        self.t, self.tick, self.reads = 1000.0, tick, 0

    def __call__(self) -> float:
        self.reads += 1
        self.t += self.tick
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds


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
    result = minimize(slow, -np.ones(4), np.ones(4), "pso", iterations=10_000, seed=0, time_limit=limit)
    assert result.deadline_hit
    assert 1 <= result.iterations < 10_000
    assert len(calls) == result.iterations + 1  # the initial population and each iteration
    assert "deadline" in result.message and "time_limit" in result.message
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


# ------------------------------------------------------------------------------ exact solvers
@pytest.mark.parametrize("name", ["ipopt", "sqp", "fatrop"])
def test_exact_solver_stops_inside_an_attempt_at_the_deadline(s2_problem, from_rest, name, monkeypatch):
    """The deadline expires at the 12th clock read; the attempt stops there, none follows.

    IPOPT and sqpmethod stop themselves (CasADi's iteration callback reads the clock once per
    iteration); fatrop runs in the watchdog's worker, killed when the clock read on one of its
    iteration lines is past the deadline.  Each read is 1000 fake seconds, so no real time limit
    (IPOPT's max_wall_time = the deadline) can interfere.
    """
    free = get_solver(s2_problem, name).solve(from_rest)
    assert free.success and len(free.details["attempts"]) >= 2
    first_free = free.details["attempts"][0][2]
    tick, reads = 1000.0, 5
    backend = get_solver(
        s2_problem,
        name,
        {"deadline": tick * reads, "stall_time": None} if name == "fatrop" else {"deadline": tick * reads},
    )
    backend.solve(from_rest)  # builds the plugin (and forks fatrop's worker) on the real clock
    clock = FakeClock(tick)
    monkeypatch.setattr(watchdog, "now", clock)
    result = backend.solve(from_rest)
    assert result.success is False
    assert result.status.startswith("deadline")
    assert result.details["deadline_hit"] is True
    ((variant, status, iterations),) = result.details["attempts"]  # one attempt, stopped inside
    assert variant == "hard" and "stopped by the deadline" in status
    assert iterations < reads and iterations < first_free
    assert result.details["attempts_skipped"] >= 1


@pytest.mark.parametrize("name", ["ipopt", "sqp"])
def test_time_limit_of_one_solve_is_enforced_inside_the_attempt(s2_problem, from_rest, name, monkeypatch):
    """``solve(time_limit=)`` (what a hybrid's exact stage gets) below the built-in deadline.

    IPOPT's own ``max_wall_time`` is the 1e6 s deadline here: only the iteration callback, which
    reads what is left of this call's limit, can stop the attempt.
    """
    free = get_solver(s2_problem, name).solve(from_rest)
    backend = get_solver(s2_problem, name, {"deadline": 1e6})
    backend.solve(from_rest)  # builds the plugin
    monkeypatch.setattr(watchdog, "now", FakeClock(1.0))
    result = backend.solve(from_rest, time_limit=10.0)
    assert result.success is False and result.details["deadline_hit"] is True
    ((variant, status, iterations),) = result.details["attempts"]
    assert "stopped by the deadline" in status
    assert iterations < 10 < free.details["attempts"][0][2]


def test_ipopt_gets_its_own_wall_and_cpu_time_limits(s2_problem):
    backend = get_solver(s2_problem, "ipopt", {"deadline": 0.25})
    options = backend.plugin_defaults(backend.variants["hard"])
    assert options["ipopt.max_wall_time"] == options["ipopt.max_cpu_time"] == 0.25
    assert "ipopt.max_wall_time" not in get_solver(s2_problem, "ipopt").plugin_defaults(
        backend.variants["hard"]
    )


@pytest.mark.parametrize("name", ["ipopt", "fatrop"])
def test_a_solve_that_succeeds_after_the_deadline_is_a_miss(s2_problem, feasible_start, name, monkeypatch):
    """The attempt converges, but the clock says it ended past the deadline: no plan in time."""
    x0, t0 = feasible_start
    p = instance_parameters(s2_problem, x0, t0)
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    backend = get_solver(s2_problem, name, {"deadline": 1.0})
    attempt = backend._attempt

    def late(*args, **kwargs):
        outcome = attempt(*args, **kwargs)
        clock.advance(5.0)  # the attempt "took" 5 s: it has returned, nothing stopped it
        return outcome

    monkeypatch.setattr(backend, "_attempt", late)
    result = backend.solve(p)
    ((variant, status, _),) = result.details["attempts"]
    assert "stopped" not in status and get_solver(s2_problem, name).solve(p).success
    assert result.success is False and result.details["deadline_hit"] is True
    assert result.status.startswith("deadline") and result.details["attempts_skipped"] == 0


def test_building_a_plugin_in_a_solve_is_not_part_of_its_deadline(s2_problem, feasible_start, monkeypatch):
    """A plugin built on first use "takes" 100× the deadline on the fake clock: no miss, the time reported."""
    x0, t0 = feasible_start
    p = instance_parameters(s2_problem, x0, t0)
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    backend = new_solver(s2_problem, "ipopt", {"deadline": 1.0})  # unbuilt: not the thread's cached one
    build = backend._solver

    def slow_build(*key):
        fresh = tuple(key) not in backend._solvers
        solver = build(*key)
        if fresh:
            clock.advance(100.0)
        return solver

    monkeypatch.setattr(backend, "_solver", slow_build)
    result = backend.solve(p)
    assert result.success and result.details["deadline_hit"] is False
    assert result.details["build_time"] == pytest.approx(100.0)
    again = backend.solve(p)  # built: nothing to exclude
    assert again.success and "build_time" not in again.details


@pytest.mark.parametrize("name", ["ipopt", "fatrop", "sqp"])
def test_build_ahead_builds_every_plugin_of_the_fallback_chain(s2_problem, name):
    backend = get_solver(s2_problem, name, {"deadline": 1.0})
    backend.build(instance_parameters(s2_problem, np.zeros(6), 0.0))
    built = set(backend._solvers)
    for variant in backend.variants:
        assert (variant, Stage.PLAIN, True) in built
        assert bool(backend.robust_options()) == ((variant, Stage.ROBUST, True) in built)
        assert bool(backend.rescue_options()) == ((variant, Stage.RESCUE, True) in built)


@pytest.mark.parametrize("name", ["ipopt", "fatrop", "sqp", "sqp-rti"])
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


# ------------------------------------------------------------------------------------ watchdog
class Scripted:
    """A stand-in plugin for the watchdog's worker: ``lines`` iteration lines, then a hang or a result."""

    def __init__(self, lines: int, hang: bool) -> None:
        self.lines, self.hang = lines, hang

    def __call__(self, x):
        for k in range(self.lines):
            os.write(1, f"{k:4d}  1.00000000e+00 1.0e-01 1.0e-01   -4.0\n".encode())
        if self.hang:
            time.sleep(3600)
        return [2.0 * np.asarray(x)]

    def stats(self):
        return {"return_status": "done", "iter_count": self.lines, "success": True}


def scripted(key):
    return Scripted(*key)


needs_fork = pytest.mark.skipif(not watchdog.CAN_WATCH, reason="no os.fork: nothing is watched")


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@needs_fork
def test_watchdog_worker_serves_calls_in_one_process():
    worker = watchdog.Worker(scripted)
    (first,), stats = worker.call((3, False), (np.arange(3.0),))
    pid = worker._pid
    (second,), _ = worker.call((2, False), (np.ones(2),))
    np.testing.assert_array_equal(first, [0.0, 2.0, 4.0])
    np.testing.assert_array_equal(second, [2.0, 2.0])
    assert stats == {"return_status": "done", "iter_count": 3, "success": True}
    assert worker._pid == pid and worker.iterations_seen == 1  # lines 0 and 1 of the second call
    worker.restart()
    assert gone(pid)


@needs_fork
@pytest.mark.parametrize(
    ("key", "limits", "reason"),
    [
        ((50, True), {"max_iter": 9}, "max_iter"),  # lines past max_iter (restoration counts)
        ((3, True), {"stall": 0.2}, "stall"),  # no line for 0.2 s: one iteration never ends
    ],
)
def test_watchdog_kills_a_plugin_that_runs_on(key, limits, reason):
    worker = watchdog.Worker(scripted)
    worker.call((1, False), (np.ones(1),))
    pid = worker._pid
    with pytest.raises(watchdog.Stopped) as stopped:
        worker.call(key, (np.ones(1),), **limits)
    assert stopped.value.reason == reason and "killed by the watchdog" in str(stopped.value)
    assert gone(pid) and not worker.alive
    (again,), _ = worker.call((1, False), (np.ones(1),))  # a fresh worker serves the next call
    assert again[0] == 2.0 and worker._pid != pid
    worker.restart()


@needs_fork
def test_watchdog_kills_at_the_deadline_read_on_its_clock(monkeypatch):
    """The deadline is a time of ``watchdog.now``: a fake clock past it stops the hanging call."""
    clock = FakeClock(tick=1.0)
    monkeypatch.setattr(watchdog, "now", clock)
    worker = watchdog.Worker(scripted)
    with pytest.raises(watchdog.Stopped) as stopped:
        worker.call((3, True), (np.ones(1),), at=clock.t + 5.0)
    assert stopped.value.reason == "deadline" and not worker.alive


@needs_fork
def test_watchdog_replaces_an_idle_worker_that_is_gone():
    """A worker killed between calls (its forking thread ended: PDEATHSIG) is replaced, not an error."""
    worker = watchdog.Worker(scripted)
    worker.call((1, False), (np.ones(1),))
    pid = worker._pid
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    (again,), _ = worker.call((1, False), (np.ones(1),))
    assert again[0] == 2.0 and worker._pid != pid
    worker.restart()


@needs_fork
def test_watchdog_reports_a_worker_that_died():
    class Dies(Scripted):
        def __call__(self, x):
            os._exit(3)

    worker = watchdog.Worker(lambda key: Dies(0, False))
    with pytest.raises(watchdog.CrashedWorker):
        worker.call(0, (np.ones(1),))
    assert not worker.alive


BLUEROV2_IN_A_CURRENT = textwrap.dedent(
    """
    import sys
    import uuv_ocp as uo
    from uuv_ocp.solvers import get_solver, watchdog

    watchdog.CAN_WATCH = sys.argv[1] == "watched"
    vehicle = uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(vehicle, uo.Reference.hold((0.0, 0.0, 0.0, 0.0)), horizon=10)
    # step 35 of a fatrop closed loop holding station in a 1.5 m/s current (issue 31)
    x0 = [1.4206260493835023, 1.1158712275703272e-11, -0.03877638823942572,
          -1.7172327839149292e-10, 0.7275786583635646, 3.96639272507664e-11,
          0.2910201050628715, 3.283480246084205e-11, 0.23592909962360034,
          -2.604099871864497e-09, 0.3073024338716981, 5.0529192496440165e-11]
    u_prev = [-40.0, -40.0, 40.0, 40.0, 40.0, -40.0, -24.843441074762723, 24.843441023115055]
    p = problem.parameters(x0, 3.4, u_prev=u_prev, current=[1.5, 0.0, 0.0])
    backend = get_solver(problem, "fatrop", {"terminal_strategy": "soft", "stall_time": 2.0})
    result = backend.solve(p)
    print(repr(result.details["attempts"]))
    print("success" if result.success else "failure", flush=True)
    """
)


@needs_fork
def test_fatrop_that_hangs_in_a_current_is_stopped_and_the_fallback_solves_the_step():
    """BlueROV2 Heavy, 8 thrusters, 1.5 m/s current: fatrop's restoration never ends an iteration.

    Its first attempt (the soft NLP from the cold guess) reaches restoration iteration 37 and then
    loops inside the search direction for good (16 min seen; ``max_iter`` is checked only between
    iterations).  The watchdog stops it after ``stall_time`` = 2 s without an iteration, and the
    robust retry solves the step.  Run in a subprocess under a timeout: without the watchdog
    (``watchdog.CAN_WATCH = False``) the timeout expires and the test fails instead of hanging.
    """
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    try:
        done = subprocess.run(
            [sys.executable, "-c", BLUEROV2_IN_A_CURRENT, "watched"],
            capture_output=True,
            text=True,
            timeout=900,
            env=env,
        )
    except subprocess.TimeoutExpired:
        pytest.fail("fatrop on the BlueROV2 in a 1.5 m/s current did not return within 900 s")
    assert done.returncode == 0, done.stderr[-2000:]
    attempts_line, outcome = done.stdout.strip().splitlines()[-2:]
    assert "killed by the watchdog: no iteration finished for 2 s" in attempts_line
    assert outcome == "success"


# ------------------------------------------------------------------------------------ hybrids
class Spy:
    """Wrap a backend and record the ``time_limit`` each solve gets.

    ``clock``/``takes``: the fake clock advanced by ``takes`` seconds per solve (the stage's
    duration as the hybrid sees it), whatever the real time.
    """

    def __init__(self, backend, clock=None, takes=0.0):
        self.backend, self.clock, self.takes, self.limits = backend, clock, takes, []
        self.name, self.problem = backend.name, backend.problem

    def solve(self, p, warm_start=None, rng=None, *, time_limit=None):
        self.limits.append(time_limit)
        result = self.backend.solve(p, warm_start, rng, time_limit=time_limit)
        if self.clock is not None:
            self.clock.advance(self.takes)
        return result


def spied_hybrid_solve(hybrid, p, swarm, exact):
    hybrid.first, hybrid.second = swarm, exact
    try:
        return hybrid.solve(p, None, np.random.default_rng(0))
    finally:
        hybrid.first, hybrid.second = swarm.backend, exact.backend


def test_hybrid_gives_its_swarm_a_share_and_the_exact_stage_the_rest(s2_problem, moving, monkeypatch):
    """On a fake clock the swarm stage takes 30 % of the deadline: the exact stage gets the other 70 %.

    The clock stands still inside the exact stage, so it converges and the deadline is met.  The
    deadline is long (1000 s) so that no real-time limit (IPOPT's max_wall_time) can stop it.
    """
    p, u_prev = moving
    deadline = 1000.0
    hybrid = get_solver(s2_problem, "pso+ipopt", {"deadline": deadline, "swarm": {"iterations": 50}})
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    swarm, exact = Spy(hybrid.first, clock, takes=0.3 * deadline), Spy(hybrid.second)
    result = spied_hybrid_solve(hybrid, p, swarm, exact)
    assert swarm.limits == [pytest.approx(SWARM_SHARE * deadline)]
    assert exact.limits == [pytest.approx(0.7 * deadline)]
    assert result.success and result.details["deadline_hit"] is False
    # an interior-point plan holds the rate bound to IPOPT's tolerance
    assert_box_and_rate(s2_problem, result.controls, u_prev, tolerance=1e-7)


def test_hybrid_reports_a_miss_when_its_exact_stage_ends_late(s2_problem, moving, monkeypatch):
    p, _ = moving
    deadline = 0.2
    hybrid = get_solver(s2_problem, "pso+ipopt", {"deadline": deadline, "swarm": {"iterations": 5}})
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    swarm, exact = Spy(hybrid.first, clock, takes=0.1 * deadline), Spy(hybrid.second, clock, takes=deadline)
    result = spied_hybrid_solve(hybrid, p, swarm, exact)
    assert exact.limits == [pytest.approx(0.9 * deadline)]
    assert result.details["deadline_hit"] is True


def test_hybrid_starts_no_exact_stage_when_the_swarm_used_the_deadline(s2_problem, moving, monkeypatch):
    p, _ = moving
    hybrid = get_solver(s2_problem, "igwo+fatrop", {"deadline": 0.01, "swarm": {"iterations": 3}})
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    swarm, exact = Spy(hybrid.first, clock, takes=0.05), Spy(hybrid.second)
    result = spied_hybrid_solve(hybrid, p, swarm, exact)
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
def test_multistart_starts_nothing_after_the_deadline(s2_problem, from_rest, monkeypatch):
    """Each start "takes" 0.02 s of a 0.05 s deadline on a fake clock: three starts, then none."""
    deadline = 0.05
    backend = get_solver(s2_problem, "multistart-ipopt", {"starts": 8, "deadline": deadline})
    clock = FakeClock()
    monkeypatch.setattr(watchdog, "now", clock)
    spy = Spy(backend.exact, clock, takes=0.02)
    backend.exact = spy
    try:
        result = backend.solve(from_rest)
    finally:
        backend.exact = spy.backend
    assert result.details["deadline_hit"] is True
    assert len(result.details["starts"]) == 3
    assert result.details["starts_skipped"] == 5
    # each start gets what is left of the deadline
    assert spy.limits == [pytest.approx(0.05), pytest.approx(0.03), pytest.approx(0.01)]


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
    # the one options parser names the option and the backend (a composite: itself, before any build)
    expected = r"options\['deadline'\]" + f" of '{re.escape(name)}'"
    with pytest.raises(ValueError, match=expected):
        get_solver(s2_problem, name, {"deadline": bad})


@pytest.mark.parametrize("name", ["ipopt", "igwo"])
def test_bad_time_limit_of_one_solve_raises(s2_problem, from_rest, name):
    backend = get_solver(s2_problem, name)
    with pytest.raises(ValueError, match="time_limit"):
        backend.solve(from_rest, time_limit=-1.0)


@pytest.mark.parametrize("bad", [0, -1.0, math.nan, "1", True, [1.0]])
def test_bad_stall_time_raises_naming_the_option(s2_problem, bad):
    with pytest.raises(ValueError, match=r"options\['stall_time'\]"):
        get_solver(s2_problem, "fatrop", {"stall_time": bad})
