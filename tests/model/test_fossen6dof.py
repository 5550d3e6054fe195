"""6-DOF Fossen model: an independent numpy reference, physics, current, restoring, thrusters."""

import dataclasses
import pickle

import casadi as ca
import numpy as np
import pytest

from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.thrusters import ThrusterConfiguration


# ------------------------------------------------------------ numpy reference
def skew(a):
    """S(a) with S(a) b = a × b, written out."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def rotation(phi, theta, psi):
    """R = Rz(psi) Ry(theta) Rx(phi) from the three elementary rotations."""
    c, s = np.cos, np.sin
    rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    return rz @ ry @ rx


def euler_rate(phi, theta):
    """T(Θ) as the inverse of ω = e1 φ̇ + Rxᵀ e2 θ̇ + Rxᵀ Ryᵀ e3 ψ̇ (no closed form used)."""
    c, s = np.cos, np.sin
    rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    e1, e2, e3 = np.eye(3)
    rates_to_omega = np.column_stack([e1, rx.T @ e2, rx.T @ ry.T @ e3])
    return np.linalg.inv(rates_to_omega)


def reference_rhs(p, state, tau, current):
    """Fossen's equations of relative motion, built from the formulas in numpy."""
    phi, theta, psi = state[3:6]
    nu = state[6:12]
    m, inertia, added = p["mass"], np.asarray(p["inertia"]), np.asarray(p["added_mass"])
    r_g, r_b = np.asarray(p["centre_of_gravity"]), np.asarray(p["centre_of_buoyancy"])
    w, b = p["weight"], p["buoyancy"]
    rot = rotation(phi, theta, psi)

    m_rb = np.block([[m * np.eye(3), -m * skew(r_g)], [m * skew(r_g), inertia]])
    mass_matrix = m_rb + added

    nu_c = np.concatenate([rot.T @ np.asarray(current), np.zeros(3)])
    nu_r = nu - nu_c
    v1, v2 = nu_r[:3], nu_r[3:]
    c_rb = np.block(
        [[m * skew(v2), -m * skew(v2) @ skew(r_g)], [m * skew(r_g) @ skew(v2), -skew(inertia @ v2)]]
    )
    a11, a12, a21, a22 = added[:3, :3], added[:3, 3:], added[3:, :3], added[3:, 3:]
    s1 = skew(a11 @ v1 + a12 @ v2)
    s2 = skew(a21 @ v1 + a22 @ v2)
    c_a = np.block([[np.zeros((3, 3)), -s1], [-s1, -s2]])
    damping = np.diag(p["linear_damping"]) + np.diag(np.asarray(p["quadratic_damping"]) * np.abs(nu_r))

    f_g = rot.T @ np.array([0.0, 0.0, w])  # weight acts down (NED z)
    f_b = -rot.T @ np.array([0.0, 0.0, b])  # buoyancy acts up
    restoring = -np.concatenate([f_g + f_b, np.cross(r_g, f_g) + np.cross(r_b, f_b)])

    nu_r_dot = np.linalg.solve(mass_matrix, tau - (c_rb + c_a) @ nu_r - damping @ nu_r - restoring)
    omega = nu[3:]
    nu_dot = nu_r_dot + np.concatenate([-np.cross(omega, rot.T @ np.asarray(current)), np.zeros(3)])
    eta_dot = np.concatenate([rot @ nu[:3], euler_rate(phi, theta) @ omega])
    return np.concatenate([eta_dot, nu_dot])


def random_spd(rng, size, scale, floor):
    root = rng.normal(scale=scale, size=(size, size))
    return root @ root.T + floor * np.eye(size)


