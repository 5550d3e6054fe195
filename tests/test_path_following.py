"""Path following (issue 28): PathFollowingProblem through the solvers, NMPC and simulate.

Every geometric figure is checked against a numpy computation written here (point-to-line
distance, the arc length of an analytic path), not against the module's own projection.
"""

from __future__ import annotations

import math
import warnings

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests import helpers_remus as remus
from tests.conftest import needs_compiler
from uuv_ocp.path_following import PathFollowingProblem, PathWeights, path_errors
from uuv_ocp.solvers import get_solver


def _remus_line() -> uo.Reference:
    """Return a straight line due north at 10 m depth, timed at 1.5 m/s."""
    return uo.Reference.from_xyz(lambda t: 1.5 * t, lambda t: 0 * t, lambda t: 10 + 0 * t, "line")


def _planar_line(speed: float = 0.5, t_end: float = math.inf) -> uo.Reference:
    """Return a straight line through the origin at 30° from north, timed at ``speed`` m/s."""
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    return uo.Reference.from_xy(lambda t: speed * c * t, lambda t: speed * s * t, "line", t_end=t_end)


def _signed_distance_to_line(points: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Signed horizontal distance (m) from the line, positive to starboard (numpy, NED)."""
    unit = direction / np.linalg.norm(direction)
    offset = points - origin
    return unit[0] * offset[:, 1] - unit[1] * offset[:, 0]  # z of unit × offset


def test_remus_converges_to_a_straight_line_from_a_10_m_offset() -> None:
    """REMUS 100 at 1.5 m/s from 10 m to starboard: no steady cross-track or depth error.

    With sqp-rti (CasADi's HPIPM in the suite) at the defaults: RK4 in 2 substeps (stable on
    the roll mode) and the propeller floored at 0.9 × its cruise speed.  Without the floor this
    loop stalled near the line (the plan reversed the propeller: u -> 0.003 m/s by 40 s).
    The default rate weight (500, for calm fins) makes the approach a slow decaying weave:
    measured |e_c| = 0.32, 0.14, 0.05, 0.014, 0.002 m at 20, 30, 40, 50, 60 s, hence 80 s.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # the default substeps are stable
        problem = PathFollowingProblem(uo.Remus100(), _remus_line(), speed=1.5, horizon=20, dt=0.5)
    assert problem.substeps == 2
    start = np.zeros(12)
    start[[1, 2, 6]] = (10.0, 10.0, 1.5)  # 10 m east of the line, at its depth, at cruise speed
    x0 = problem.initial_state(start)
    assert x0[-1] == pytest.approx(0.0, abs=1e-6)
    run = uo.simulate(uo.NMPC(problem, solver="sqp-rti"), x0=x0, duration=80.0)
    assert run.fault is None
    assert not any(run.fallback_steps[-40:])  # the last 20 s are fresh RTI plans
    cross = _signed_distance_to_line(run.states[:, :2], np.zeros(2), np.array([1.0, 0.0]))
    depth = run.states[:, 2] - 10.0
    settled = run.t >= run.t[-1] - 10.0  # measured: |e_c| < 4e-4 m from t = 70 s
    assert np.max(np.abs(cross[settled])) < 0.01
    assert np.max(np.abs(depth[settled])) < 0.01
    assert abs(cross[0]) == pytest.approx(10.0)
    # the module's projection agrees with the independent distance, sample by sample
    errors = path_errors(problem, run)
    np.testing.assert_allclose(errors["cross_track"], cross, atol=1e-6)
    np.testing.assert_allclose(errors["vertical"], depth, atol=1e-6)
    # the vehicle moves on at (and, catching up with p(s), approaches) the commanded speed
    speed = np.diff(run.states[:, 0])[settled[1:]] / problem.dt
    assert np.all(np.abs(speed - 1.5) < 0.1)
    assert abs(speed[-1] - 1.5) < 0.03


@pytest.mark.parametrize("solver", ["sqp-rti", "fatrop"])
def test_rexrov_converges_to_a_straight_line_from_a_10_m_offset(solver: str) -> None:
    """The planar RexROV from 10 m to port of a line at 30°: converged within 0.02 m."""
    line = _planar_line()
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), line, speed=0.5, horizon=20, dt=0.5)
    direction = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    port = np.array([direction[1], -direction[0]]) * 10.0  # 10 m to port
    x0 = problem.initial_state([port[0], port[1], math.pi / 6, 0.0, 0.0, 0.0])
    run = uo.simulate(uo.NMPC(problem, solver=solver), x0=x0, duration=40.0)
    assert run.fault is None
    cross = _signed_distance_to_line(run.states[:, :2], np.zeros(2), direction)
    assert cross[0] == pytest.approx(-10.0)
    settled = run.t >= run.t[-1] - 10.0
    assert np.max(np.abs(cross[settled])) < 0.02
    np.testing.assert_allclose(path_errors(problem, run)["cross_track"], cross, atol=1e-6)


