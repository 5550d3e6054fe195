"""Threads: N closed loops in N threads give the controls of the same loops run one after another.

Each loop is its own ``NMPC`` (seeded) on the paper's s2 with the RexROV, a short horizon and a
few steps, stepping a plant integrated by the same RK4 (the plant is the test's own: built once,
evaluated through DM calls).  The loops start from different states, so a controller that reads
another's buffers or warm start gives other controls.  The threads start every step together (a
barrier), so their builds and solves overlap.
The sequential result is computed once per solver and compared with loops on one shared problem
and with loops on problems built inside the threads (equal problems give equal controls).
"""

import threading

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.solvers import REGISTRY

THREADS = 4
STEPS = 4
HORIZON = 6
SWARM = {"population": 8, "iterations": 6}
#: small budgets of the swarm-kind backends whose options are not a swarm's
SMALL = {"mppi": {"samples": 16, "iterations": 2}}
#: name -> (solver, options): every registered backend (a new one is tested here by
#: registering it), one hybrid and one multistart; sqp-rti runs its C step (hpipm-ocp) where a
#: compiler exists; "igwo-compiled" the all-C IGWO step with its random-number worker thread.
SOLVERS = {
    **{
        name: (name, SMALL.get(name, SWARM) if REGISTRY.kind(name) == "swarm" else None)
        for name in REGISTRY.names()
        if REGISTRY.kind(name) in ("exact", "swarm")
    },
    "igwo+sqp": ("igwo+sqp", {"swarm": SWARM}),
    "multistart-ipopt": ("multistart-ipopt", None),
    "igwo-compiled": ("igwo", {**SWARM, "compiled": True, "rng_thread": True}),
}


def make_problem(reference=None):
    """Return the paper's s2 on the RexROV, short horizon (each call a new problem object)."""
    return uo.TrackingProblem(uo.Vehicle.rexrov(), reference or uo.Reference.paper("s2"), horizon=HORIZON)


@pytest.fixture(scope="module")
def plant():
    problem = make_problem()
    return uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 4)


def closed_loop(problem, solver, index, plant, sync=lambda: None):
    """Run loop ``index`` (own start state and seed); ``sync()`` before each step; its controls."""
    name, options = SOLVERS[solver]
    controller = uo.NMPC(problem, name, options=options, seed=index)
    if (options or {}).get("compiled"):
        assert controller.backend.native is not None  # the all-C step, not the VM fallback
    state = problem.reference.initial_state(0.0) + 0.05 * (index + 1) * np.array([1, -1, 0.2, 0.1, 0, 0])
    control, controls = np.zeros(3), []
    for k in range(STEPS):
        sync()
        output = controller.step(state, k * problem.dt, control)
        control = output.control
        controls.append(control)
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    return np.array(controls)


def run_loops(solver, plant, *, threaded, problems):
    """Return the controls of loops 0..THREADS-1; ``problems(i)`` makes loop i's problem in its thread."""
    results = [None] * THREADS
    errors = []
    barrier = threading.Barrier(THREADS)

    def sync():
        if threaded:  # every step of the loops starts at once: their solves overlap
            barrier.wait(timeout=120)

    def work(index):
        try:
            sync()
            results[index] = closed_loop(problems(index), solver, index, plant, sync)
        except BaseException as error:  # reported by the main thread
            barrier.abort()  # the other threads stop waiting
            errors.append(error)

    if threaded:
        threads = [threading.Thread(target=work, args=(i,)) for i in range(THREADS)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    else:
        for index in range(THREADS):
            work(index)
    assert not errors, errors
    return results


@pytest.fixture(scope="module", params=list(SOLVERS))
def sequential(request, plant):
    """(solver, controls of the loops run one after another on one problem)."""
    if (SOLVERS[request.param][1] or {}).get("compiled") and needs_compiler.args[0]:
        pytest.skip("no C compiler on this machine")
    shared = make_problem()
    return request.param, run_loops(request.param, plant, threaded=False, problems=lambda i: shared)


def test_controllers_on_one_shared_problem_in_threads_equal_sequential(sequential, plant):
    """One problem object (and with it one Reference) for every controller, built before the threads."""
    solver, expected = sequential
    shared = make_problem()
    got = run_loops(solver, plant, threaded=True, problems=lambda i: shared)
    for index in range(THREADS):
        np.testing.assert_array_equal(got[index], expected[index], err_msg=f"{solver}, loop {index}")


def test_problems_built_inside_threads_equal_sequential(sequential, plant):
    """Every thread builds its own problem and Reference (CasADi builds run at the same time)."""
    solver, expected = sequential
    got = run_loops(solver, plant, threaded=True, problems=lambda i: make_problem())
    for index in range(THREADS):
        np.testing.assert_array_equal(got[index], expected[index], err_msg=f"{solver}, loop {index}")


def test_two_controllers_on_one_problem_own_their_backends():
    problem = make_problem()
    first, second = uo.NMPC(problem, "ipopt"), uo.NMPC(problem, "ipopt")
    assert first.backend is not second.backend
    swarms = uo.NMPC(problem, "igwo", options=SWARM), uo.NMPC(problem, "igwo", options=SWARM)
    assert swarms[0].backend is not swarms[1].backend
    assert swarms[0].backend._decode is not swarms[1].backend._decode  # zero-copy buffers too


def test_equal_problems_share_one_build():
    """The build cache is keyed by content: two equal problem objects, one build."""
    reference = uo.Reference.paper("s2")
    assert make_problem(reference).build() is make_problem(reference).build()
    assert (
        make_problem(reference).build()
        is not uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=HORIZON + 1).build()
    )