def general_parameters(seed=1):
    """Return a made-up vehicle exercising every term: offsets, full inertia, full added mass."""
    rng = np.random.default_rng(seed)
    return dict(
        mass=30.0,
        inertia=random_spd(rng, 3, 0.5, 2.0),
        added_mass=random_spd(rng, 6, 2.0, 1.0),
        linear_damping=rng.uniform(1.0, 20.0, size=6),
        quadratic_damping=rng.uniform(1.0, 50.0, size=6),
        weight=30.0 * 9.81,
        buoyancy=31.0 * 9.81,
        centre_of_gravity=(0.02, -0.01, 0.05),
        centre_of_buoyancy=(-0.01, 0.015, -0.04),
        max_thrust=(100.0, 100.0, 100.0, 20.0, 20.0, 20.0),
    )


def call(function, *args):
    return np.array(function(*args)).ravel()


def random_state(rng):
    return np.concatenate(
        [
            rng.normal(scale=5.0, size=3),
            rng.uniform(-1.2, 1.2, size=2),  # roll, pitch well inside (−90°, 90°)
            rng.uniform(-np.pi, np.pi, size=1),
            rng.normal(scale=1.0, size=3),
            rng.normal(scale=0.5, size=3),
        ]
    )


# ------------------------------------------------------------ 1. reference
def test_dynamics_equal_an_independent_numpy_implementation():
    params = general_parameters()
    vehicle = Vehicle6DOF(**params)
    assert np.max(np.abs(np.array(params["added_mass"]) - np.diag(np.diag(params["added_mass"])))) > 0.5
    rng = np.random.default_rng(2)
    for _ in range(20):
        state = random_state(rng)
        tau = rng.uniform(-100.0, 100.0, size=6)
        current = rng.normal(scale=0.5, size=3)
        expected = reference_rhs(params, state, tau, current)
        got = call(vehicle.dynamics, state, tau, current)
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10 * np.max(np.abs(expected)))


@pytest.mark.parametrize("preset", [Vehicle6DOF.rexrov2, Vehicle6DOF.bluerov2_heavy])
def test_presets_equal_the_numpy_implementation(preset):
    vehicle = preset()
    params = {
        field: getattr(vehicle, field)
        for field in (
            "mass",
            "inertia",
            "added_mass",
            "linear_damping",
            "quadratic_damping",
            "weight",
            "buoyancy",
            "centre_of_gravity",
            "centre_of_buoyancy",
        )
    }
    rng = np.random.default_rng(3)
    for _ in range(10):
        state = random_state(rng)
        tau = rng.uniform(-1.0, 1.0, size=6) * np.array(vehicle.max_thrust)
        current = rng.normal(scale=0.5, size=3)
        expected = reference_rhs(params, state, tau, current)
        got = call(vehicle.dynamics, state, tau, current)
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10 * np.max(np.abs(expected)))


def test_symbolic_entry_points_agree():
    vehicle = Vehicle6DOF(**general_parameters())
    rng = np.random.default_rng(4)
    state, tau, current = random_state(rng), rng.normal(size=6), rng.normal(size=3)
    x, u, c = ca.MX.sym("x", 12), ca.MX.sym("u", 6), ca.MX.sym("c", 3)
    via_mx = ca.Function("f", [x, u, c], [vehicle.dynamics_expression(x, u, c)])
    xs, us = ca.SX.sym("x", 12), ca.SX.sym("u", 6)
    still = ca.Function("g", [xs, us], [vehicle.rhs(xs, us)])
    expected = call(vehicle.dynamics, state, tau, current)
    np.testing.assert_allclose(call(via_mx, state, tau, current), expected, rtol=1e-12)
    np.testing.assert_allclose(call(still, state, tau), call(vehicle.dynamics, state, tau, np.zeros(3)))
    assert vehicle.dynamics_function() is vehicle.dynamics


# ------------------------------------------------------------ 2. physics
@pytest.mark.parametrize(
    "preset",
    [Vehicle6DOF.rexrov2, Vehicle6DOF.bluerov2_heavy, lambda: Vehicle6DOF.bluerov2_heavy(thrusters=True)],
)
def test_preset_mass_matrices_are_symmetric_positive_definite(preset):
    vehicle = preset()
    for matrix in (vehicle.mass_matrix, vehicle.rigid_body_mass_matrix):
        np.testing.assert_array_equal(matrix, matrix.T)
        assert np.linalg.eigvalsh(matrix)[0] > 0.0
    added = vehicle.added_mass_matrix
    np.testing.assert_array_equal(added, added.T)
    assert np.linalg.eigvalsh(added)[0] >= 0.0
    np.testing.assert_allclose(vehicle.mass_matrix, vehicle.rigid_body_mass_matrix + added)


