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


# ------------------------------------------------------- thruster health (issue 27)
def _no_rate_cost(vehicle):
    """Default weights without the control-rate cost: the optimum then depends on τ = T f only."""
    w = uo.Weights.for_layout(vehicle.layout)
    return uo.Weights(
        pose=w.pose, velocity=w.velocity, rate=(0.0,) * vehicle.layout.control_dim, terminal=w.terminal
    )


def test_thruster_ocp_reaches_the_force_ocp_optimum_when_no_thruster_saturates():
    # the same vehicle planning in 8 thruster forces and in the 6 generalised forces: with no
    # control cost and no bound active, both optima give the same τ and states (the allocation
    # of τ to thrusters is then not unique, so f itself is not compared)
    thrusters, forces = Vehicle6DOF.bluerov2_heavy(thrusters=True), Vehicle6DOF.bluerov2_heavy()
    hold = uo.Reference.hold((0.0, 0.0, 1.0, 0.3), duration=10.0)
    x0 = np.r_[0.002, -0.0015, 1.001, 0.0, 0.0, 0.299, np.zeros(6)]
    options = {"plugin_options": {"ipopt.tol": 1e-12}}
    results = []
    for vehicle in (thrusters, forces):
        problem = uo.TrackingProblem(
            vehicle,
            hold,
            horizon=8,
            dt=0.1,
            terminal="cost",
            weights=_no_rate_cost(vehicle),
            rate_limits=False,
        )
        results.append(uo.solve(problem, "ipopt", x0=x0, options=options))
    in_thrusters, in_forces = results
    assert in_thrusters.success and in_forces.success
    # nothing saturates: every thruster and every generalised force well inside its box
    assert np.max(np.abs(in_thrusters.controls)) < 0.5 * 40.0
    assert np.max(np.abs(in_forces.controls) / np.asarray(forces.max_thrust)) < 0.5
    np.testing.assert_allclose(
        in_thrusters.controls @ thrusters.allocation.T, in_forces.controls, rtol=0, atol=1e-8
    )
    np.testing.assert_allclose(in_thrusters.states, in_forces.states, rtol=0, atol=1e-8)
    assert in_thrusters.cost == pytest.approx(in_forces.cost, rel=1e-8)


def test_a_thruster_at_zero_health_is_never_used_and_the_cost_is_that_without_its_column():
    import dataclasses

    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    dead = 4  # a vertical thruster: the other three still drive heave, roll and pitch
    config = boat.thrusters
    keep = [i for i in range(config.count) if i != dead]
    seven = uo.ThrusterConfiguration(
        positions=[config.positions[i] for i in keep],
        directions=[config.directions[i] for i in keep],
        max_thrust=[config.max_thrust[i] for i in keep],
    )
    reduced = dataclasses.replace(boat, thrusters=seven)
    hold = uo.Reference.hold((0.0, 0.0, 1.0, 0.3), duration=10.0)
    x0 = np.r_[0.1, -0.08, 0.9, 0.0, 0.0, 0.2, np.zeros(6)]
    health = np.ones(8)
    health[dead] = 0.0
    problem = uo.TrackingProblem(boat, hold, horizon=10, dt=0.1, terminal="cost")
    without = uo.TrackingProblem(reduced, hold, horizon=10, dt=0.1, terminal="cost")
    plan = uo.solve(problem, "ipopt", x0=x0, parameters={"health": health})
    reference = uo.solve(without, "ipopt", x0=x0)
    assert plan.success and reference.success
    assert plan.cost == pytest.approx(reference.cost, rel=1e-7)
    np.testing.assert_allclose(plan.states, reference.states, atol=1e-6)
    np.testing.assert_allclose(plan.controls[:, keep], reference.controls, atol=1e-5 * 40.0)
    # its force is irrelevant to the model: any value of it gives the same rollout
    p = problem.parameters(x0, 0.0, model={"health": health})
    changed = plan.controls.copy()
    changed[:, dead] = 35.0
    np.testing.assert_array_equal(problem.rollout(changed, p), problem.rollout(plan.controls, p))