def test_get_solver_gives_each_thread_its_own_backend():
    problem = make_problem()
    mine = uo.get_solver(problem, "ipopt")
    assert uo.get_solver(problem, "IPOPT") is mine  # one per thread, content, name and options
    theirs = []
    thread = threading.Thread(target=lambda: theirs.append(uo.get_solver(problem, "ipopt")))
    thread.start()
    thread.join()
    assert theirs[0] is not mine


def test_solve_never_lends_a_busy_backend(monkeypatch):
    """``uo.solve`` checks a backend out of the pool: a second call while one runs gets another."""
    problem = make_problem()
    x0 = problem.reference.initial_state(0.0)
    seen, inside, release = [], threading.Barrier(3), threading.Event()  # two calls and this thread
    original = type(uo.get_solver(problem, "ipopt")).solve

    def solve(self, p, warm_start=None, *args, **kwargs):
        seen.append(self)
        if len(seen) <= 2:  # the two concurrent calls are inside a solve at once
            inside.wait(timeout=60)
            release.wait(timeout=60)
        return original(self, p, warm_start, *args, **kwargs)

    monkeypatch.setattr(type(uo.get_solver(problem, "ipopt")), "solve", solve)
    results = []
    threads = [
        threading.Thread(target=lambda: results.append(uo.solve(problem, "ipopt", x0=x0))) for _ in range(2)
    ]
    for thread in threads:
        thread.start()
    inside.wait(timeout=60)
    release.set()
    for thread in threads:
        thread.join()
    assert len(seen) == 2 and seen[0] is not seen[1]
    assert np.array_equal(results[0].controls, results[1].controls)
    # back in the pool: the next call reuses one of them instead of building a third
    assert uo.solve(problem, "ipopt", x0=x0).success
    assert seen[2] in seen[:2]


def test_a_shared_buffered_function_takes_turns():
    """Two threads calling one zero-copy caller at once get their own results (never mixed)."""
    reference = uo.Reference.paper("s2")
    caller = BufferedFunction(reference.function.map(21))
    grids = [np.arange(21) * 0.1 + i for i in range(THREADS)]
    expected = [np.array(reference.function.map(21)(grid)).ravel(order="F") for grid in grids]
    wrong = [0] * THREADS

    def work(index):
        for _ in range(300):
            (states,) = caller(grids[index])
            wrong[index] += not np.array_equal(states, expected[index])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(THREADS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert wrong == [0] * THREADS


def test_a_shared_reference_evaluates_right_in_every_thread():
    reference = uo.Reference.paper("s2")
    grids = [np.arange(21) * 0.1 + i for i in range(THREADS)]
    expected = [reference.evaluate_grid(grid) for grid in grids]
    wrong = [0] * THREADS

    def work(index):
        for _ in range(300):
            wrong[index] += not np.array_equal(reference.evaluate_grid(grids[index]), expected[index])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(THREADS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert wrong == [0] * THREADS


def test_one_controller_stepped_by_two_threads_raises():
    # a controller is one closed loop: a second thread inside it gets a clear error, never a
    # control interleaved from two loops (the issue: silent wrong controls)
    problem = make_problem()
    controller = uo.NMPC(problem, "ipopt")
    x0 = problem.reference.initial_state(0.0)
    inside, release = threading.Event(), threading.Event()
    solve = controller.backend.solve

    def slow_solve(*args, **kwargs):
        inside.set()
        release.wait(30)
        return solve(*args, **kwargs)

    controller.backend.solve = slow_solve
    worker = threading.Thread(target=controller.step, args=(x0, 0.0))
    worker.start()
    try:
        assert inside.wait(60)
        with pytest.raises(RuntimeError, match="another thread is inside this controller"):
            controller.step(x0, 0.0)
    finally:
        release.set()
        worker.join()
    controller.backend.solve = solve
    controller.warm_up(x0, 0.0)  # nested calls by one thread pass
    assert controller.step(x0, 0.0).control.shape == (3,)


def estimated_loop(problem, method, index):
    """One 1-s closed loop with estimator ``method`` under an unknown current: (controls, estimates)."""
    estimator = uo.Estimator(problem, method, sensors=uo.Sensors.auv(problem.vehicle))
    state = problem.reference.initial_state(0.0) + 0.05 * (index + 1) * np.array([1, -1, 0.2, 0.1, 0, 0])
    run = uo.simulate(
        uo.NMPC(problem, "sqp-rti"),
        x0=state,
        duration=1.0,
        current=uo.Current(0.3 + 0.1 * index, 0.5 * index),
        estimator=estimator,
        seed=index,
    )
    return run.controls, run.estimates.states, run.estimates.currents


@pytest.mark.parametrize("method", uo.available_estimators())  # every registered estimator
def test_estimated_loops_in_threads_equal_sequential(method):
    """Each thread its own problem, estimator and controller: the sequential loops, bit for bit.

    The estimates and the controls both; the estimators' Functions run through per-thread buffers.
    """
    expected = [estimated_loop(make_problem(), method, index) for index in range(THREADS)]
    results, errors = [None] * THREADS, []
    barrier = threading.Barrier(THREADS)

    def work(index):
        try:
            barrier.wait(timeout=120)
            results[index] = estimated_loop(make_problem(), method, index)
        except BaseException as error:  # reported by the main thread
            barrier.abort()
            errors.append(error)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(THREADS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    for index in range(THREADS):
        for got, want in zip(results[index], expected[index], strict=True):
            np.testing.assert_array_equal(got, want, err_msg=f"{method}, loop {index}")