@pytest.fixture(scope="module")
def rexrov_instance() -> tuple[PathFollowingProblem, np.ndarray]:
    """Return a short RexROV instance 1.4 m off a line, moving; a current is given at solve time."""
    problem = PathFollowingProblem(
        uo.Vehicle.rexrov(), _planar_line(t_end=200.0), speed=0.5, horizon=8, dt=0.5
    )
    return problem, problem.initial_state([1.0, -1.0, 0.5, 0.4, 0.0, 0.0])


def test_ipopt_fatrop_and_sqp_reach_the_same_optimum(rexrov_instance) -> None:
    problem, x0 = rexrov_instance
    arguments = {"x0": x0, "u_prev": np.r_[np.zeros(3), 0.5], "current": [0.1, -0.05]}
    results = {name: uo.solve(problem, name, **arguments) for name in ("ipopt", "fatrop", "sqp")}
    reference = results["ipopt"]
    assert reference.success
    for name in ("fatrop", "sqp"):
        assert results[name].success, name
        assert results[name].cost == pytest.approx(reference.cost, rel=1e-6), name
        scale = np.r_[problem.vehicle.control_bound, problem.max_path_speed]
        # the heading is free (not referenced): the optimum is flat along it, so the plans
        # agree to the solvers' tolerances where the costs agree to 1e-8 (measured: 2e-4 of
        # the control bounds between IPOPT's default tolerance and SQP; 2e-5 with IPOPT at 1e-12)
        np.testing.assert_allclose(results[name].controls / scale, reference.controls / scale, atol=1e-3)
        np.testing.assert_allclose(results[name].states, reference.states, atol=1e-3)


def test_a_swarm_plan_holds_every_bound_and_rate(rexrov_instance) -> None:
    problem, x0 = rexrov_instance
    u_prev = np.zeros(
        4
    )  # from rest: the speed cost asks for 0.5 m/s, the rate bound allows 0.25 m/s per step
    result = uo.solve(problem, "igwo", x0=x0, u_prev=u_prev, options={"seed": 3, "iterations": 20})
    controls = result.controls
    bound = np.r_[problem.vehicle.control_bound, problem.max_path_speed]
    lower = np.r_[-np.asarray(problem.vehicle.control_bound), 0.0]
    assert np.all(controls <= bound + 1e-9) and np.all(controls >= lower - 1e-9)
    rate = np.r_[problem.vehicle.control_rate_bound, problem.path_acceleration] * problem.dt
    steps = np.diff(np.vstack([u_prev, controls]), axis=0)
    assert np.all(np.abs(steps) <= rate + 1e-9)
    # the judge's rollout of the plan: finite cost, no hard-constraint violation
    cost, violation = uo.score(problem, controls, x0=x0, u_prev=u_prev)
    assert np.isfinite(cost) and violation <= 1e-9


def test_the_path_parameter_moves_p_of_s_at_v_s_along_the_path() -> None:
    """On x = τ² (speed 2τ), the arc length from the origin is s², so s_{k+1}² − s_k² = v_s,k dt."""
    path = uo.Reference.from_xy(lambda t: t**2, lambda t: 0 * t, "accelerating", t_start=1.0, t_end=100.0)
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), path, speed=0.5, horizon=10, dt=0.5, substeps=4)
    x0 = problem.initial_state([4.5, 1.0, 0.0, 0.2, 0.0, 0.0])
    assert x0[-1] == pytest.approx(math.sqrt(4.5), abs=1e-4)  # the closest point of the line y = 0
    result = uo.solve(problem, "ipopt", x0=x0, u_prev=np.r_[np.zeros(3), 0.3])
    s, v_s = result.states[:, -1], result.controls[:, -1]
    assert np.all(v_s > 0.1)  # the path parameter moves
    np.testing.assert_allclose(np.diff(s**2), v_s * problem.dt, rtol=1e-6)


