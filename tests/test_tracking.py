"""The formulation: NLP objective = condensed cost = score, gradients, parameters, validation."""

import math

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers.ipopt import IpoptSolver


def nlp_objective_at_rollout(problem, scaled, p):
    """Evaluate the hard NLP's objective at the point built from a rollout of ``scaled``."""
    built = problem.build()
    solver = IpoptSolver(problem)
    _, reference, u_prev, _ = problem.parameter_parts(p)
    states = np.array(built.rollout(scaled, p)).T
    primal = solver.compose_primal("hard", states, scaled.reshape(-1, 3), u_prev / problem.max_thrust)
    data = built.hard
    # tube slacks at their optimal value max(0, |e| - tube), on nodes 1..N
    if problem.position_tube is not None:
        position = {key: i for i, key in enumerate(data.variable_keys)}
        slack_kinds = {key[0] for key in data.variable_keys if key[0].endswith("_slack")}
        assert len(slack_kinds) == 1
        kind = slack_kinds.pop()
        for k in range(1, problem.horizon + 1):
            excess = np.maximum(0.0, np.abs(states[k, :2] - reference[k, :2]) - problem.position_tube)
            for i in range(2):
                primal[position[(kind, k, i)]] = excess[i]
    f = ca.Function("f", [data.nlp["x"], data.nlp["p"]], [data.nlp["f"], data.nlp["g"]])
    objective, constraints = f(primal, p)
    return float(objective), np.array(constraints).ravel(), data


@pytest.mark.parametrize("terminal", ["equality", "cost", "none"])
@pytest.mark.parametrize("tube", [None, 0.05])
def test_nlp_objective_equals_condensed_cost_and_score(terminal, tube):
    reference = uo.Reference.paper("s8")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), reference, horizon=8, terminal=terminal, position_tube=tube
    )
    rng = np.random.default_rng(3)
    x0 = reference.evaluate([2.0])[0] + rng.normal(scale=0.1, size=6)
    for _ in range(5):
        u_prev = rng.uniform(-1500, 1500, size=3)
        p = problem.parameters(x0, 2.0, u_prev=u_prev, current=[0.1, -0.2])
        scaled = rng.uniform(-1, 1, size=problem.control_dim)
        objective, constraints, data = nlp_objective_at_rollout(problem, scaled, p)
        condensed, _penalty = problem.build().cost(scaled, p)
        cost, _violation = uo.score(
            problem,
            problem.controls_from_scaled(scaled),
            x0,
            2.0,
            u_prev=u_prev,
            current=[0.1, -0.2],
        )
        assert objective == pytest.approx(float(condensed), rel=1e-9)
        assert objective == pytest.approx(cost, rel=1e-9)
        # the rollout point satisfies the dynamics constraints exactly
        dynamics = np.array([key[0] in ("dynamics", "initial") for key in data.constraint_keys])
        assert np.max(np.abs(constraints[dynamics])) < 1e-10


def test_condensed_gradient_matches_finite_differences(s2_problem, feasible_start):
    x0, t0 = feasible_start
    p = s2_problem.parameters(x0, t0)
    cost = s2_problem.build().cost
    scaled = np.random.default_rng(1).uniform(-0.5, 0.5, s2_problem.control_dim)
    symbol = ca.SX.sym("U", s2_problem.control_dim)
    objective = cost(symbol, p)[0]
    gradient = np.array(ca.Function("g", [symbol], [ca.gradient(objective, symbol)])(scaled)).ravel()
    step = 1e-6
    for index in [0, 7, 31, 59]:
        bump = np.zeros_like(scaled)
        bump[index] = step
        central = (float(cost(scaled + bump, p)[0]) - float(cost(scaled - bump, p)[0])) / (2 * step)
        assert gradient[index] == pytest.approx(central, rel=1e-5, abs=1e-4)


def test_score_reports_terminal_and_rate_violations(s2_problem, feasible_start):
    x0, t0 = feasible_start
    zero = np.zeros((s2_problem.horizon, 3))
    cost, violation = uo.score(s2_problem, zero, x0, t0)
    p = s2_problem.parameters(x0, t0)
    states = s2_problem.rollout(zero, p)
    _, reference, _, _ = s2_problem.parameter_parts(p)
    assert violation == pytest.approx(np.max(np.abs(states[-1] - reference[-1])), rel=1e-12)
    jump = zero.copy()
    jump[0, 0] = 2000.0  # 1.0 scaled in one step, bound is 0.2
    _, rate_violation = uo.score(s2_problem.replace(terminal="none"), jump, x0, t0)
    assert rate_violation == pytest.approx(0.8, rel=1e-12)


def test_reference_heading_is_aligned_with_the_vehicle(s2_problem):
    reference = uo.Reference.paper("s2")
    x0 = reference.initial_state(1.0)
    x0[2] += 4 * math.pi
    _, window, _, _ = s2_problem.parameter_parts(s2_problem.parameters(x0, 1.0))
    assert window[0, 2] == pytest.approx(x0[2])


