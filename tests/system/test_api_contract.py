"""DESIGN §3: the public API as documented, run at small sizes."""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.helpers_fossen import formulation_cost, formulation_violation, rk4_rollout, s2_reference


def independent_score(vehicle, controls, x0, t0, weights, u_prev=(0.0, 0.0, 0.0), horizon=10, dt=0.1):
    """Cost and violation of docs/formulation.md in numpy (the sine path is s2)."""
    states = rk4_rollout(vehicle, x0, controls, dt)
    max_thrust = np.asarray(vehicle.max_thrust)
    reference = s2_reference(t0 + dt * np.arange(horizon + 1))
    scaled, scaled_prev = np.asarray(controls) / max_thrust, np.asarray(u_prev) / max_thrust
    cost = formulation_cost(weights, states, scaled, scaled_prev, reference)
    rate_bound = np.asarray(vehicle.max_thrust_rate) * dt / max_thrust
    return cost, formulation_violation(states, scaled, scaled_prev, reference[-1], rate_bound)


def test_design_section_3_snippet(tmp_path):
    vehicle = uo.Vehicle.rexrov()
    vehicle = uo.Vehicle(
        mass=1862.9,
        inertia=691.2,
        added_mass=(779.8, 1222.0, 224.3),
        linear_damping=(74.8, 69.5, 105.0),
        quadratic_damping=(748.2, 992.5, 523.3),
        max_thrust=(2000.0, 2000.0, 1400.0),
        max_thrust_rate=(4000.0, 4000.0, 2800.0),
    )
    ref = uo.Reference.paper("s2")
    ref = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 2 * ca.sin(0.5 * t), name="sine")
    problem = uo.TrackingProblem(vehicle, ref, horizon=10, dt=0.1, terminal="equality")
    x0 = ref.initial_state(t0=0.0)
    assert x0.shape == (6,)
    at_rest_on_the_path = np.concatenate([s2_reference([0.0])[0, :3], np.zeros(3)])  # pose of Eq. (9)
    np.testing.assert_allclose(x0, at_rest_on_the_path, rtol=0, atol=1e-12)

    res = uo.solve(problem, "ipopt", x0=x0, t0=0.0)
    assert res.controls.shape == (10, 3) and res.states.shape == (11, 6)
    # values recomputed independently: numpy RK4 rollout, the formulation's cost in numpy
    cost, violation = independent_score(vehicle, res.controls, x0, 0.0, problem.weights)
    assert res.cost == pytest.approx(cost, rel=1e-9)
    # from rest x_N = x_R,N is unreachable: the soft fallback's terminal residual is reported
    assert res.terminal_relaxed and res.max_violation == pytest.approx(violation, rel=1e-9)
    # the judge on an infeasible plan (over the thrust box, rate-violating): same numbers
    rng = np.random.default_rng(5)
    rough = res.controls + rng.normal(scale=800.0, size=res.controls.shape)
    judged = uo.score(problem, rough, x0=x0, t0=0.0)
    expected = independent_score(vehicle, rough, x0, 0.0, problem.weights)
    assert expected[1] > 0.1  # the plan really is infeasible
    assert judged == pytest.approx(expected, rel=1e-9)
    # a plan within the rate bound that leaves the box: surge ramps 2000 -> 6000 N (excess 2)
    u_prev = np.array([2000.0, 0.0, 0.0])
    ramp = np.zeros((10, 3))
    ramp[:, 0] = 2000.0 + 400.0 * np.arange(1, 11)
    judged = uo.score(problem, ramp, x0=x0, t0=0.0, u_prev=u_prev)
    expected = independent_score(vehicle, ramp, x0, 0.0, problem.weights, u_prev=u_prev)
    assert judged == pytest.approx(expected, rel=1e-9) and expected[1] == pytest.approx(2.0)
    for attribute in ("success", "status", "solve_time", "iterations", "evaluations", "solver"):
        assert hasattr(res, attribute)
    assert {"fatrop", "gwo", "igwo", "igwo+ipopt", "ipopt", "pso", "sqp", "sqp-rti", "ssa"} <= set(
        uo.available_solvers()
    )

    best = uo.minimize(
        lambda X: np.sum(X**2, axis=1),
        -np.ones(4),
        np.ones(4),
        method="igwo",
        population=20,
        iterations=30,
        seed=1,
    )
    assert best.x.shape == (4,) and best.history.size == 31 and best.evaluations == 620
    assert best.fun == pytest.approx(float(np.sum(best.x**2)), rel=1e-12, abs=1e-300)  # f(x) itself
    assert best.history[-1] == best.fun and np.all(np.diff(best.history) <= 0)
    # the known optimum 0 at the origin; the random initial population is far from it
    assert best.history[0] > 1e-2 and best.fun <= 1e-12

    mpc = uo.NMPC(problem, solver="igwo", seed=1, options={"population": 8, "iterations": 4})
    run = uo.simulate(mpc, x0=x0, duration=0.5, current=uo.Current(speed=0.3, direction=0.5), seed=1)
    for attribute in ("t", "states", "controls", "reference", "solve_times", "failures"):
        assert hasattr(run, attribute)
    np.testing.assert_allclose(run.reference, s2_reference(run.t), rtol=0, atol=1e-9)
    assert run.metrics()["max_abs_ex"] == pytest.approx(np.max(np.abs(run.states[:, 0] - 0.5 * run.t)))

    generated = uo.generate_c(problem, tmp_path / "cost")
    assert generated.library.exists()
    table = uo.compare(problem, ["ipopt", "sqp", "igwo"], x0=x0, seed=1)
    assert [row.solver for row in table] == ["ipopt", "sqp", "igwo"]
    ipopt, sqp, igwo = table
    assert ipopt.cost == pytest.approx(res.cost, rel=1e-8)  # same instance, same optimum
    assert sqp.cost == pytest.approx(ipopt.cost, rel=1e-6)  # another algorithm agrees
    assert igwo.cost > ipopt.cost and igwo.ratio == pytest.approx(igwo.cost / ipopt.cost)
