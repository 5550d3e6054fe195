"""RK4 against scipy's adaptive integrator, and its order of convergence."""

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
