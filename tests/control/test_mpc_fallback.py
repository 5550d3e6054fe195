"""NMPC's fallback chain, refused plans, broken plug-ins and the warm-up before a closed loop."""

import dataclasses

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.control.scenario import vehicle_plant
from uuv_ocp.judge import FEASIBILITY_TOLERANCE
from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.solvers.result import Iterate, SolveResult, Stage


def _result(problem, controls, *, success, status):
    spec = problem.spec()
    return SolveResult(
        solver="plug-in",
        controls=controls,
        states=np.zeros((spec.horizon + 1, spec.state_dim)),
        cost=0.0,
        max_violation=0.0,
        success=success,
        status=status,
        solve_time=0.0,
        iterations=1,
        evaluations=1,
        terminal_relaxed=False,
        iterate=Iterate(
            np.zeros((spec.horizon, spec.control_size)), np.zeros((spec.horizon + 1, spec.state_dim))
        ),
    )


class _AlwaysFails:
    """A plug-in backend whose every solve fails (with a plan that is not finite)."""

    name = "always-fails"

    def __init__(self, problem, options=None):
        self.problem = problem

    def solve(self, p, warm_start=None, rng=None):
        spec = self.problem.spec()
        nan = np.full((spec.horizon, spec.control_size), np.nan)
        return _result(self.problem, nan, success=False, status="synthetic failure")


@pytest.fixture
def plug_in():
    """Register backends for one test and remove them afterwards."""
    names = []

    def register(name, factory):
        REGISTRY.register(name, factory, overwrite=True)
        names.append(name)
        return name

    yield register
    for name in names:
        REGISTRY._factories.pop(name, None)


def _zero_thrust_drift(problem, run):
    """Horizontal distance (m) from the start after the run's duration with no thrust at all.

    The same plant (RK4, 10 sub-steps) under the run's recorded currents: the baseline the
    old fallback (zero control held) gave.
    """
    spec = problem.spec()
    plant, _ = vehicle_plant(problem, None, spec.dt, 10)
    state = run.states[0]
    for k in range(run.controls.shape[0]):
        state = np.array(plant(state, np.zeros(spec.control_size), run.currents[k]))[:, -1]
    return float(np.hypot(*(state[:2] - run.states[0][:2])))


@pytest.mark.parametrize(
    ("vehicle", "pose", "speed"),
    [
        (uo.Vehicle.rexrov(), (0.0, 0.0, 0.0), 1.0),
        # the instance: 8 thrusters as controls, a current the vehicle cannot stem
        (Vehicle6DOF.bluerov2_heavy(thrusters=True), (0.0, 0.0, 5.0, 0.0), 1.5),
    ],
    ids=["rexrov-1.0", "bluerov2-heavy-thrusters-1.5"],
)
def test_when_every_solve_fails_the_fallback_beats_zero_thrust_within_the_bounds(
    plug_in, vehicle, pose, speed
):
    reference = uo.Reference.hold(pose)
    problem = uo.TrackingProblem(vehicle, reference, horizon=10, dt=0.1)
    current = uo.Current(speed=speed, direction=0.5, speed_noise=0.0, direction_noise=0.0)
    controller = uo.NMPC(problem, plug_in("always-fails", _AlwaysFails))
    run = uo.simulate(controller, reference.initial_state(0.0), 6.0, current=current, seed=1)
    assert run.failures == run.controls.shape[0] == 60
    assert set(run.statuses) == {"synthetic failure"}
    drift = float(np.hypot(*(run.states[-1, :2] - run.states[0, :2])))
    baseline = _zero_thrust_drift(problem, run)
    assert baseline > 2.0  # the current does sweep an unpowered vehicle away
    assert drift < 0.5 * baseline
    # every applied control holds the box and the rate bound (from the zero start)
    spec = problem.spec()
    assert np.all(run.controls >= spec.lower - 1e-9) and np.all(run.controls <= spec.upper + 1e-9)
    steps = np.diff(np.vstack([np.zeros(spec.control_size), run.controls]), axis=0)
    assert np.all(np.abs(steps) <= spec.max_rate * spec.dt * (1 + 1e-9))


def test_fallback_sources_are_reported_in_order(s2_problem):
    """The shifted plan while it is admissible; then the steady control, recomputed each step."""
    controller = uo.NMPC(s2_problem, "ipopt")
    x0 = s2_problem.reference.initial_state(0.0)
    first = controller.step(x0, 0.0, np.zeros(3))
    controller.backend = _AlwaysFails(s2_problem)
    second = controller.step(x0, 0.1, first.control)
    assert second.fallback and second.fallback_source == "shifted plan"
    np.testing.assert_allclose(second.control, first.result.controls[1])
    # a last control far from the plan's next one: the shifted plan breaks the rate bound
    far = first.control + np.array([1500.0, 0.0, 0.0])
    third = controller.step(x0, 0.2, far)
    assert third.fallback and third.fallback_source == "steady control"
    assert controller.plan is None  # a fallback that left the solver's plan does not replay it