def test_a_reference_timed_twice_as_fast_gives_the_same_optimal_vehicle_path() -> None:
    """The speed cost is in m/s: re-timing the path (s → s/2) changes no vehicle state."""
    vehicle = uo.Vehicle.rexrov()
    slow = PathFollowingProblem(vehicle, _planar_line(0.5), speed=0.5, horizon=8, dt=0.5)
    fast = PathFollowingProblem(vehicle, _planar_line(1.0), speed=0.5, horizon=8, dt=0.5)
    start = [3.0, -0.5, 0.5, 0.4, 0.0, 0.0]
    x_slow, x_fast = slow.initial_state(start), fast.initial_state(start)
    assert x_fast[-1] == pytest.approx(x_slow[-1] / 2.0, rel=1e-9)
    u_prev = np.r_[np.zeros(3), 0.5]
    one = uo.solve(slow, "ipopt", x0=x_slow, u_prev=u_prev)
    two = uo.solve(fast, "ipopt", x0=x_fast, u_prev=u_prev)
    np.testing.assert_allclose(one.states[:, :-1], two.states[:, :-1], atol=1e-6)
    scale = np.r_[vehicle.control_bound, slow.max_path_speed]  # N, N, N·m, m/s
    np.testing.assert_allclose(one.controls / scale, two.controls / scale, atol=1e-6)
    np.testing.assert_allclose(one.states[:, -1], 2.0 * two.states[:, -1], atol=1e-6)


def test_closest_parameter_on_a_circle_is_the_polar_angle() -> None:
    """A circle of radius 5 m at 1 rad/s: the closest point of (r cos a, r sin a) is τ = a."""
    circle = uo.Reference.from_xy(lambda t: 5 * ca.cos(t), lambda t: 5 * ca.sin(t), "circle", t_end=6.0)
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), circle, speed=0.5, horizon=4, dt=0.5)
    rng = np.random.default_rng(7)
    for angle, radius in zip(rng.uniform(0.2, 5.8, 10), rng.uniform(1.0, 9.0, 10), strict=True):
        point = radius * np.array([math.cos(angle), math.sin(angle)])
        assert problem.closest_parameter(point) == pytest.approx(angle, abs=1e-4)
        errors = path_errors(problem, np.r_[point, np.zeros(4)][None, :])
        # a counter-clockwise circle in NED: the centre is to starboard (inside: positive)
        assert errors["cross_track"][0] == pytest.approx(5.0 - radius, abs=1e-6)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"path": _planar_line()}, "path must be spatial"),
        ({"speed": 0.0}, "speed must be"),
        ({"speed": -1.0}, "speed must be"),
        ({"max_path_speed": 1.0}, "max_path_speed must be >= speed"),
        ({"path_acceleration": 0.0}, "path_acceleration must be"),
        ({"terminal": "equality"}, "terminal"),
        ({"weights": uo.Weights()}, "weights must be a uuv_ocp.PathWeights"),
        ({"horizon": 0}, "horizon"),
        ({"path": "north"}, "path must be a uuv_ocp.Reference"),
        ({"obstacles": (uo.Obstacle.moving(lambda t: (t, 0 * t), 1.0),)}, "obstacles must be static"),
        ({"control_lower": (0.0, 0.0)}, "control_lower must have shape"),
        ({"control_lower": (0.0, 0.0, 2000.0)}, "control_lower must lie within"),
        ({"control_lower": (0.0, 0.0, math.nan)}, "control_lower must be finite"),
        ({"speed": 3.0}, "speed must be reachable"),  # beyond the REMUS's 2.5 m/s: no cruise rpm
    ],
)
def test_bad_inputs_are_refused_by_name(changes: dict, message: str) -> None:
    arguments = {"vehicle": uo.Remus100(), "path": _remus_line(), "speed": 1.5, **changes}
    with pytest.raises(ValueError, match=message):
        PathFollowingProblem(**arguments)


def test_bad_weights_and_instances_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="weights.cross_track must be > 0"):
        PathWeights(cross_track=0.0)
    with pytest.raises(ValueError, match="weights.speed"):
        PathWeights(speed=-1.0)
    with pytest.raises(ValueError, match="path must be planar"):
        PathFollowingProblem(uo.Vehicle.rexrov(), _remus_line(), speed=1.0)
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), _planar_line(), speed=0.5, horizon=4)
    x0 = problem.initial_state(np.zeros(6))
    with pytest.raises(ValueError, match="t0 must be 0"):
        uo.solve(problem, "ipopt", x0=x0, t0=1.0)
    with pytest.raises(ValueError, match="x0"):
        uo.solve(problem, "ipopt", x0=np.zeros(6))  # without the path parameter
    with pytest.raises(ValueError, match="parameters"), warnings.catch_warnings():
        problem.instance_parameters(x0, parameters={"current": [0.0, 0.0]})