def _direct_window(reference, t0, dt, horizon, heading):
    window = reference.evaluate(t0 + dt * np.arange(horizon + 1))
    window[:, 2] += 2 * math.pi * np.round((heading - window[0, 2]) / (2 * math.pi))
    return window


@pytest.mark.parametrize(
    "reference",
    [
        uo.Reference.paper("s3"),  # starts at t = 1 s: the first sample block is clipped
        uo.Reference.paper("s8"),
        uo.Reference.from_xy(lambda t: 3 * ca.cos(2 * t), lambda t: 3 * ca.sin(2 * t), "fast circle"),
    ],
    ids=["s3", "s8", "fast-circle"],
)
def test_windows_cut_from_sample_blocks_match_direct_evaluation(reference):
    """Windows cut from cached sample blocks equal a direct evaluation of the reference.

    Closed-loop windows (t0 = i dt) come from cached blocks of samples; this holds across block
    boundaries and many heading turns.
    """
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=20, dt=0.1)
    heading = 0.7 - 6 * math.pi
    first = int(math.ceil(reference.t_start / 0.1))
    for index in range(first, first + 150):  # windows inside, across and after blocks 0-2
        t0 = index * 0.1
        expected = _direct_window(reference, t0, 0.1, 20, heading)
        np.testing.assert_allclose(problem.reference_window(t0, heading), expected, rtol=1e-13, atol=1e-11)
        # without a vehicle heading: the reference's own branch, first value in [-π, π]
        as_given = reference.evaluate(t0 + 0.1 * np.arange(21))
        np.testing.assert_allclose(problem.reference_window(t0), as_given, rtol=1e-13, atol=1e-11)
    blocks = problem.sample_blocks
    assert len(blocks) >= 3 and all(block is not None for block in blocks.values())
    # off the sampling grid: the direct evaluation itself
    t0 = first * 0.1 + 0.05
    np.testing.assert_allclose(
        problem.reference_window(t0, heading),
        _direct_window(reference, t0, 0.1, 20, heading),
        rtol=1e-13,
        atol=1e-11,
    )


def test_a_stationary_point_outside_the_window_does_not_matter():
    """A point where the heading is undefined raises only in a window containing it.

    The sample block around a window may hold such a point: the window then comes from a
    direct evaluation.
    """
    reference = uo.Reference.from_xy(lambda t: (t - 5) ** 3, lambda t: 0 * t, "stops at t = 5")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=20, dt=0.1)
    np.testing.assert_allclose(
        problem.reference_window(1.0, 0.0), _direct_window(reference, 1.0, 0.1, 20, 0.0), atol=1e-12
    )
    with pytest.raises(ValueError, match=r"t = 5\.0"):
        problem.reference_window(4.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        problem.reference_window(math.inf)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"horizon": -3}, "horizon"),
        ({"horizon": 0}, "horizon"),
        ({"horizon": 2.5}, "horizon"),
        ({"dt": 0.0}, "dt"),
        ({"dt": -0.1}, "dt"),
        ({"terminal": "hard"}, "terminal"),
        ({"position_tube": -1.0}, "position_tube"),
        ({"substeps": 0}, "substeps"),
    ],
)
def test_bad_problem_arguments_raise(kwargs, name):
    with pytest.raises(ValueError, match=name):
        uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), **kwargs)


@pytest.mark.parametrize(
    ("x0", "match"),
    [
        (np.zeros(5), r"x0 must have shape \(6,\)"),
        (np.array([0, 0, np.nan, 0, 0, 0]), "x0 must be finite"),
        ("abc", "x0"),
    ],
)
def test_bad_state_raises_before_solving(s2_problem, x0, match):
    with pytest.raises(ValueError, match=match):
        uo.solve(s2_problem, "ipopt", x0=x0, t0=0.0)


def test_bad_start_time_raises(s2_problem):
    x0 = uo.Reference.paper("s2").initial_state()
    with pytest.raises(ValueError, match="t0"):
        uo.solve(s2_problem, "ipopt", x0=x0, t0=-1.0)


def test_weights_validation():
    with pytest.raises(ValueError, match="weights.pose"):
        uo.Weights(pose=(1.0, -1.0, 1.0))
    with pytest.raises(ValueError, match="weights.terminal_penalty"):
        uo.Weights(terminal_penalty=0.0)


def test_clearance_of_a_moving_obstacle_needs_its_centre():
    position = ca.SX.sym("position", 2)
    static = uo.Obstacle.circle((1.0, 2.0), 0.5, margin=0.5)
    value = ca.Function("c", [position], [static.clearance(position)])
    assert float(value([1.0, 4.0])) == pytest.approx(2.0**2 - 1.0**2)
    moving = uo.Obstacle.moving(lambda t: (t, 0 * t), 0.5)
    with pytest.raises(ValueError, match="moves"):
        moving.clearance(position)
    centre = ca.SX.sym("centre", 2)
    value = ca.Function("c", [position, centre], [moving.clearance(position, centre)])
    assert float(value([3.0, 0.0], [1.0, 0.0])) == pytest.approx(2.0**2 - 0.5**2)