def test_a_nan_plan_reported_as_success_is_refused_and_says_so(s2_problem, plug_in):
    class NanSuccess(_AlwaysFails):
        def solve(self, p, warm_start=None, rng=None):
            spec = self.problem.spec()
            nan = np.full((spec.horizon, spec.control_size), np.nan)
            return _result(self.problem, nan, success=True, status="Solve_Succeeded")

    controller = uo.NMPC(s2_problem, plug_in("nan-success", NanSuccess))
    run = uo.simulate(controller, s2_problem.reference.initial_state(0.0), 0.3)
    assert run.failures == 3
    assert all(status.startswith("non-finite controls") for status in run.statuses), run.statuses
    assert np.all(np.isfinite(run.controls))


def test_a_backend_returning_something_else_than_a_solve_result_is_refused(s2_problem, plug_in):
    class ReturnsDict(_AlwaysFails):
        def solve(self, p, warm_start=None, rng=None):
            return {"controls": np.zeros((20, 3))}

    controller = uo.NMPC(s2_problem, plug_in("returns-dict", ReturnsDict))
    with pytest.raises(TypeError, match=r"'returns-dict' \(ReturnsDict\) returned a dict"):
        uo.simulate(controller, s2_problem.reference.initial_state(0.0), 0.3)
    with pytest.raises(TypeError, match="'no-solve'.*no solve"):
        uo.NMPC(s2_problem, plug_in("no-solve", lambda problem, options: object()))


def test_a_swarm_never_takes_the_vehicle_into_an_obstacle():
    """IGWO near a rock (margin 0): plans that enter it are refused, the fallback steps counted."""
    rock = uo.Obstacle.circle((5.0, 0.2), 0.6, margin=0.0, name="rock")
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=25, dt=0.2, terminal="cost", obstacles=(rock,)
    )
    controller = uo.NMPC(problem, "igwo", seed=1)
    run = uo.simulate(controller, line.initial_state(0.0), 16.0)
    distance = np.hypot(run.states[:, 0] - 5.0, run.states[:, 1] - 0.2) - 0.6
    assert np.min(distance) >= 0.0
    assert run.failures > 0  # the swarm's infeasible plans were refused, the steps counted
    assert run.states[-1, 0] > 5.5  # and the vehicle got past the rock


def test_a_plan_reported_feasible_that_enters_an_obstacle_is_refused(plug_in):
    """Whatever a backend reports, the judge decides: a plan through the rock is not applied."""
    rock = uo.Obstacle.circle((1.0, 0.0), 0.3, margin=0.0, name="rock")
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=20, dt=0.2, terminal="cost", obstacles=(rock,)
    )

    class Reckless(_AlwaysFails):
        def solve(self, p, warm_start=None, rng=None):
            spec = self.problem.spec()
            # full surge, ramped at the rate bound: straight into the rock within the horizon
            ramp = np.minimum(spec.max_rate[0] * spec.dt * np.arange(1, spec.horizon + 1), spec.upper[0])
            controls = np.zeros((spec.horizon, spec.control_size))
            controls[:, 0] = ramp
            return _result(self.problem, controls, success=True, status="Solve_Succeeded")

    controller = uo.NMPC(problem, plug_in("reckless", Reckless))
    output = controller.step(line.initial_state(0.0), 0.0, np.zeros(3))
    assert output.fallback and output.message.startswith("path constraint violated by")
    assert "Solve_Succeeded" in output.message
    # the same plan without the rock is applied as it is
    blind = uo.NMPC(problem.replace(obstacles=()), plug_in("reckless", Reckless))
    assert not blind.step(line.initial_state(0.0), 0.0, np.zeros(3)).fallback