def test_the_propeller_is_floored_at_0_9_of_its_cruise_speed() -> None:
    """The REMUS's default lower bounds: the fins' ``−δ_max`` and 0.9 × the cruise rpm.

    The cruise rpm is checked on the independent REMUS implementation (tests/helpers_remus.py):
    the surge acceleration of a straight run at 1.5 m/s vanishes there.  A one-step plan that
    wants to brake (the vehicle 5 m ahead of ``p(s)`` at 2 m/s) keeps the propeller on the
    floor; with ``control_lower = −u_max`` the same plan reverses it.
    """
    problem = PathFollowingProblem(uo.Remus100(), _remus_line(), speed=1.5, horizon=4, dt=0.5)
    fin, _, top = uo.Remus100().control_bound
    assert problem.control_lower[:2] == (-fin, -fin)
    cruise = problem.control_lower[2] / 0.9
    state = np.zeros(12)
    state[0] = 1.5  # u: helpers_remus orders the state [ν, η]
    assert remus.remus100_derivative(state, [0.0, 0.0, cruise])[0] == pytest.approx(0.0, abs=1e-9)
    assert 500.0 < cruise < top
    rexrov = PathFollowingProblem(uo.Vehicle.rexrov(), _planar_line(), speed=0.5, horizon=4)
    np.testing.assert_array_equal(rexrov.control_lower, -np.asarray(uo.Vehicle.rexrov().control_bound))
    start = np.zeros(12)
    start[[0, 2, 6]] = (5.0, 10.0, 2.0)
    lowest = {}
    for name, lower in (("floor", None), ("reverse", (-fin, -fin, -top))):
        braking = PathFollowingProblem(
            uo.Remus100(), _remus_line(), speed=1.5, horizon=4, dt=0.5, control_lower=lower
        )
        x0 = np.r_[start, 0.0]  # p(s) at the origin, 5 m behind the vehicle
        u_prev = np.r_[0.0, 0.0, braking.control_lower[2] if lower is None else 0.0, 1.5]
        result = uo.solve(braking, "ipopt", x0=x0, u_prev=u_prev)
        assert result.success
        lowest[name] = float(np.min(result.controls[:, 2]))
    assert lowest["floor"] == pytest.approx(problem.control_lower[2], abs=1e-3)  # it presses on the floor
    assert lowest["reverse"] < 0.5 * problem.control_lower[2]  # measured: 12 rpm, braking


def _survey(depth: float | None = 10.0) -> uo.Reference:
    """Return two 40 m lanes 10 m apart at 1.5 m/s (turn radius 5 m), braking to rest at the end."""
    return uo.Reference.lawnmower(width=40.0, spacing=10.0, lanes=2, speed=1.5, depth=depth)


def test_the_path_geometry_is_the_references_position_and_its_derivative() -> None:
    """p(s) and p'(s) on a 3-D survey with turns: the reference's samples and central differences."""
    problem = PathFollowingProblem(uo.Remus100(), _survey(), speed=1.5)
    step = 1e-5
    for s in np.linspace(1.0, 55.0, 12):  # lanes and the turn
        samples = problem.path.evaluate([s - step, s, s + step])[:, :3]
        point, tangent = (np.array(value).ravel() for value in problem.geometry(s))
        np.testing.assert_allclose(point, samples[1], atol=1e-12)
        np.testing.assert_allclose(tangent, (samples[2] - samples[0]) / (2 * step), atol=1e-6)


def test_the_path_ends_where_the_survey_brakes_to_rest() -> None:
    """Two lanes of 40 m and a turn of radius 5 m: length 2·40 − 2·5 + 5π m; braking over 5 m."""
    problem = PathFollowingProblem(uo.Remus100(), _survey(), speed=1.5)
    length, radius, speed = 80.0 - 10.0 + 5.0 * math.pi, 5.0, 1.5
    deceleration = speed**2 / (2.0 * radius)
    cruise_end = (length - radius) / speed
    # the speed falls linearly from 1.5 m/s; the path ends where it is 10 % of that
    assert problem.path_end == pytest.approx(cruise_end + 0.9 * speed / deceleration, abs=0.05)
    unbounded = PathFollowingProblem(uo.Remus100(), _remus_line(), speed=1.5)
    assert unbounded.path_end == math.inf


def test_the_vehicle_stops_at_the_end_of_the_path() -> None:
    """The RexROV 5 s before the end of a planar survey parks s at path_end and stops there."""
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), _survey(None), speed=0.5, horizon=10, dt=0.5)
    point = np.array(problem.geometry(problem.path_end - 5.0)[0]).ravel()
    x0 = problem.initial_state([*point, math.pi, 0.0, 0.0, 0.0])
    run = uo.simulate(uo.NMPC(problem, solver="sqp-rti"), x0=x0, duration=40.0)
    assert run.fault is None
    end = np.array(problem.geometry(problem.path_end)[0]).ravel()
    assert run.states[-1, -1] == pytest.approx(problem.path_end, abs=0.02)  # 3 mm of path at 10 % speed
    assert np.linalg.norm(run.states[-1, :2] - end) < 0.05
    assert np.linalg.norm(run.states[-1, 3:5]) < 0.02  # at rest