def test_rk4_stability_of_the_remus_roll_mode_at_rest() -> None:
    """RK4 on the REMUS 100 at rest: stable for h <= 0.446 s (its roll mode −1.94 ± 6.03i /s).

    Reference: the one-step matrix of RK4 on the finite-difference linearisation, ``Σ (hA)^k/k!``
    (k <= 4), its spectral radius over the decaying modes (numpy), and the model's documented
    bound.
    """
    import warnings

    from uuv_ocp.tracking import Rk4StabilityWarning, rest_eigenvalues, rk4_amplification, stable_substeps

    vehicle = uo.Remus100()
    f = vehicle.dynamics
    step = 1e-6
    columns = [
        (
            np.array(f(step * e, np.zeros(3), np.zeros(3))) - np.array(f(-step * e, np.zeros(3), np.zeros(3)))
        ).ravel()
        / (2 * step)
        for e in np.eye(12)
    ]
    a = np.array(columns).T
    values, vectors = np.linalg.eig(a)
    decaying = values.real < -1e-9
    for h, stable in ((0.44, True), (0.45, False), (0.25, True)):
        ha = h * a
        one_step = np.eye(12) + ha + ha @ ha / 2 + ha @ ha @ ha / 6 + ha @ ha @ ha @ ha / 24
        growth = np.max(np.abs(np.linalg.eigvals(np.linalg.solve(vectors, one_step @ vectors))[decaying]))
        assert rk4_amplification(
            rest_eigenvalues(vehicle)[rest_eigenvalues(vehicle).real < -1e-9], h
        ) == pytest.approx(growth, rel=1e-6)
        assert (growth <= 1.0) == stable
    assert stable_substeps(vehicle, 0.5) == 2 and stable_substeps(vehicle, 0.4) == 1
    assert stable_substeps(vehicle, 1.0) == 3  # h = 0.333 s
    reference = uo.Reference.from_xyz(lambda t: 1.5 * t, lambda t: 0 * t, lambda t: 10 + 0 * t, "line")
    with pytest.warns(Rk4StabilityWarning, match="substeps = 2 is stable"):
        uo.TrackingProblem(vehicle, reference, horizon=5, dt=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", Rk4StabilityWarning)
        uo.TrackingProblem(vehicle, reference, horizon=5, dt=0.5, substeps=2)
        assert uo.PathFollowingProblem(vehicle, reference, speed=1.5, dt=0.5, substeps=None).substeps == 2


def test_the_ocp_plans_the_thrusters_first_order_response():
    """BlueROV2 Heavy thrusters with τ = 0.3 s: the OCP's state carries the delivered forces.

    Their weights are zero (referenced to zero, not tracked), and the plan of an IPOPT step from
    rest obeys the exact discretisation of ``ḟ_a = (f − f_a)/τ`` under held commands,
    ``f_a,k+1 = f_k + (f_a,k − f_k) exp(−dt/τ)`` (RK4's error at dt/τ = 1/3 is below 1e-4).
    """
    import dataclasses

    boat = uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)
    constant = 0.3
    boat = dataclasses.replace(boat, thrusters=dataclasses.replace(boat.thrusters, time_constant=constant))
    reference = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.5, depth=2.0)
    problem = uo.TrackingProblem(boat, reference, horizon=5, dt=0.1, terminal="cost")
    assert problem.weights.pose[6:] == (0.0,) * 8 and len(problem.weights.velocity) == 6
    x0 = problem.initial_state()
    assert x0.shape == (20,) and np.all(x0[6:14] == 0.0)
    plan = uo.NMPC(problem, "ipopt").step(x0, 0.0, np.zeros(8)).result
    states, controls = np.asarray(plan.states), np.asarray(plan.controls)
    delivered = states[:, 6:14]
    decay = np.exp(-problem.dt / constant)
    expected = controls + (delivered[:-1] - controls) * decay
    scale = np.abs(controls).max()
    assert scale > 1.0  # the plan pushes, so the check has something to check
    np.testing.assert_allclose(delivered[1:], expected, rtol=0.0, atol=1e-4 * scale)


def test_weights_may_have_more_pose_entries_than_velocities():
    """Actuator states in the pose (zero-weighted): 14 pose, 6 velocity, 20 terminal; not 6 > 3."""
    weights = uo.Weights(pose=(1.0,) * 14, velocity=(1.0,) * 6, terminal=(1.0,) * 20)
    assert len(weights.terminal) == 20
    with pytest.raises(ValueError, match="weights.terminal must have 20 entries"):
        uo.Weights(pose=(1.0,) * 14, velocity=(1.0,) * 6, terminal=(1.0,) * 28)