@needs_compiler
def test_warm_up_builds_before_the_loop_and_no_step_compiles_after_it(s2_problem, monkeypatch):
    """sqp-rti's C step (and its judge) are compiled by warm_up, never inside a step."""
    import uuv_ocp.native.compile as native

    calls = []
    compile_functions = native.compile_functions

    def counting(*args, **kwargs):
        calls.append(kwargs.get("name", ""))
        return compile_functions(*args, **kwargs)

    monkeypatch.setattr(native, "compile_functions", counting)
    problem = s2_problem.replace()  # its own backends: nothing built yet
    x0 = problem.reference.initial_state(0.0)
    options = {"qpsol": "hpipm-ocp"}
    controller = uo.NMPC(problem, "sqp-rti", options=options)
    controller.warm_up(x0, 0.0)
    assert controller.warmed_up and calls  # the warm-up compiled (or loaded) the C step
    calls.clear()
    u = np.zeros(3)
    for k in range(3):
        u = controller.step(x0, 0.1 * k, u).control
    assert calls == []
    # without the warm-up the first warm step is where the C step gets built
    fresh = uo.NMPC(s2_problem.replace(), "sqp-rti", options=options)
    first = fresh.step(x0, 0.0, np.zeros(3))
    assert calls == []  # the cold step (IPOPT) compiles nothing
    fresh.step(x0, 0.1, first.control)
    assert calls


def test_simulate_warms_the_controller_up_once(s2_problem, monkeypatch):
    controller = uo.NMPC(s2_problem, "ipopt")
    warm_ups = []
    original = controller.warm_up

    def counting(*args, **kwargs):
        warm_ups.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr(controller, "warm_up", counting)
    x0 = s2_problem.reference.initial_state(0.0)
    first = uo.simulate(controller, x0, 0.3)
    again = uo.simulate(controller, x0, 0.3)
    assert len(warm_ups) == 1
    # the warm-up leaves no trace: the same run twice
    np.testing.assert_array_equal(first.controls, again.controls)


# -- saying so when a compile takes a while ---------------------------------------------------


def test_a_slow_notice_is_one_line_and_quick_work_prints_nothing(monkeypatch):
    import io

    from uuv_ocp.progress import SlowNotice

    monkeypatch.setenv("UUV_OCP_PROGRESS", "always")
    stream = io.StringIO()
    with SlowNotice("compiling x", delay=0.0, stream=stream) as notice:
        assert notice._shown.wait(10.0)  # the timer has fired: the work is "slow"
    assert stream.getvalue().startswith("compiling x ... done in ") and stream.getvalue().count("\n") == 1
    quick = io.StringIO()
    with SlowNotice("compiling y", delay=3600.0, stream=quick):
        pass
    assert quick.getvalue() == ""
    monkeypatch.setenv("UUV_OCP_PROGRESS", "never")
    assert not SlowNotice("compiling z", delay=0.0, stream=io.StringIO()).enabled


@needs_compiler
def test_a_c_compile_runs_inside_a_slow_notice(tmp_path, monkeypatch):
    import casadi as ca

    import uuv_ocp.native.compile as native

    texts = []

    class Recorder:
        def __init__(self, text, *args, **kwargs):
            texts.append(text)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return None

    monkeypatch.setattr(native, "SlowNotice", Recorder)
    x = ca.SX.sym("x", 2)
    function = ca.Function("notice_probe", [x], [ca.sumsqr(x)])
    native.compile_functions([function], tmp_path, name="notice_probe")
    assert texts == [f"uuv_ocp: compiling notice_probe (first use; cached in {tmp_path})"]
    native.compile_functions([function], tmp_path, name="notice_probe")  # from the cache: silent
    assert len(texts) == 1


def test_warm_up_builds_the_whole_fallback_chain(s2_problem):
    """The robust retry and the IPOPT rescue are built by warm_up, not by the step that needs them."""
    controller = uo.NMPC(s2_problem.replace(), "fatrop")
    x0 = s2_problem.reference.initial_state(0.0)
    controller.warm_up(x0, 0.0)
    stages = {stage for (_, stage, _) in controller.backend._solvers}
    assert {Stage.PLAIN, Stage.ROBUST, Stage.RESCUE} <= stages, stages


def test_real_time_iteration_plans_applied_on_obstacles_hold_them(monkeypatch):
    """sqp-rti on the obstacle tutorial: every fresh plan applied passes the judge (1e-6).

    One QP holds the obstacles linearised at the warm start; the plans it gives that the judge
    refuses (the linearisation error, mm) are iterated further before they may be applied.
    """
    rock = uo.Obstacle.circle((5.0, 0.2), 0.6, margin=0.5, name="rock")
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=25, dt=0.2, terminal="cost", obstacles=(rock,)
    )
    controller = uo.NMPC(problem, "sqp-rti")
    applied, refined, mended = [], [], []
    step, solve = controller.step, controller.backend.solve

    def recording_step(x, t, u_prev=None, current=None, parameters=None):
        before = len(refined)
        output = step(x, t, u_prev, current, parameters)
        if not output.fallback:
            applied.append((np.array(x), t, u_prev, output.result.controls))
            if len(refined) > before:  # a refused one-QP plan, mended and applied
                mended.append(t)
        return output

    def counting_solve(*args, **kwargs):
        if "time_limit" in kwargs:  # only NMPC's refinement passes it (feedback does not)
            refined.append(args)
        return solve(*args, **kwargs)

    monkeypatch.setattr(controller, "step", recording_step)
    monkeypatch.setattr(controller.backend, "solve", counting_solve)
    run = uo.simulate(controller, line.initial_state(0.0), 16.0)
    # the refused plans that further steps did not mend fell back (judged plans too)
    assert len(applied) > 0.75 * run.controls.shape[0] and run.states[-1, 0] > 6.0
    worst = max(uo.score(problem, plan, x, t, u_prev=u_prev)[1] for x, t, u_prev, plan in applied)
    assert worst <= FEASIBILITY_TOLERANCE
    # the rock bends the path: some one-QP plans broke its constraint and further steps mended them
    assert mended