def test_a_known_cross_current_leaves_no_steady_cross_track_error() -> None:
    """The RexROV on the 30° line under a 0.2 m/s current across it: it crabs, on the line.

    Without the current in the model (``current_known=False``) the same loop keeps an offset:
    the current reaches the controller through the instance's current parameter.
    """
    line = _planar_line()
    problem = PathFollowingProblem(uo.Vehicle.rexrov(), line, speed=0.5, horizon=20, dt=0.5)
    direction = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    x0 = problem.initial_state([0.0, 0.0, math.pi / 6, 0.5, 0.0, 0.0])
    current = uo.Current(speed=0.2, direction=math.pi / 6 + math.pi / 2)  # to starboard of the line
    errors = {}
    for known in (True, False):
        run = uo.simulate(
            uo.NMPC(problem, solver="sqp-rti"), x0=x0, duration=30.0, current=current, current_known=known
        )
        assert run.fault is None
        cross = _signed_distance_to_line(run.states[:, :2], np.zeros(2), direction)
        errors[known] = np.max(np.abs(cross[run.t >= 20.0]))
    assert errors[True] < 0.01
    assert errors[False] > 10 * errors[True]


@needs_compiler
def test_the_lawnmower_builds_the_c_step_and_its_step_is_casadis() -> None:
    """The REMUS survey's RTI step in C (HPIPM's OCP-QP) equals CasADi's hpipm path to 1e-8.

    The C step refused this problem while the waypoint look-ups were interpolant calls (their
    SX Jacobian read ``s_(k+1)`` in stage k's gap); it must build here, without a warning.
    """
    problem = PathFollowingProblem(uo.Remus100(), _survey(), speed=1.5, horizon=10, dt=0.5)
    start = np.zeros(12)
    start[[1, 2, 5, 6]] = (-3.0, 10.5, 0.2, 1.2)  # 3 m to port, 0.5 m deep, yawed, at speed
    x0 = problem.initial_state(start)
    p = problem.parameters(x0, np.r_[0.0, 0.0, 1200.0, 1.5], current=[0.2, -0.1, 0.0])
    tight = {
        "hpipm": {"hpipm": {f"res_{k}_max": 1e-12 for k in "gbdm"}},
        "hpipm-ocp": {
            "mode": "robust",
            "cond_horizon": 0,
            **{f"tol_{k}": 1e-11 for k in ("stat", "eq", "ineq", "comp")},
        },
    }
    results = {}
    for qpsol, settings in tight.items():
        backend = get_solver(
            problem, "sqp-rti", {"cold_start": "rti", "qpsol": qpsol, "qpsol_options": settings}
        )
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # no fall back to CasADi's path
            results[qpsol] = backend.solve(p, None)
        assert backend.qpsol == qpsol
        assert results[qpsol].success and results[qpsol].iterations == 1
    a, b = results["hpipm"], results["hpipm-ocp"]
    np.testing.assert_allclose(b.iterate.primal, a.iterate.primal, rtol=0, atol=1e-8)


def test_an_estimated_current_path_following_loop_converges_to_the_true_current() -> None:
    """The RexROV on the 30° line, the current unknown: an EKF on the vehicle's 6 states.

    The path parameter is the controller's own state: the estimator measures and estimates the
    vehicle's states and the current, the controller keeps ``s``.  Reference: the true current.
    """
    line = _planar_line()
    vehicle = uo.Vehicle.rexrov()
    problem = PathFollowingProblem(vehicle, line, speed=0.5, horizon=10, dt=0.5)
    estimator = uo.Estimator(problem, "ekf", sensors=uo.Sensors.auv(vehicle))
    assert estimator.model.nx == 6 and estimator.model.nc == 2
    current = uo.Current(speed=0.2, direction=math.pi / 6 + math.pi / 2)  # across the line
    x0 = problem.initial_state([0.0, 0.0, math.pi / 6, 0.5, 0.0, 0.0])
    run = uo.simulate(
        uo.NMPC(problem, "sqp-rti"), x0=x0, duration=60.0, current=current, estimator=estimator, seed=2
    )
    assert run.fault is None
    truth = 0.2 * np.array([math.cos(current.direction), math.sin(current.direction)])
    late = run.t[:-1] >= 40.0
    error = np.linalg.norm(run.estimates.currents[late] - truth, axis=1)
    assert np.max(error) < 0.04  # the sensors' noise (measured: 0.022)
    assert np.linalg.norm(run.estimates.currents[late].mean(axis=0) - truth) < 0.01
    assert np.linalg.norm(run.estimates.currents[0] - truth) > 0.1  # it started from zero
    # the controller kept its own path parameter: the plant's, not an estimate
    assert run.estimates.states.shape[1] == 6
    cross = _signed_distance_to_line(
        run.states[:, :2], np.zeros(2), np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    )
    assert np.max(np.abs(cross[run.t >= 40.0])) < 0.25  # a 0.5 m position fix (measured: 0.11)


