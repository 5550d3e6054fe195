"""TrackingProblem on the 6-DOF Fossen model: depth and heading tracking, roll and pitch held."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF


@pytest.fixture(scope="module")
def dive():
    boat = Vehicle6DOF.bluerov2_heavy()
    ref = uo.Reference.from_xyz(
        lambda t: 0.3 * t, lambda t: ca.sin(0.2 * t), lambda t: 1.0 + 0.5 * ca.sin(0.1 * t), name="dive"
    )
    return uo.TrackingProblem(boat, ref, horizon=20, dt=0.1)


def test_exact_solvers_agree_on_the_6dof_problem(dive):
    ref = dive.reference
    x0 = ref.initial_state(2.0) + np.r_[0.05, -0.05, 0.1, 0.02, -0.02, 0.05, np.zeros(6)]
    results = {s: uo.solve(dive, s, x0=x0, t0=2.0) for s in ("ipopt", "fatrop", "sqp")}
    for name, res in results.items():
        assert res.success, (name, res.status)
        assert res.states.shape == (21, 12) and res.controls.shape == (20, 6)
        assert np.all(np.abs(res.controls) <= np.asarray(dive.max_thrust) * (1 + 1e-12))
    costs = [res.cost for res in results.values()]
    assert max(costs) == pytest.approx(min(costs), rel=1e-6)
    # the terminal equality holds at the prediction: depth and heading of the reference at t0 + N dt
    target = dive.reference_window(2.0, heading=x0[5])[-1]
    np.testing.assert_allclose(results["ipopt"].states[-1], target, atol=1e-6)


def test_closed_loop_tracks_depth_with_roll_and_pitch_near_zero(dive):
    ref = dive.reference
    run = uo.simulate(uo.NMPC(dive, "sqp"), ref.initial_state(0.0), duration=4.0)
    assert run.failures == 0
    settled = run.t >= 2.0
    # errors against the reference evaluated independently at the run's times
    expected = np.column_stack([0.3 * run.t, np.sin(0.2 * run.t), 1.0 + 0.5 * np.sin(0.1 * run.t)])
    assert np.max(np.abs(run.states[settled, :3] - expected[settled])) < 1e-3
    assert np.max(np.abs(run.states[:, 3:5])) < 0.05  # roll and pitch regulated


def test_thruster_driven_vehicle_holds_per_thruster_bounds():
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    hold = uo.Reference.hold((0.0, 0.0, 1.0, 0.5), duration=10.0)
    problem = uo.TrackingProblem(boat, hold, horizon=10, dt=0.1, terminal="cost")
    x0 = np.r_[0.1, -0.1, 0.9, 0.0, 0.0, 0.4, np.zeros(6)]
    res = uo.solve(problem, "fatrop", x0=x0)
    assert res.success and res.controls.shape == (10, 8)
    assert res.cost == pytest.approx(uo.solve(problem, "ipopt", x0=x0).cost, rel=1e-7)
    assert np.all(np.abs(res.controls) <= np.asarray(boat.control_bound) * (1 + 1e-12))
    # the plan's states are the rollout of τ = T f through the vehicle's own dynamics Function
    step = uo.rk4_step(boat.dynamics, 0.1)
    x = x0
    for f in res.controls:
        x = np.array(step(x, boat.allocation @ f, np.zeros(3))).ravel()
    np.testing.assert_allclose(res.states[-1], x, atol=1e-6)


def test_a_planar_reference_for_a_6dof_vehicle_is_refused():
    with pytest.raises(ValueError, match="reference must give 12 states"):
        uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), uo.Reference.paper("s2"))
    with pytest.raises(ValueError, match="weights.pose must have 6 entries"):
        uo.TrackingProblem(
            Vehicle6DOF.bluerov2_heavy(), uo.Reference.hold((0, 0, 1, 0)), weights=uo.Weights()
        )


def test_thruster_rollout_equals_an_independent_integration_of_tau_equals_t_f():
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(
        boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.5)), horizon=6, dt=0.1, terminal="cost"
    )
    rng = np.random.default_rng(5)
    forces = rng.uniform(-1.0, 1.0, size=(6, 8)) * np.asarray(boat.control_bound)
    x0 = np.r_[0.1, -0.1, 0.9, 0.05, -0.02, 0.4, 0.1, 0.0, -0.05, 0.0, 0.02, 0.1]
    p = problem.parameters(x0, 0.0, u_prev=forces[0])
    step = uo.rk4_step(boat.dynamics, 0.1)
    x, states = x0, [x0]
    for f in forces:
        x = np.array(step(x, boat.allocation @ f, np.zeros(3))).ravel()
        states.append(x)
    np.testing.assert_allclose(problem.rollout(forces, p), np.array(states), rtol=1e-12, atol=1e-12)


def test_roll_pitch_and_heading_errors_are_wrap_safe():
    boat = Vehicle6DOF.bluerov2_heavy()
    problem = uo.TrackingProblem(
        boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.0)), horizon=5, dt=0.1, terminal="cost"
    )
    controls = np.zeros((5, 6))
    base = np.r_[0.0, 0.0, 1.0, 0.1, -0.1, 0.2, np.zeros(6)]
    for index in (3, 4, 5):  # φ, θ, ψ shifted by a full turn: the same pose
        turned = base.copy()
        turned[index] += 2 * np.pi
        reference_cost, _ = uo.score(problem, controls, x0=base, t0=0.0)
        turned_cost, _ = uo.score(problem, controls, x0=turned, t0=0.0)
        assert turned_cost == pytest.approx(reference_cost, rel=1e-9)