@needs_compiler
def test_the_c_fast_paths_apply_only_plans_that_hold_the_obstacles():
    """NMPC.step with the C step (the resident fast path) on the rock: every applied plan is judged.

    A resident C step's plan is one QP's, like ``solve``'s: unjudged, plans entering the rock's
    zone by mm were applied (docs/solvers.md); judged, refused ones are refined or fall back.
    """
    rock = uo.Obstacle.circle((5.0, 0.2), 0.6, margin=0.5, name="rock")
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=25, dt=0.2, terminal="cost", obstacles=(rock,)
    )
    controller = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    plant, _ = vehicle_plant(problem, None, problem.dt, 10)
    x, u, worst, fast = line.initial_state(0.0), np.zeros(3), 0.0, 0
    for k in range(60):
        t = k * problem.dt
        output = controller.step(x, t, u)
        if not output.fallback:
            worst = max(worst, uo.score(problem, controller.plan, x, t, u_prev=u)[1])
        fast += output.fast_path == "resident C step"
        u = output.control
        x = np.array(plant(x, u, np.zeros(2)))[:, -1]
    assert worst <= FEASIBILITY_TOLERANCE
    assert fast > 30  # the fast path ran (and was judged)
    assert x[0] > 5.5  # past the rock


def test_the_nmpc_keeps_no_non_finite_warm_start(s2_problem, monkeypatch):
    """Finite controls over a NaN multiplier: applied, but the next step starts cold.

    Reference: the warm starts the backend is handed (None: cold, as after ``reset``).
    """
    controller = uo.NMPC(s2_problem, "ipopt")
    backend = controller.backend
    original = backend.solve
    warm_starts = []

    def solve(p, warm_start=None, rng=None, **kwargs):
        warm_starts.append(warm_start)
        result = original(p, warm_start, rng, **kwargs)
        lam_g = result.iterate.lam_g.copy()
        lam_g[-1] = np.nan
        return dataclasses.replace(result, iterate=dataclasses.replace(result.iterate, lam_g=lam_g))

    monkeypatch.setattr(backend, "solve", solve)
    state = s2_problem.reference.initial_state(0.0)
    first = controller.step(state, 0.0, np.zeros(3))
    assert not first.fallback and np.all(np.isfinite(first.control))
    assert controller.iterate is None
    controller.step(state, s2_problem.dt, first.control)
    assert warm_starts == [None, None]


@pytest.mark.parametrize(("ahead", "source"), [(1.3, "braking control"), (1.6, "steady control")])
def test_braking_comes_after_the_steady_control_and_stops_short_of_an_obstacle(ahead, source):
    """A RexROV at 1.5 m/s, a rock ``ahead`` m in front, every solve failing.

    At 1.6 m the steady control (hold the reference's velocities) stays out over the horizon
    and is taken; at 1.3 m it would enter the rock, and the braking control, ramped at the rate
    bound from the last control, is the first admissible plan (the judge's verdict).
    """
    reference = uo.Reference.paper("s2")
    x0 = reference.initial_state(0.0)
    heading = x0[2]
    centre = (x0[0] + (ahead + 0.5) * np.cos(heading), x0[1] + (ahead + 0.5) * np.sin(heading))
    rock = uo.Obstacle.circle(centre, 0.5)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=10, dt=0.1, obstacles=(rock,))
    controller = uo.NMPC(problem, "ipopt")
    controller.backend = _AlwaysFails(problem)
    x0[3] = 1.5  # surge toward the rock
    record = controller.step(x0, 0.0, np.zeros(3))
    assert record.fallback and record.fallback_source == source
    spec = problem.spec()
    assert np.all(np.abs(record.control) <= spec.max_rate * spec.dt * (1 + 1e-12))  # from rest
    if source == "braking control":
        assert record.control[0] < 0.0  # thrust against the motion