def test_path_metrics_against_numpy() -> None:
    """A made-up run beside a 90 m line at 10 m depth, going on past its end to 120 m.

    Reference (numpy, here): the cross-track error is ``|y|`` while ``x < 90`` m (then the
    vehicle has passed the end), the depth error ``z − 10``, the fin activity ``Σ|Δδ|`` and the
    energy ``Σ 2π n_s Q Δt`` with the REMUS propeller torque written out from Fossen's model.
    """
    line = uo.Reference.from_xyz(lambda t: 1.5 * t, lambda t: 0 * t, lambda t: 10 + 0 * t, "line", t_end=60.0)
    vehicle = uo.Remus100()
    problem = PathFollowingProblem(vehicle, line, speed=1.5)
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 80.0, 157)  # positions between the path samples (3 cm apart)
    states = np.zeros((157, 13))
    states[:, 0] = 1.5 * t
    states[:, 1] = 2.0 * np.sin(0.1 * t) + 0.1 * rng.normal(size=157)
    states[:, 2] = 10.0 + 0.3 * rng.normal(size=157)
    states[:, 6:9] = rng.normal([1.5, 0.0, 0.0], 0.1, size=(157, 3))
    controls = np.column_stack(
        [rng.uniform(-0.2, 0.2, (156, 2)), rng.uniform(800.0, 1500.0, 156), np.full(156, 1.5)]
    )
    run = type("Run", (), {"t": t, "states": states, "controls": controls})()
    found = uo.path_metrics(run, problem)
    before = states[:, 0] < 90.0  # at 90 m the closest point is the end
    np.testing.assert_allclose(found["cross_track_rms"], np.sqrt(np.mean(states[before, 1] ** 2)), rtol=1e-9)
    assert found["cross_track_max"] == pytest.approx(np.max(np.abs(states[before, 1])), rel=1e-9)
    assert found["depth_rms"] == pytest.approx(np.sqrt(np.mean((states[:, 2] - 10.0) ** 2)), rel=1e-9)
    assert found["fin_activity"] == pytest.approx(np.sum(np.abs(np.diff(controls[:, :2], axis=0))), rel=1e-12)
    rho, d_p = 1026.0, 0.14  # Fossen's remus100.py: rho, D_prop, KQ_0, KQ_max, Ja_max, w
    n = controls[:, 2] / 60.0
    va = 0.944 * np.sqrt(np.sum(states[:-1, 6:9] ** 2, axis=1))
    q = rho * d_p**5 * (0.0700 * np.abs(n) * n + (0.0312 - 0.0700) / 0.6632 * va / d_p * np.maximum(n, 0))
    assert found["energy"] == pytest.approx(np.sum(2 * np.pi * n * q * np.diff(t)), rel=1e-9)
    assert found["completed"] == 1.0
    tracking = uo.path_metrics(run, uo.TrackingProblem(vehicle, line, horizon=1, dt=0.5))
    assert tracking == pytest.approx(found, rel=1e-12)  # the same path through a tracking problem


def test_replace_recomputes_the_defaults_it_filled_in_and_u_prev_defaults_into_the_box() -> None:
    """A copy at another speed gets that speed's propeller floor, another vehicle its rate weight.

    The floor is checked against the cruise rpm of the independent REMUS implementation
    (tests/helpers_remus.py); a given ``control_lower`` or rate weight is kept.
    """
    problem = PathFollowingProblem(uo.Remus100(), _remus_line(), speed=1.5, horizon=4, dt=0.5)
    slower = problem.replace(speed=0.8)
    state = np.zeros(12)
    state[0] = 0.8
    cruise = slower.control_lower[2] / 0.9
    assert remus.remus100_derivative(state, [0.0, 0.0, cruise])[0] == pytest.approx(0.0, abs=1e-9)
    assert slower.control_lower[2] < 0.6 * problem.control_lower[2]
    assert slower.weights.rate == problem.weights.rate == 500.0
    rexrov = problem.replace(vehicle=uo.Vehicle.rexrov(), path=_planar_line(), speed=0.5)
    assert rexrov.weights.rate == 1.0
    given = PathFollowingProblem(
        uo.Remus100(), _remus_line(), speed=1.5, horizon=4, control_lower=(-0.1, -0.1, 100.0)
    )
    assert given.replace(speed=0.8).control_lower == (-0.1, -0.1, 100.0)
    assert given.replace(weights=uo.PathWeights(rate=7.0)).weights.rate == 7.0
    # no previous control given: zero clipped into the box (the floor), not a refusal
    x0 = np.zeros(13)
    x0[0] = 1.5
    packed = problem.instance_parameters(x0)
    spec = problem.spec()
    explicit = problem.instance_parameters(x0, u_prev=np.clip(np.zeros(4), spec.lower, spec.upper))
    np.testing.assert_array_equal(packed, explicit)


