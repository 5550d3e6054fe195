"""RK4 against scipy's adaptive integrator, and its order of convergence."""

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import uuv_ocp as uo
from uuv_ocp.integrators import rk4_path

STATE = np.array([0.3, -0.2, 0.5, 0.8, 0.2, 0.15])
CONTROL = np.array([1500.0, -600.0, 300.0])
CURRENT = np.array([0.2, 0.1])


def exact_flow(duration):
    f = uo.Vehicle.rexrov().dynamics_function()
    solution = solve_ivp(
        lambda _t, x: np.array(f(x, CONTROL, CURRENT)).ravel(),
        (0.0, duration),
        STATE,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
    )
    return solution.y[:, -1]


def rk4_error(duration, steps):
    step = uo.rk4_step(uo.Vehicle.rexrov().dynamics_function(), duration / steps, 1)
    state = STATE
    for _ in range(steps):
        state = np.array(step(state, CONTROL, CURRENT)).ravel()
    return np.max(np.abs(state - exact_flow(duration)))


def test_rk4_step_agrees_with_solve_ivp():
    step = uo.rk4_step(uo.Vehicle.rexrov().dynamics_function(), 0.1, substeps=10)
    np.testing.assert_allclose(
        np.array(step(STATE, CONTROL, CURRENT)).ravel(), exact_flow(0.1), rtol=1e-10, atol=1e-12
    )


def test_rk4_is_fourth_order():
    coarse, fine = rk4_error(4.0, 20), rk4_error(4.0, 40)
    assert 12.0 < coarse / fine < 20.0  # ~16 for a fourth-order method


def test_substeps_equal_repeated_steps():
    f = uo.Vehicle.rexrov().dynamics_function()
    single = uo.rk4_step(f, 0.05, 1)
    double = uo.rk4_step(f, 0.1, 2)
    twice = single(single(STATE, CONTROL, CURRENT), CONTROL, CURRENT)
    np.testing.assert_allclose(np.array(double(STATE, CONTROL, CURRENT)), np.array(twice), rtol=1e-14)


def test_rk4_path_columns_are_the_states_after_each_substep():
    """Column j is the state after j + 1 sub-steps (repeated one-step maps); the last is rk4_step's."""
    f = uo.Vehicle.rexrov().dynamics_function()
    path = np.array(rk4_path(f, 0.1, 4)(STATE, CONTROL, CURRENT))
    assert path.shape == (6, 4)
    single = uo.rk4_step(f, 0.025, 1)
    state = STATE
    for column in range(4):
        state = np.array(single(state, CONTROL, CURRENT)).ravel()
        np.testing.assert_allclose(path[:, column], state, rtol=1e-13, atol=1e-15)
    # bit-identical to the step the controller's problems and the old plant used
    np.testing.assert_array_equal(
        path[:, -1], np.array(uo.rk4_step(f, 0.1, 4)(STATE, CONTROL, CURRENT)).ravel()
    )


@pytest.mark.parametrize(("dt", "substeps"), [(0.0, 1), (-0.1, 1), (0.1, 0), (0.1, 1.5)])
def test_bad_arguments_raise(dt, substeps):
    with pytest.raises(ValueError, match="dt|substeps"):
        uo.rk4_step(uo.Vehicle.rexrov().dynamics_function(), dt, substeps)


@pytest.mark.parametrize("vehicle", ["rexrov", "remus100"])
def test_rk4_sensitivity_is_the_jacobian_of_rk4_step(vehicle):
    """``rk4_sensitivity``: ``rk4_step``'s value bit for bit and its Jacobians in x and u.

    Reference: central differences of ``rk4_step`` itself (independent of any AD), at random
    states and commands; and CasADi's AD of the unrolled step to rounding.
    """
    from uuv_ocp.integrators import rk4_sensitivity

    if vehicle == "rexrov":
        f = uo.Vehicle.rexrov().dynamics_function()
        x, u, c = STATE, CONTROL, CURRENT
    else:
        f = uo.Remus100().dynamics
        rng = np.random.default_rng(28)
        x = np.r_[rng.normal(0, 1, 3), rng.uniform(-0.3, 0.3, 3), 1.5, rng.normal(0, 0.1, 5)]
        u, c = np.array([0.1, -0.05, 900.0]), np.array([0.2, -0.1, 0.0])
    step, sensitivity = uo.rk4_step(f, 0.5, 2), rk4_sensitivity(f, 0.5, 2)
    value, d_x, d_u = (np.array(a) for a in sensitivity(x, u, c))
    assert np.array_equal(value, np.array(step(x, u, c)))
    for base, derivative, other in ((x, d_x, u), (u, d_u, x)):
        for j in range(base.size):
            h = 1e-6 * max(1.0, abs(base[j]))
            plus, minus = base.copy(), base.copy()
            plus[j] += h
            minus[j] -= h
            args = ((plus, other), (minus, other)) if base is x else ((other, plus), (other, minus))
            central = (np.array(step(*args[0], c)) - np.array(step(*args[1], c))).ravel() / (2 * h)
            np.testing.assert_allclose(
                derivative[:, j], central, rtol=1e-6, atol=1e-6 * np.abs(central).max()
            )
    xs, us, cs = (ca.SX.sym(n, len(v)) for n, v in (("x", x), ("u", u), ("c", c)))
    unrolled = step(xs, us, cs)
    ad = ca.Function("ad", [xs, us, cs], [ca.jacobian(unrolled, xs), ca.jacobian(unrolled, us)])
    for mine, theirs in zip((d_x, d_u), ad(x, u, c), strict=True):
        np.testing.assert_allclose(mine, np.array(theirs), rtol=1e-12, atol=1e-12 * np.abs(mine).max())
