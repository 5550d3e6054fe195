"""Vehicle model: the paper's equations, the current model, validation."""

import dataclasses

import numpy as np
import pytest

import uuv_ocp as uo


def paper_rhs(vehicle, state, control):
    """Eqs. (2)-(7) of the paper, written out by hand in numpy."""
    _, _, psi, u, v, r = state
    m_x = vehicle.mass + vehicle.added_mass[0]
    m_y = vehicle.mass + vehicle.added_mass[1]
    m_psi = vehicle.inertia + vehicle.added_mass[2]
    x_u, y_v, n_r = vehicle.linear_damping
    d_u, d_v, d_r = vehicle.quadratic_damping
    return np.array(
        [
            u * np.cos(psi) - v * np.sin(psi),
            u * np.sin(psi) + v * np.cos(psi),
            r,
            (m_y * v * r - x_u * u - d_u * u * abs(u) + control[0]) / m_x,
            (-m_x * u * r - y_v * v - d_v * v * abs(v) + control[1]) / m_y,
            ((m_x - m_y) * u * v - n_r * r - d_r * r * abs(r) + control[2]) / m_psi,
        ]
    )


def test_dynamics_equal_the_paper_equations():
    vehicle = uo.Vehicle.rexrov()
    f = vehicle.dynamics_function()
    rng = np.random.default_rng(0)
    for _ in range(20):
        state = rng.normal(size=6)
        control = rng.uniform(-2000, 2000, size=3)
        np.testing.assert_allclose(
            np.array(f(state, control, [0, 0])).ravel(),
            paper_rhs(vehicle, state, control),
            rtol=1e-13,
        )


def test_vehicle_drifting_with_the_current_feels_no_force():
    vehicle = uo.Vehicle.rexrov()
    f = vehicle.dynamics_function()
    current = np.array([0.4, -0.3])
    psi = 0.7
    body_current = np.array(
        [
            np.cos(psi) * current[0] + np.sin(psi) * current[1],
            -np.sin(psi) * current[0] + np.cos(psi) * current[1],
        ]
    )
    state = np.array([1.0, 2.0, psi, *body_current, 0.0])
    rate = np.array(f(state, [0, 0, 0], current)).ravel()
    np.testing.assert_allclose(rate[:2], current, atol=1e-15)  # moves with the water
    np.testing.assert_allclose(rate[3:], 0.0, atol=1e-15)  # no hydrodynamic force


def test_max_speed_balances_damping_and_thrust():
    vehicle = uo.Vehicle.rexrov()
    speed = vehicle.max_speed()
    damping = np.asarray(vehicle.linear_damping) * speed + np.asarray(vehicle.quadratic_damping) * speed**2
    np.testing.assert_allclose(damping, vehicle.max_thrust, rtol=1e-12)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("mass", 0.0),
        ("mass", -1.0),
        ("inertia", float("nan")),
        ("linear_damping", (1.0, -1.0, 1.0)),
        ("quadratic_damping", (1.0, 1.0)),
        ("max_thrust", (0.0, 1.0, 1.0)),
        ("max_thrust_rate", (1.0, float("inf"), 1.0)),
        ("added_mass", (1.0, float("nan"), 1.0)),
    ],
)
def test_bad_parameters_raise_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(uo.Vehicle.rexrov(), **{field: value})


def test_presets_differ_only_in_hydrodynamics():
    exact, rounded = uo.Vehicle.rexrov(), uo.Vehicle.rexrov_controller_model()
    assert exact.mass == rounded.mass and exact.max_thrust == rounded.max_thrust
    assert rounded.added_mass == (700.0, 1200.0, 200.0)