def test_the_path_window_gives_the_whole_tables_point_and_tangent_wherever_a_plan_reaches() -> None:
    """PathWindow: rows chosen from s_0, the path's point and tangent as the whole look-up.

    On the 3-D survey (REMUS 100, N = 20, dt = 0.5: a plan moves at most 30 m along the
    path) from 400 starts, at s up to 30 m of path ahead (20 s of reference time at 1.5 m/s)
    and 0.5 s behind: the window's point and tangent against ``problem.geometry`` (the
    reference's full table, its tangent rotated from heading and body velocities), to rounding.
    Past the window (beyond its reach) the last piece's formula is extended: 250 m ahead, on
    the second lane, the first turn's circle is not the lane.
    """
    survey = uo.Reference.lawnmower(width=150.0, spacing=60.0, lanes=3, speed=1.5, depth=10.0)
    problem = PathFollowingProblem(uo.Remus100(), survey, speed=1.5, horizon=20, dt=0.5)
    window = problem.window
    assert window is not None and window.rows == (2, 2)  # x, y, heading share one table; depth
    s, rows = ca.SX.sym("s"), ca.SX.sym("w", window.size)
    windowed = ca.Function("windowed", [s, rows], [ca.vertcat(*window.geometry(s, rows))])
    rng = np.random.default_rng(7)
    worst = 0.0
    for s0 in rng.uniform(0.0, problem.path_end, 400):
        values = window.values(s0)
        for t in np.r_[s0 - 0.5, np.linspace(s0, s0 + 20.0, 9)]:
            exact = np.concatenate([np.array(part).ravel() for part in problem.geometry(t)])
            worst = max(worst, float(np.max(np.abs(np.array(windowed(t, values)).ravel() - exact))))
    assert worst < 1e-12
    far = 2.0 + 250.0 / 1.5  # 3 m along the first lane (120 m), then 250 m: the second lane
    exact = np.concatenate([np.array(part).ravel() for part in problem.geometry(far)])
    assert np.max(np.abs(np.array(windowed(far, window.values(2.0))).ravel() - exact)) > 1.0


def test_the_path_window_counts_the_piece_a_rounded_reach_meets() -> None:
    """PathWindow.of counts rows per piece start, not through ``(start − reach) + reach``.

    On these waypoints (found by a reviewer's random search, N = 8) that round trip came one
    ulp short of a start: 3 rows where 4 are reached. Checked against the full table at the
    keys a plan can reach from starts just behind that piece's start.
    """
    points = [[9.41351481464853, -10.271467107628443], [13.899936518312977, -4.699254686835168]]
    points += [[22.344705453678763, 1.751065240234496], [28.516318289919575, 5.158541985356503]]
    points += [[39.553527676598954, -6.83404305022914], [44.06724317509648, -11.944634865257555]]
    reference = uo.Reference.waypoints(np.array(points), speed=0.5, turn_radius=1.0)
    horizon, dt, speed = 8, 0.5, 1.0
    problem = PathFollowingProblem(
        uo.Vehicle.rexrov(), reference, speed=0.5, horizon=horizon, dt=dt, max_path_speed=speed
    )
    window = problem.window
    assert window is not None and window.rows == (4,)
    s, rows = ca.SX.sym("s"), ca.SX.sym("w", window.size)
    windowed = ca.Function("windowed", [s, rows], [ca.vertcat(*window.geometry(s, rows))])
    fine = np.linspace(reference.t_start, problem.path_end, 8001)
    keys = np.array(window.keys.map(fine.size)(fine[None, :]))[0]
    worst = 0.0
    for s0 in fine[::20]:
        values = window.values(s0)
        key0 = float(window.keys(s0)[0])
        ahead = (fine >= s0) & (keys <= key0 + horizon * dt * speed)
        for t in fine[ahead][::3]:
            exact = np.concatenate([np.array(part).ravel() for part in problem.geometry(t)])
            worst = max(worst, float(np.max(np.abs(np.array(windowed(t, values)).ravel() - exact))))
    assert worst < 1e-12


