"""Vehicle model: Fossen's matrix form (independent numpy), energy, the current model, validation."""

import dataclasses

import numpy as np
import pytest

import uuv_ocp as uo
from tests.helpers_fossen import fossen_rhs, mass_matrix, rotation


def random_states(rng, count):
    """Seeded states with every velocity, the yaw rate included, clearly nonzero."""
    states = rng.uniform(-1.5, 1.5, size=(count, 6))
    states[:, 2] = rng.uniform(-np.pi, np.pi, count)
    states[:, 3:] += np.sign(states[:, 3:]) * 0.2  # |u|, |v|, |r| >= 0.2: Coriolis terms active
    return states


@pytest.mark.parametrize("with_current", [False, True])
def test_dynamics_equal_fossens_matrix_form(with_current):
    """Compare with an independent numpy Fossen model: M ν̇_r + C(ν_r)ν_r + D(ν_r)ν_r = τ, η̇ = R(ψ)ν."""
    vehicle = uo.Vehicle.rexrov()
    f = vehicle.dynamics_function()
    rng = np.random.default_rng(2024)
    for state in random_states(rng, 30):
        control = rng.uniform(-2000, 2000, size=3)
        current = rng.uniform(-0.8, 0.8, size=2) if with_current else np.zeros(2)
        expected = fossen_rhs(vehicle, state, control, current)
        actual = np.array(f(state, control, current)).ravel()
        np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12 * np.max(np.abs(expected)))


@pytest.mark.parametrize("with_current", [False, True])
def test_without_damping_the_kinetic_energy_changes_by_the_thrust_power(with_current):
    """C(ν) is skew-symmetric: with D = 0, d/dt ½ ν_rᵀ M ν_r = ν_rᵀ τ (ν_r = ν without current)."""
    vehicle = dataclasses.replace(
        uo.Vehicle.rexrov(), linear_damping=(0.0, 0.0, 0.0), quadratic_damping=(0.0, 0.0, 0.0)
    )
    mass = mass_matrix(vehicle)
    f = vehicle.dynamics_function()
    rng = np.random.default_rng(7)
    for state in random_states(rng, 30):
        control = rng.uniform(-2000, 2000, size=3)
        current = rng.uniform(-0.8, 0.8, size=2) if with_current else np.zeros(2)
        nu_c = rotation(state[2]).T @ np.array([*current, 0.0])
        nu_r = state[3:] - nu_c
        nu_dot = np.array(f(state, control, current)).ravel()[3:]
        nu_r_dot = nu_dot - state[5] * np.array([nu_c[1], -nu_c[0], 0.0])  # ν̇_c = r [v_c, −u_c, 0]
        power = nu_r @ mass @ nu_r_dot
        # scale of the individual terms, so the tolerance is relative to what could cancel
        scale = np.abs(nu_r) @ (np.abs(control) + np.abs(mass @ nu_r_dot))
        assert abs(power - nu_r @ control) <= 1e-12 * scale


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


@pytest.mark.parametrize("yaw_moment", [1400.0, 300.0])  # 300 N·m: the Munk moment binds
def test_top_horizontal_speed_is_the_largest_steady_crab_the_thrust_box_holds(yaw_moment):
    """Check the top crab speed independently of the code under test.

    Steady straight motion at (s, β) needs thrust inside the box, and 0.2 % more speed is
    impossible at every crab angle (forces recomputed here from the damping).
    """
    vehicle = dataclasses.replace(uo.Vehicle.rexrov(), max_thrust=(2000.0, 2000.0, yaw_moment))
    speed, crab = vehicle.max_horizontal_speed()
    m_x, m_y, _ = vehicle.inertia_diagonal
    d_lin, d_quad = np.asarray(vehicle.linear_damping), np.asarray(vehicle.quadratic_damping)

    def forces(s, beta):
        u, v = s * np.cos(beta), s * np.sin(beta)
        return np.array(
            [
                d_lin[0] * u + d_quad[0] * u * abs(u),
                d_lin[1] * v + d_quad[1] * v * abs(v),
                -(m_x - m_y) * u * v,
            ]
        )

    needed = forces(speed, crab)
    assert np.all(np.abs(needed) <= np.asarray(vehicle.max_thrust) * (1 + 1e-9))
    state = np.array([0.0, 0.0, 0.3, speed * np.cos(crab), speed * np.sin(crab), 0.0])
    xdot = np.array(vehicle.dynamics_function()(state, needed, np.zeros(2))).ravel()
    np.testing.assert_allclose(xdot[3:], 0.0, atol=1e-9)  # steady: no acceleration
    for beta in np.linspace(0.0, np.pi / 2, 2001):
        assert np.any(np.abs(forces(1.002 * speed, beta)) > np.asarray(vehicle.max_thrust))
    assert speed > vehicle.max_speed()[0]  # crabbing beats surge alone