def conservative(params):
    """No damping, no restoring (W = B, r_b = r_g): only inertia and Coriolis remain."""
    return dict(
        params,
        linear_damping=np.zeros(6),
        quadratic_damping=np.zeros(6),
        buoyancy=params["weight"],
        centre_of_buoyancy=params["centre_of_gravity"],
    )


def test_coriolis_does_no_work_kinetic_energy_rate_is_zero():
    vehicle = Vehicle6DOF(**conservative(general_parameters()))
    mass_matrix = vehicle.mass_matrix
    rng = np.random.default_rng(5)
    for _ in range(20):
        state = random_state(rng)
        nu = state[6:]
        nu_dot = call(vehicle.dynamics, state, np.zeros(6), np.zeros(3))[6:]
        terms = nu * (mass_matrix @ nu_dot)  # d/dt ½ νᵀMν = νᵀ M ν̇
        assert abs(terms.sum()) <= 1e-9 * np.abs(terms).sum()
        coriolis = np.array(vehicle.coriolis_matrix(nu))
        np.testing.assert_allclose(coriolis, -coriolis.T, atol=1e-12 * np.abs(coriolis).max())


def test_kinetic_energy_is_conserved_along_an_rk4_trajectory():
    vehicle = Vehicle6DOF(**conservative(general_parameters()))
    f = vehicle.dynamics
    mass_matrix = vehicle.mass_matrix
    state = np.array([0.0, 0.0, 0.0, 0.1, -0.2, 0.3, 0.8, -0.4, 0.3, 0.4, -0.3, 0.5])
    zero_tau, zero_current = np.zeros(6), np.zeros(3)

    def energy(x):
        return 0.5 * x[6:] @ mass_matrix @ x[6:]

    def rhs(x):
        return call(f, x, zero_tau, zero_current)

    start = energy(state)
    dt = 2e-3
    for _ in range(250):
        k1 = rhs(state)
        k2 = rhs(state + 0.5 * dt * k1)
        k3 = rhs(state + 0.5 * dt * k2)
        k4 = rhs(state + dt * k3)
        state = state + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert abs(np.degrees(state[4])) < 80.0  # stayed away from the Euler singularity
    assert abs(energy(state) - start) <= 1e-9 * start


def test_rigid_body_coriolis_equals_newton_euler():
    params = general_parameters()
    vehicle = Vehicle6DOF(**params)
    m, r_g, inertia = params["mass"], np.array(params["centre_of_gravity"]), params["inertia"]
    rng = np.random.default_rng(6)
    for _ in range(5):
        nu = rng.normal(size=6)
        v, w = nu[:3], nu[3:]
        newton_euler = np.concatenate(
            [
                m * (np.cross(w, v) + np.cross(w, np.cross(w, r_g))),
                m * np.cross(r_g, np.cross(w, v)) + np.cross(w, inertia @ w),
            ]
        )
        np.testing.assert_allclose(
            np.array(vehicle.rigid_body_coriolis_matrix(nu)) @ nu, newton_euler, rtol=1e-12, atol=1e-12
        )


# ------------------------------------------------------------ 3. current
def test_vehicle_drifting_with_the_current_feels_no_force():
    vehicle = Vehicle6DOF(**conservative(general_parameters()) | {"linear_damping": np.full(6, 10.0)})
    current = np.array([0.4, -0.3, 0.1])
    angles = np.array([0.2, -0.3, 0.7])
    body_current = rotation(*angles).T @ current
    state = np.concatenate([[1.0, 2.0, 3.0], angles, body_current, np.zeros(3)])
    rate = call(vehicle.dynamics, state, np.zeros(6), current)
    np.testing.assert_allclose(rate[:3], current, atol=1e-14)  # moves with the water
    np.testing.assert_allclose(rate[3:], 0.0, atol=1e-14)  # no rotation, no acceleration