def test_the_path_window_plans_as_the_whole_table(monkeypatch) -> None:
    """A plan with the window (rows from s_0) is the plan with the whole table, across a turn.

    The RexROV 1 m before the first turn of three 40 m lanes, N = 10: IPOPT with PATH_WINDOW
    on and off.
    """
    from uuv_ocp import path_following

    plans = {}
    for on in (False, True):
        monkeypatch.setattr(path_following, "PATH_WINDOW", on)
        survey = uo.Reference.lawnmower(width=40.0, spacing=10.0, lanes=3, speed=1.5)
        problem = PathFollowingProblem(uo.Vehicle.rexrov(), survey, speed=0.5, horizon=10, dt=0.5)
        assert (problem.window is not None) == on
        s0 = (40.0 - 5.0 - 1.0) / 1.5  # 1 m before the arc of radius 5 m at the first lane's end
        point = np.array(problem.geometry(s0)[0]).ravel()
        x0 = np.r_[point, 0.0, 0.5, 0.0, 0.0, s0]
        backend = get_solver(problem, "ipopt", {"plugin_options": {"ipopt.tol": 1e-10}})
        plans[on] = backend.solve(problem.parameters(x0, np.r_[0.0, 0.0, 0.0, 0.5]), None)
        assert plans[on].success
    assert plans[True].states[-1, -1] > (40.0 - 5.0) / 1.5  # the plan reaches into the turn
    np.testing.assert_allclose(plans[True].states, plans[False].states, rtol=0, atol=1e-8)
    np.testing.assert_allclose(plans[True].controls, plans[False].controls, rtol=1e-8, atol=1e-6)


def test_with_state_chooses_the_path_window_again() -> None:
    """``with_state(p, x)`` is ``parameters(x, ...)``: the window follows ``s_0`` (NMPC.prepare's path).

    From a start on the first lane to one in the first turn (another window).
    """
    survey = uo.Reference.lawnmower(width=150.0, spacing=60.0, lanes=3, speed=1.5, depth=10.0)
    problem = PathFollowingProblem(uo.Remus100(), survey, speed=1.5, horizon=20, dt=0.5)
    x_lane = problem.initial_state(np.r_[10.0, np.zeros(5), 1.5, np.zeros(5)])
    x_turn = np.r_[x_lane[:-1], (120.0 + 50.0) / 1.5]  # 50 m into the first turn
    u_prev, current = np.r_[0.0, 0.0, 1000.0, 1.5], [0.1, -0.2, 0.0]
    p = problem.parameters(x_lane, u_prev, current)
    expected = problem.parameters(x_turn, u_prev, current)
    window = problem.spec().layout.entries["path_window"][0]
    assert not np.array_equal(p[window], expected[window])  # another window
    np.testing.assert_array_equal(problem.with_state(p, x_turn), expected)


def test_reading_a_window_while_another_problem_builds_does_not_deadlock(monkeypatch) -> None:
    """Reading b.window while a.ocp is being built in another thread returns (forced interleaving).

    .window and .geometry were functools.cached_property (one lock per class attribute in
    Python 3.11) taking BUILD_LOCK inside, while .ocp holds BUILD_LOCK and reads .window: a
    lock-order inversion across instances.  Forced interleaving (legal in any run): B reads
    b.window while A is inside a._declare, holding BUILD_LOCK, before A reads a.window.
    """
    import threading
    import time

    from uuv_ocp import path_following

    survey = uo.Reference.lawnmower(width=150.0, spacing=60.0, lanes=3, speed=1.5, depth=10.0)
    a = PathFollowingProblem(uo.Remus100(), survey, speed=1.5, horizon=20, dt=0.5)
    b = PathFollowingProblem(uo.Remus100(), survey, speed=1.5, horizon=21, dt=0.5)
    inside = threading.Event()
    original = path_following.vehicle_rhs

    def slow_rhs(*args, **kwargs):  # A is in _declare, holding BUILD_LOCK
        inside.set()
        time.sleep(0.3)  # B asks for its window meanwhile
        return original(*args, **kwargs)

    monkeypatch.setattr(path_following, "vehicle_rhs", slow_rhs)
    threads = [
        threading.Thread(target=lambda: a.ocp, daemon=True),
        threading.Thread(target=lambda: (inside.wait(), b.window, b.path_end), daemon=True),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(20.0)  # a regression fails here instead of hanging the suite
    assert not any(thread.is_alive() for thread in threads), "deadlock: both threads still waiting after 20 s"
    fresh = PathFollowingProblem(uo.Remus100(), survey, speed=1.5, horizon=21, dt=0.5)  # this thread
    window, expected = b.window, fresh.window
    assert isinstance(window, path_following.PathWindow) and isinstance(expected, path_following.PathWindow)
    assert window.rows == expected.rows
    assert b.path_end == fresh.path_end and "_declared_ocp" in a.__dict__