def test_health_and_thrust_offset_enter_the_model_as_t_times_h_f_plus_s():
    # the Ocp's rollout against RK4 of the force model with τ = T (h ∘ f + s) written out here
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(
        boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.5)), horizon=5, dt=0.1, terminal="cost"
    )
    rng = np.random.default_rng(27)
    forces = rng.uniform(-1.0, 1.0, size=(5, 8)) * 40.0
    health = rng.uniform(0.0, 1.0, size=8)
    offset = np.zeros(8)
    offset[2] = -12.5  # thruster 3 stuck at -12.5 N: health 0, offset -12.5
    health[2] = 0.0
    x0 = np.r_[0.1, -0.1, 0.9, 0.05, -0.02, 0.4, 0.1, 0.0, -0.05, 0.0, 0.02, 0.1]
    p = problem.parameters(x0, 0.0, u_prev=forces[0], model={"health": health, "thrust_offset": offset})
    step = uo.rk4_step(boat.dynamics, 0.1)
    allocation = np.array(boat.thrusters.allocation)
    x, states = x0, [x0]
    for f in forces:
        tau = sum(allocation[:, i] * (health[i] * f[i] + offset[i]) for i in range(8))
        x = np.array(step(x, tau, np.zeros(3))).ravel()
        states.append(x)
    np.testing.assert_allclose(problem.rollout(forces, p), np.array(states), rtol=1e-12, atol=1e-12)
    # the defaults are the healthy vehicle: the parameters omitted equal ones and zeros
    np.testing.assert_array_equal(
        problem.parameters(x0, 0.0),
        problem.parameters(x0, 0.0, model={"health": np.ones(8), "thrust_offset": np.zeros(8)}),
    )


def test_health_is_a_parameter_the_controller_takes_per_step_without_a_rebuild():
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(
        boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.0)), horizon=6, dt=0.1, terminal="cost"
    )
    controller = uo.NMPC(problem, "ipopt")
    x0 = np.r_[0.0, 0.0, 0.8, 0.0, 0.0, 0.0, np.zeros(6)]  # 20 cm high: the vertical thrusters push
    backend = controller.backend
    healthy = controller.step(x0, 0.0)
    dead = np.ones(8)
    dead[[4, 7]] = 0.0
    controller.reset()
    faulty = controller.step(x0, 0.0, parameters={"health": dead})
    assert controller.backend is backend and problem.spec().global_dim == 16
    assert not healthy.fallback and not faulty.fallback
    assert np.max(np.abs(healthy.control[[4, 7]])) > 1.0  # used when healthy ...
    np.testing.assert_allclose(faulty.control[[4, 7]], 0.0, atol=1e-6)  # ... left at u_prev = 0 when dead


def test_model_parameter_values_are_checked_by_name():
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.0)), horizon=3, dt=0.1)
    x0 = problem.initial_state()
    with pytest.raises(ValueError, match=r"unknown names \['helth'\].*\['health', 'thrust_offset'\]"):
        problem.parameters(x0, model={"helth": np.ones(8)})
    with pytest.raises(ValueError, match=r"parameters\['health'\] must be 8 finite numbers"):
        problem.parameters(x0, model={"health": np.ones(7)})
    with pytest.raises(ValueError, match=r"parameters\['health'\]\[2\] must lie in \[0, 1\], got 1.5"):
        problem.parameters(x0, model={"health": [1, 1, 1.5, 1, 1, 1, 1, 1]})
    with pytest.raises(ValueError, match=r"parameters\['thrust_offset'\]\[0\] must lie in \[-40, 40\] N"):
        problem.parameters(x0, model={"thrust_offset": [50.0] + [0.0] * 7})
    forces = uo.TrackingProblem(
        Vehicle6DOF.bluerov2_heavy(), uo.Reference.hold((0, 0, 1, 0)), horizon=3, dt=0.1
    )
    assert forces.spec().global_dim == 0  # a vehicle that declares none: no parameter block
    with pytest.raises(ValueError, match="parameters= is for an Ocp or a vehicle with model parameters"):
        uo.solve(forces, "ipopt", x0=forces.initial_state(), parameters={"health": np.ones(8)})