def test_current_enters_through_the_relative_velocity():
    vehicle = Vehicle6DOF(**general_parameters())
    rng = np.random.default_rng(7)
    for _ in range(5):
        state = random_state(rng)
        tau, current = rng.normal(size=6), rng.normal(scale=0.5, size=3)
        rot = rotation(*state[3:6])
        omega = state[9:]
        relative = state.copy()
        relative[6:9] -= rot.T @ current
        with_current = call(vehicle.dynamics, state, tau, current)
        still_water = call(vehicle.dynamics, relative, tau, np.zeros(3))
        np.testing.assert_allclose(
            with_current[6:9], still_water[6:9] - np.cross(omega, rot.T @ current), rtol=1e-10, atol=1e-12
        )
        np.testing.assert_allclose(with_current[9:], still_water[9:], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(with_current[:3], rot @ state[6:9], rtol=1e-12)  # absolute velocity


def test_current_pushes_a_vehicle_at_rest_downstream():
    vehicle = Vehicle6DOF.bluerov2_heavy()
    state = np.zeros(12)
    state[:3] = [0.0, 0.0, 5.0]
    rate_still = call(vehicle.dynamics, state, np.zeros(6), np.zeros(3))
    rate_current = call(vehicle.dynamics, state, np.zeros(6), [0.5, 0.0, 0.0])
    assert rate_current[6] > 0.0 and rate_still[6] == 0.0


# ------------------------------------------------------------ 4. restoring
def restoring_parameters():
    params = general_parameters()
    return dict(
        params,
        added_mass=np.diag(np.diag(params["added_mass"])),
        inertia=np.diag(np.diag(params["inertia"])),
        buoyancy=params["weight"],
        centre_of_gravity=(0.0, 0.0, 0.0),
        centre_of_buoyancy=(0.0, 0.0, -0.05),  # 5 cm above the centre of gravity
    )


def test_neutral_vehicle_at_rest_and_level_stays_at_rest():
    params = dict(restoring_parameters(), centre_of_gravity=(0.03, -0.02, 0.04))
    params["centre_of_buoyancy"] = (0.03, -0.02, -0.06)  # directly above r_g
    vehicle = Vehicle6DOF(**params)
    state = np.zeros(12)
    state[5] = 1.1  # any heading
    np.testing.assert_allclose(call(vehicle.dynamics, state, np.zeros(6), np.zeros(3)), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.array(vehicle.restoring_force(0.0, 0.0)).ravel(), 0.0, atol=1e-15)


@pytest.mark.parametrize("axis, angle", [(4, 0.2), (4, -0.3), (3, 0.25), (3, -0.1)])
def test_tilted_vehicle_is_pushed_back_to_level(axis, angle):
    params = restoring_parameters()
    vehicle = Vehicle6DOF(**params)
    state = np.zeros(12)
    state[axis] = angle
    rate = call(vehicle.dynamics, state, np.zeros(6), np.zeros(3))
    angular_acceleration = rate[6 + axis]  # ṗ for roll (axis 3), q̇ for pitch (axis 4)
    assert np.sign(angular_acceleration) == -np.sign(angle)
    # metacentric moment −W·BG·sin(angle) with BG = z_g − z_b = 0.05 m
    moment = -np.array(vehicle.restoring_force(state[3], state[4])).ravel()[axis]
    np.testing.assert_allclose(moment, -params["weight"] * 0.05 * np.sin(angle), rtol=1e-12)
    np.testing.assert_allclose(rate[6:9], 0.0, atol=1e-12)  # W = B: no net force


def test_heavy_vehicle_sinks_and_light_one_rises():
    params = restoring_parameters()
    heavy = Vehicle6DOF(**dict(params, buoyancy=0.9 * params["weight"]))
    light = Vehicle6DOF(**dict(params, buoyancy=1.1 * params["weight"]))
    rest = np.zeros(12)
    assert call(heavy.dynamics, rest, np.zeros(6), np.zeros(3))[8] > 0.0  # ẇ > 0: down in NED
    assert call(light.dynamics, rest, np.zeros(6), np.zeros(3))[8] < 0.0


# ------------------------------------------------------------ 5. thrusters
def test_thruster_dynamics_apply_the_allocation():
    vehicle = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    rng = np.random.default_rng(9)
    allocation = vehicle.allocation
    assert allocation.shape == (6, 8)
    for _ in range(5):
        state, current = random_state(rng), rng.normal(scale=0.3, size=3)
        forces = rng.uniform(-40.0, 40.0, size=8)
        np.testing.assert_allclose(
            call(vehicle.thruster_dynamics, state, forces, current),
            call(vehicle.dynamics, state, allocation @ forces, current),
            rtol=1e-12,
            atol=1e-12,
        )


def _responding(constant):
    """Return the BlueROV2 Heavy with thrusters of first-order time constant(s) ``constant`` (s)."""
    vehicle = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    return dataclasses.replace(
        vehicle, thrusters=dataclasses.replace(vehicle.thrusters, time_constant=constant)
    )


def test_a_zero_thruster_time_constant_is_the_vehicle_without_response():
    """τ = 0 (explicit) is the default vehicle: equal, 12 states, the same numbers bit for bit."""
    default, explicit = Vehicle6DOF.bluerov2_heavy(thrusters=True), _responding(0.0)
    assert explicit == default and explicit.state_dim == 12 and explicit.layout == default.layout
    rng = np.random.default_rng(4)
    state, forces, current = random_state(rng), rng.uniform(-40.0, 40.0, 8), rng.normal(scale=0.3, size=3)
    health, offset = rng.uniform(0.0, 1.0, 8), rng.uniform(-5.0, 5.0, 8)
    np.testing.assert_array_equal(
        call(explicit.thruster_dynamics, state, forces, current),
        call(default.dynamics, state, default.allocation @ forces, current),
    )
    np.testing.assert_allclose(  # numpy's and CasADi's T (h ∘ f + s) round differently
        call(explicit.faulty_thruster_dynamics, state, forces, current, health, offset),
        call(default.dynamics, state, default.allocation @ (health * forces + offset), current),
        rtol=1e-14,
        atol=1e-13,
    )


def test_the_thruster_response_is_the_analytic_first_order_step_through_rk4():
    """A step command from rest: ``f_a(t) = f (1 − exp(−t/τ))`` per thruster, through ``rk4_step``.

    The rigid body sees the delivered force: its derivative is :attr:`dynamics` at ``T f_a``.
    """
    from uuv_ocp.integrators import rk4_step

    constants = np.array([0.05, 0.1, 0.2, 0.4, 0.1, 0.1, 0.3, 0.15])
    vehicle = _responding(tuple(constants))
    assert vehicle.state_dim == 20 and vehicle.layout.velocities == tuple(range(14, 20))
    assert vehicle.state_names[6:14] == tuple(f"f_a{i}" for i in range(1, 9))
    rng = np.random.default_rng(6)
    command = rng.uniform(-30.0, 30.0, 8)
    dt, steps = 0.005, 200
    step = rk4_step(vehicle.thruster_dynamics, dt)
    x = np.zeros(20)
    x[2] = 2.0
    for k in range(1, steps + 1):
        x = np.array(step(x, command, np.zeros(3))).ravel()
        expected = command * (1.0 - np.exp(-k * dt / constants))
        np.testing.assert_allclose(x[6:14], expected, rtol=0.0, atol=1e-6 * np.abs(command).max())
    state, delivered, current = random_state(rng), rng.uniform(-40.0, 40.0, 8), rng.normal(scale=0.3, size=3)
    full = np.concatenate([state[:6], delivered, state[6:]])
    derivative = call(vehicle.thruster_dynamics, full, command, current)
    body = call(vehicle.dynamics, state, vehicle.allocation @ delivered, current)
    np.testing.assert_allclose(np.r_[derivative[:6], derivative[14:]], body, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(derivative[6:14], (command - delivered) / constants, rtol=1e-12)
    health = np.full(8, 0.5)  # a fault acts on what the thruster delivers
    faulty = call(vehicle.faulty_thruster_dynamics, full, command, current, health, np.zeros(8))
    np.testing.assert_allclose(
        faulty[14:],
        call(vehicle.dynamics, state, vehicle.allocation @ (0.5 * delivered), current)[6:],
        rtol=1e-12,
        atol=1e-12,
    )


@pytest.mark.parametrize("constant", [-0.1, (0.1, 0.0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1)])
def test_bad_thruster_time_constants_are_refused_by_name(constant):
    with pytest.raises(ValueError, match="time_constant"):
        _responding(constant)


def test_derived_max_thrust_and_rates():
    params = dict(general_parameters(), max_thrust=None, thrusters=ThrusterConfiguration.bluerov2_heavy())
    vehicle = Vehicle6DOF(**params)
    limits = ThrusterConfiguration.bluerov2_heavy().generalised_force_limits()
    assert vehicle.max_thrust == pytest.approx(limits)
    assert vehicle.max_thrust_rate == pytest.approx(tuple(2 * v for v in limits))
    assert vehicle.control_bound == (40.0,) * 8
    assert vehicle.control_rate_bound == (80.0,) * 8
    planar_only = ThrusterConfiguration(
        [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], max_thrust=5.0
    )
    with pytest.raises(ValueError, match="max_thrust cannot be derived"):
        Vehicle6DOF(**dict(params, thrusters=planar_only))


# ------------------------------------------------------------ 6. bad input
def replaced(**changes):
    return dict(general_parameters(), **changes)


@pytest.mark.parametrize(
    "changes, pattern",
    [
        ({"mass": -1.0}, "^mass must"),
        ({"mass": float("nan")}, "^mass must"),
        ({"inertia": np.ones((2, 2))}, "^inertia must have shape"),
        ({"inertia": [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "^inertia must be symmetric"),
        ({"inertia": (1.0, -1.0, 1.0)}, "^inertia must be positive definite"),
        ({"inertia": (1.0, np.inf, 1.0)}, "^inertia must be finite"),
        ({"added_mass": np.ones(5)}, "^added_mass must have shape"),
        ({"added_mass": -np.ones(6)}, "^added_mass must be positive semidefinite"),
        ({"added_mass": np.triu(np.ones((6, 6)))}, "^added_mass must be symmetric"),
        ({"added_mass": "heavy"}, "^added_mass must be"),
        ({"linear_damping": np.ones(5)}, "^linear_damping must have shape"),
        ({"quadratic_damping": -np.ones(6)}, "^quadratic_damping must be >= 0"),
        ({"weight": float("inf")}, "^weight must be finite"),
        ({"weight": 0.0}, "^weight must be"),
        ({"buoyancy": -5.0}, "^buoyancy must be"),
        ({"centre_of_gravity": (0.0, 0.0)}, "^centre_of_gravity must have shape"),
        ({"centre_of_buoyancy": (0.0, np.nan, 0.0)}, "^centre_of_buoyancy must be finite"),
        ({"max_thrust": None}, "^max_thrust must be 6 numbers"),
        ({"max_thrust": (1.0,) * 5}, "^max_thrust must have shape"),
        ({"max_thrust_rate": (-1.0,) * 6}, "^max_thrust_rate must be > 0"),
        ({"thrusters": "eight"}, "^thrusters must be a ThrusterConfiguration"),
        ({"name": 3}, "^name must be a string"),
        # inertia about the origin is positive definite but the centre of gravity is so far off
        # that the inertia about it, I_o + m S(r_g)², is not: M_RB (and M) is indefinite
        (
            {"inertia": (0.1, 0.1, 0.1), "added_mass": np.zeros(6), "centre_of_gravity": (0.0, 0.0, 1.0)},
            "^mass matrix M = M_RB \\+ M_A",
        ),
    ],
)
def test_bad_vehicle_input_raises_naming_the_parameter(changes, pattern):
    with pytest.raises(ValueError, match=pattern):
        Vehicle6DOF(**replaced(**changes))


@pytest.mark.parametrize(
    "changes, pattern",
    [
        ({"positions": np.zeros((2, 2))}, "^positions must have shape \\(n, 3\\)"),
        ({"positions": [[0.0, 0.0, np.inf], [0.0, 0.0, 0.0]]}, "^positions must be finite"),
        ({"directions": [[1.0, 0.0, 0.0]]}, "^directions must have shape \\(2, 3\\)"),
        ({"directions": [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]}, "^directions must be unit vectors"),
        ({"directions": [[1.0, 0.0, 0.0], [0.0, np.nan, 0.0]]}, "^directions must be finite"),
        ({"max_thrust": (1.0, 0.0)}, "^max_thrust must be > 0"),
        ({"max_thrust": (1.0, 2.0, 3.0)}, "^max_thrust must have shape"),
        ({"name": None}, "^name must be a string"),
    ],
)
def test_bad_thruster_input_raises_naming_the_parameter(changes, pattern):
    good = dict(
        positions=[[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]], directions=[[1.0, 0.0, 0.0]] * 2, max_thrust=5.0
    )
    with pytest.raises(ValueError, match=pattern):
        ThrusterConfiguration(**dict(good, **changes))


def test_preset_keywords_are_checked():
    with pytest.raises(ValueError, match="^thrusters must be True or False"):
        Vehicle6DOF.bluerov2_heavy(thrusters="yes")
    with pytest.raises(ValueError, match="^water_density must be"):
        Vehicle6DOF.bluerov2_heavy(water_density=-1.0)


# ------------------------------------------------------------ 7. presets and API
@pytest.mark.parametrize("preset", [Vehicle6DOF.rexrov2, Vehicle6DOF.bluerov2_heavy])
def test_presets_build_and_dynamics_have_the_documented_signature(preset):
    vehicle = preset()
    f = vehicle.dynamics
    assert isinstance(f, ca.Function) and f.name() == "dynamics"
    assert f.name_in() == ["x", "tau", "current"] and f.name_out() == ["xdot"]
    assert [f.size_in(i) for i in range(3)] == [(12, 1), (6, 1), (3, 1)]
    assert f.size_out(0) == (12, 1)
    assert vehicle.dynamics is f  # cached
    assert (vehicle.state_dim, vehicle.control_dim, vehicle.current_dim) == (12, 6, 3)
    assert len(vehicle.state_names) == len(vehicle.state_units) == 12
    assert vehicle.control_names == ("X", "Y", "Z", "K", "M", "N")
    assert vehicle.control_units == ("N", "N", "N", "N·m", "N·m", "N·m")
    assert vehicle.control_bound == vehicle.max_thrust
    assert vehicle.max_thrust_rate == pytest.approx(tuple(2 * v for v in vehicle.max_thrust))
    assert all(np.isfinite(call(f, np.zeros(12), np.zeros(6), np.zeros(3))))
    with pytest.raises(AttributeError):
        vehicle.allocation  # noqa: B018


@pytest.mark.parametrize("preset", [Vehicle6DOF.rexrov2, Vehicle6DOF.bluerov2_heavy])
def test_thruster_presets_have_the_documented_signature(preset):
    vehicle = preset(thrusters=True)
    count = vehicle.thrusters.count
    f = vehicle.thruster_dynamics
    assert f.name() == "thruster_dynamics"
    assert f.name_in() == ["x", "f", "current"] and f.name_out() == ["xdot"]
    assert [f.size_in(i) for i in range(3)] == [(12, 1), (count, 1), (3, 1)]
    assert vehicle.control_dim == count
    assert vehicle.control_names == tuple(f"f_{i}" for i in range(1, count + 1))
    assert vehicle.dynamics.size_in(1) == (6, 1)  # still the generalised force


def test_vehicles_are_hashable_values_and_pickle_without_the_cache():
    first, second = Vehicle6DOF.rexrov2(), Vehicle6DOF.rexrov2()
    first.dynamics  # noqa: B018 - fill the cache on one of them only
    assert first == second and hash(first) == hash(second)
    assert first != Vehicle6DOF.rexrov2(thrusters=True)
    assert first != dataclasses.replace(first, buoyancy=first.weight)
    assert len({first, second, Vehicle6DOF.bluerov2_heavy()}) == 2
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.mass = 1.0
    copy = pickle.loads(pickle.dumps(first))
    assert copy == first and "dynamics" not in copy.__dict__
    state = np.linspace(-0.5, 0.5, 12)
    np.testing.assert_array_equal(
        call(copy.dynamics, state, np.ones(6), np.ones(3)),
        call(first.dynamics, state, np.ones(6), np.ones(3)),
    )


def test_rexrov2_parameters_are_the_simulator_values_in_fossen_axes():
    vehicle = Vehicle6DOF.rexrov2()
    flip3 = np.diag([1.0, -1.0, -1.0])
    flip6 = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])
    ros_inertia = flip3 @ vehicle.inertia_matrix @ flip3
    np.testing.assert_allclose(ros_inertia, [[525.39, 1.44, 33.41], [1.44, 794.2, 2.6], [33.41, 2.6, 691.23]])
    ros_added = flip6 @ vehicle.added_mass_matrix @ flip6
    assert ros_added[0, 0] == 779.79 and ros_added[1, 5] == 62.726 and ros_added[0, 4] == -165.54
    assert ros_added[2, 5] == pytest.approx(10.7745)
    assert vehicle.centre_of_buoyancy == (0.0, 0.0, -0.3)  # 0.3 m above the origin
    assert vehicle.buoyancy - vehicle.weight == pytest.approx((1028.0 * 1.83826 - 1862.87) * 9.81)


def test_bluerov2_parameters():
    vehicle = Vehicle6DOF.bluerov2_heavy()
    np.testing.assert_allclose(np.diag(vehicle.added_mass_matrix), [6.36, 7.12, 18.68, 0.189, 0.135, 0.222])
    np.testing.assert_allclose(vehicle.inertia_matrix, np.diag([0.26, 0.23, 0.37]))
    assert vehicle.buoyancy == pytest.approx(1026.0 * 9.81 * 0.0134)
    assert Vehicle6DOF.bluerov2_heavy(water_density=1000.0).buoyancy == pytest.approx(1000.0 * 9.81 * 0.0134)


def test_reading_dynamics_while_another_thread_builds_does_not_deadlock():
    """Two vehicles' dynamics read in two threads, one of them holding BUILD_LOCK (forced).

    It was cached_property + serialised: the reader held the class attribute's lock (Python
    3.11) and waited for BUILD_LOCK while the builder held BUILD_LOCK and waited for that lock.
    """
    from tests.helpers_threads import read_while_building

    first, second = Vehicle6DOF.bluerov2_heavy(), Vehicle6DOF.rexrov2()
    assert "dynamics" not in first.__dict__ and "dynamics" not in second.__dict__  # not built yet
    read_while_building(lambda: first.dynamics, lambda: second.dynamics, timeout=20.0)
    x, tau, current = np.linspace(-0.5, 0.5, 12), np.linspace(-50.0, 50.0, 6), np.array([0.1, -0.1, 0.0])
    for vehicle, fresh in ((first, Vehicle6DOF.bluerov2_heavy()), (second, Vehicle6DOF.rexrov2())):
        expected = fresh.dynamics(x, tau, current)  # built in this thread alone
        np.testing.assert_array_equal(vehicle.dynamics(x, tau, current), expected)
