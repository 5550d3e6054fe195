"""The vehicle protocol (``uuv_ocp.model.base``) and a user's own vehicle from its own file.

Built-ins conform, layouts agree with the dynamics, and the user's vehicle is tracked,
simulated and plotted.

The user's vehicle (``examples/vehicles/vessel4dof.py``) is a small 4-DOF surface vessel (surge,
sway, roll, yaw) after the structure of Fossen's 4-DOF manoeuvring model (Fossen 2011, §7.3):
diagonal mass with added mass, linear damping, a roll restoring moment ``W GM_T sin φ cos φ``
and the sway force acting ``z_t`` below the centre of gravity (so steering heels the vessel).
Its state is ``[x, y, ψ, φ, u, v, r, p]`` (8 states) and its controls the generalised forces
``[X, Y, N]`` (roll is not actuated).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.model.base import REFERENCE_STATE_NAMES, check_vehicle, model_function
from uuv_ocp.specs import VEHICLE_PRESETS, vehicle_from_class

# ------------------------------------------------- a user's vehicle, in one file of examples/
# loaded from its file as the CLI loads it (--vehicle FILE.py:CLASS), not imported as a package
USER_VEHICLE_FILE = Path(__file__).resolve().parents[2] / "examples" / "vehicles" / "vessel4dof.py"
Vessel4DOF = type(vehicle_from_class(USER_VEHICLE_FILE, "Vessel4DOF"))
VESSEL_LAYOUT = Vessel4DOF().layout


# ------------------------------------- a vehicle whose controls are actuator commands, not forces
TORPEDO_LAYOUT = uo.VehicleLayout(
    state_names=("x", "y", "psi", "u", "v", "r"),
    state_units=("m", "m", "rad", "m/s", "m/s", "rad/s"),
    control_names=("n", "delta"),
    control_units=("rad/s", "rad"),
    positions=(0, 1),
    angles=(2,),
    heading=2,
    velocities=(3, 4, 5),
    current_dim=2,
    reference="planar",
)


@dataclass(frozen=True)
class Torpedo:
    """A small underactuated torpedo in the plane: propeller speed ``n`` and rudder angle ``δ``.

    Thrust ``k_t n|n|`` (a fixed-pitch propeller at low advance), rudder lift ``Y_δ u_r² δ``
    acting ``l`` behind the centre (so it yaws the hull), linear damping; no sway actuator.
    """

    mass: float = 30.0  # kg
    inertia: float = 3.0  # I_z, kg·m²
    added_mass: tuple[float, float, float] = (1.5, 30.0, 3.0)  # X_u̇, Y_v̇, N_ṙ
    damping: tuple[float, float, float] = (5.0, 60.0, 15.0)  # X_u, Y_v, N_r
    thrust_coefficient: float = 0.0167  # k_t, N/(rad/s)²
    rudder_lift: float = 40.0  # Y_δ, N/((m/s)²·rad)
    rudder_arm: float = 0.8  # l, m
    control_bound: tuple[float, ...] = (60.0, 0.4)  # rad/s, rad
    control_rate_bound: tuple[float, ...] = (100.0, 0.8)  # per second
    name: str = "torpedo"

    @property
    def layout(self) -> uo.VehicleLayout:
        return TORPEDO_LAYOUT

    def model_function(self) -> ca.Function:
        x, command, current = ca.SX.sym("x", 6), ca.SX.sym("command", 2), ca.SX.sym("current", 2)
        psi, u, v, r = x[2], x[3], x[4], x[5]
        propeller, rudder = command[0], command[1]
        u_r = u - (ca.cos(psi) * current[0] + ca.sin(psi) * current[1])
        v_r = v - (-ca.sin(psi) * current[0] + ca.cos(psi) * current[1])
        m_u, m_v = self.mass + self.added_mass[0], self.mass + self.added_mass[1]
        m_r = self.inertia + self.added_mass[2]
        d_u, d_v, d_r = self.damping
        lift = self.rudder_lift * u_r**2 * rudder
        xdot = ca.vertcat(
            u * ca.cos(psi) - v * ca.sin(psi),
            u * ca.sin(psi) + v * ca.cos(psi),
            r,
            (m_v * v * r - d_u * u_r + self.thrust_coefficient * propeller * ca.fabs(propeller)) / m_u,
            (-m_u * u * r - d_v * v_r + lift) / m_v,
            (-d_r * r - self.rudder_arm * lift) / m_r,
        )
        return ca.Function("torpedo", [x, command, current], [xdot], ["x", "command", "current"], ["xdot"])


def built_in_vehicles():
    """Every vehicle the package ships: the presets' registry, with and without thrusters."""
    vehicles = [make() for make in VEHICLE_PRESETS.values()]
    vehicles += [uo.Vehicle6DOF.bluerov2_heavy(thrusters=True), uo.Vehicle6DOF.rexrov2(thrusters=True)]
    return vehicles


ALL_VEHICLES = [*built_in_vehicles(), Vessel4DOF(), Torpedo()]
IDS = [f"{v.name}-{v.layout.control_dim}u" for v in ALL_VEHICLES]


# ------------------------------------------------------------------------------ conformance
@pytest.mark.parametrize("vehicle", ALL_VEHICLES, ids=IDS)
def test_vehicles_conform(vehicle):
    assert isinstance(vehicle, uo.VehicleModel)
    assert check_vehicle("vehicle", vehicle) is vehicle
    layout = vehicle.layout
    f = model_function("vehicle", vehicle)
    assert f.size_in(0) == (layout.state_dim, 1) and f.size_out(0) == (layout.state_dim, 1)
    assert f.size_in(1) == (layout.control_dim, 1) and f.size_in(2) == (layout.current_dim, 1)
    assert len(vehicle.control_bound) == len(vehicle.control_rate_bound) == layout.control_dim


def test_the_registry_covers_every_built_in_class():
    kinds = {type(vehicle) for vehicle in built_in_vehicles()}
    assert kinds == {uo.Vehicle, uo.Vehicle6DOF, uo.Remus100}


def _rhs(vehicle, x, u, current=None):
    layout = vehicle.layout
    current = np.zeros(layout.current_dim) if current is None else current
    return np.asarray(vehicle.model_function()(x, u, current)).ravel()


def _random_point(vehicle, rng):
    layout = vehicle.layout
    x = rng.normal(scale=0.3, size=layout.state_dim)
    u = rng.uniform(-0.5, 0.5, size=layout.control_dim) * np.asarray(vehicle.control_bound)
    return x, u


@pytest.mark.parametrize("vehicle", ALL_VEHICLES, ids=IDS)
def test_layout_agrees_with_the_dynamics(vehicle):
    """An independent reading of each layout from the dynamics, by finite differences."""
    layout = vehicle.layout
    rng = np.random.default_rng(7)
    x, u = _random_point(vehicle, rng)
    f0 = _rhs(vehicle, x, u)
    pose = list(range(layout.pose_dim))
    # positions: the dynamics do not depend on where the vehicle is (translation invariance)
    for i in layout.positions:
        moved = x.copy()
        moved[i] += 3.7
        np.testing.assert_allclose(_rhs(vehicle, moved, u), f0, rtol=1e-12, atol=1e-9)
    # angles: the dynamics are 2π-periodic in them (hence the wrapped errors)
    for i in layout.angles:
        turned = x.copy()
        turned[i] += 2.0 * math.pi
        np.testing.assert_allclose(_rhs(vehicle, turned, u), f0, rtol=1e-9, atol=1e-9)
    # the pose is kinematic: its derivative does not depend on the controls; every control
    # moves some velocity
    step = 1e-3 * np.asarray(vehicle.control_bound)
    for j in range(layout.control_dim):
        pushed = u.copy()
        pushed[j] += step[j]
        change = _rhs(vehicle, x, pushed) - f0
        np.testing.assert_allclose(change[pose], 0.0, atol=1e-12)
        assert np.max(np.abs(change[list(layout.velocities)])) > 0.0
    # the heading is the yaw: level, moving at 1 m/s in surge, the position moves along ψ; and
    # the heading's rate is the yaw rate
    names = layout.state_names
    for heading in (0.3, 2.0, -2.5):
        level = np.zeros(layout.state_dim)
        level[layout.heading] = heading
        level[names.index("u")] = 1.0
        rate = _rhs(vehicle, level, np.zeros(layout.control_dim))
        np.testing.assert_allclose(
            rate[list(layout.positions[:2])], [math.cos(heading), math.sin(heading)], atol=1e-12
        )
        level[names.index("r")] = 0.2
        assert _rhs(vehicle, level, np.zeros(layout.control_dim))[layout.heading] == pytest.approx(0.2)


def test_default_weights_are_the_documented_ones():
    """``Weights.for_layout`` gives the weights the 3-DOF and 6-DOF problems always had."""
    planar = uo.Weights.for_layout(uo.Vehicle.rexrov().layout)
    assert planar == uo.Weights(
        pose=(1e4, 1e4, 1e3), velocity=(10.0,) * 3, rate=(0.1,) * 3, terminal=(1e4, 1e4, 1e3, 100, 100, 100)
    )
    for vehicle in (uo.Vehicle6DOF.bluerov2_heavy(), uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)):
        nu = vehicle.layout.control_dim
        assert uo.Weights.for_layout(vehicle.layout) == uo.Weights.spatial(nu)
    vessel = uo.Weights.for_layout(VESSEL_LAYOUT)
    assert vessel.pose == (1e4, 1e4, 1e3, 1e3) and vessel.velocity == (10.0,) * 4


def test_reference_state_maps_by_name():
    rng = np.random.default_rng(3)
    planar = rng.normal(size=(5, 6))
    assert uo.Vehicle.rexrov().layout.reference_state(planar) is planar  # the same states
    spatial = rng.normal(size=(5, 12))
    assert uo.Vehicle6DOF.bluerov2_heavy().layout.reference_state(spatial) is spatial
    mapped = VESSEL_LAYOUT.reference_state(planar)
    names = REFERENCE_STATE_NAMES["planar"]
    for index, name in enumerate(VESSEL_LAYOUT.state_names):
        expected = planar[:, names.index(name)] if name in names else np.zeros(5)
        np.testing.assert_array_equal(mapped[:, index], expected)


# ------------------------------------------------------------------------------ bad input
def test_a_non_vehicle_is_refused_by_name():
    with pytest.raises(ValueError, match=r"^vehicle must implement uuv_ocp.VehicleModel .* without .*layout"):
        uo.TrackingProblem(object(), uo.Reference.paper("s2"))


def test_a_wrong_dynamics_size_is_refused_before_any_build():
    @dataclass(frozen=True)
    class Short(Vessel4DOF):
        def model_function(self) -> ca.Function:
            x, u, c = ca.SX.sym("x", 6), ca.SX.sym("u", 3), ca.SX.sym("c", 2)
            return ca.Function("f", [x, u, c], [x])

    with pytest.raises(ValueError, match=r"model_function\(\) must map column vectors of sizes \[8, 3, 2\]"):
        model_function("vehicle", Short())


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"heading": 0}, r"^layout.heading must be one of layout.angles"),
        ({"velocities": (3, 4, 5, 6)}, r"^layout.velocities must be the trailing block"),
        ({"positions": (0,)}, r"^layout.positions must give \(x, y\) or \(x, y, z\)"),
        ({"state_units": ("m",)}, r"^layout.state_units must have 8 entries"),
        ({"reference": "3d"}, r"^layout.reference must be one of"),
        ({"angles": (1, 2)}, r"^layout.positions \(0, 1\) and layout.angles \(1, 2\) must not overlap"),
    ],
)
def test_bad_layouts_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(VESSEL_LAYOUT, **change)


def test_a_reference_of_the_wrong_kind_is_refused():
    spatial = uo.Reference.from_xyz(lambda t: 0.5 * t, lambda t: 0 * t, lambda t: 1 + 0 * t)
    with pytest.raises(ValueError, match=r"^reference must give 6 states for this vehicle \(a planar"):
        uo.TrackingProblem(Vessel4DOF(), spatial)


# ------------------------------------------------------------ the user's vehicle, end to end
def _vessel_problem(horizon=15):
    return uo.TrackingProblem(
        Vessel4DOF(), uo.Reference.paper("s2"), horizon=horizon, dt=0.1, terminal="cost"
    )


def _on_reference(problem, t0=0.0):
    """Return the vessel on the reference at ``t0``, moving with it (upright: roll and roll rate zero)."""
    return problem.reference_window(t0)[0].copy()


def _rollout(x0, controls, dt=0.1):
    """States of the vessel under ``controls`` held per interval: numpy RK4, one step per interval."""
    f = Vessel4DOF().model_function()
    states = [np.asarray(x0, dtype=float)]
    for tau in controls:

        def rate(state, tau=tau):
            return np.asarray(f(state, tau, np.zeros(2))).ravel()

        x = states[-1]
        k1 = rate(x)
        k2 = rate(x + 0.5 * dt * k1)
        k3 = rate(x + 0.5 * dt * k2)
        k4 = rate(x + dt * k3)
        states.append(x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))
    return np.array(states)


def test_user_vessel_cost_wraps_its_angles_only():
    """The judge's cost of a plan equals the formulation's, computed here from the layout.

    ``ℓ = Σ w_i e_i²`` with ``e_i = 2 sin(e_i/2)`` for the layout's angles (ψ and φ) and the
    plain error for the rest; a roll 2π away and a 2 m/s surge error tell the two apart.
    """
    problem = _vessel_problem(horizon=6)
    weights = problem.weights
    x0 = _on_reference(problem)
    x0[3] += 2.0 * math.pi + 0.3  # heeled 0.3 rad, one turn away
    x0[4] += 2.0  # 2 m/s too fast
    rng = np.random.default_rng(11)
    bound = np.asarray(Vessel4DOF().control_bound)
    controls = rng.uniform(-0.05, 0.05, size=(6, 3)) * bound  # small: inside the rate bound
    states = _rollout(x0, controls)
    reference = problem.reference_window(0.0, heading=x0[2])
    error = states - reference
    for i in VESSEL_LAYOUT.angles:
        error[:, i] = 2.0 * np.sin(error[:, i] / 2.0)
    scaled = controls / bound
    previous = np.vstack([np.zeros((1, 3)), scaled[:-1]])
    expected = float(np.sum(np.asarray(weights.rate) * (scaled - previous) ** 2))
    node = np.concatenate([weights.pose, weights.velocity])
    expected += float(np.sum(node * error[1:-1] ** 2)) + float(
        np.sum(np.asarray(weights.terminal) * error[-1] ** 2)
    )
    cost, violation = uo.score(problem, controls, x0=x0, t0=0.0)
    assert violation == 0.0
    assert cost == pytest.approx(expected, rel=1e-8)


def test_user_vessel_heading_reference_follows_its_branch():
    """A vessel one turn (2π) ahead gets the heading reference on its branch; nothing else moves."""
    problem = _vessel_problem(horizon=6)
    x0 = _on_reference(problem)
    plain = problem.parameter_parts(problem.parameters(x0, 0.0))[1]
    x0[2] += 2.0 * math.pi
    turned = problem.parameter_parts(problem.parameters(x0, 0.0))[1]
    np.testing.assert_allclose(turned[:, 2], plain[:, 2] + 2.0 * math.pi, rtol=0, atol=1e-12)
    others = [i for i in range(8) if i != 2]
    np.testing.assert_array_equal(turned[:, others], plain[:, others])


ORDER = [2, 0, 1, 3, 4, 5, 6, 7]  # the permuted state is [ψ, x, y, φ, u, v, r, p]


@dataclass(frozen=True)
class PermutedVessel(Vessel4DOF):
    """The same vessel with its state in another order: the layout, not the order, says what is what."""

    @property
    def layout(self) -> uo.VehicleLayout:
        return dataclasses.replace(
            VESSEL_LAYOUT,
            state_names=tuple(VESSEL_LAYOUT.state_names[i] for i in ORDER),
            state_units=tuple(VESSEL_LAYOUT.state_units[i] for i in ORDER),
            positions=(1, 2),
            angles=(0, 3),
            heading=0,
        )

    def model_function(self) -> ca.Function:
        x, tau, current = ca.SX.sym("x", 8), ca.SX.sym("tau", 3), ca.SX.sym("current", 2)
        standard = ca.vertcat(*[x[ORDER.index(i)] for i in range(8)])
        xdot = Vessel4DOF.model_function(self)(standard, tau, current)
        return ca.Function("permuted", [x, tau, current], [xdot[ORDER]])


def test_a_permuted_state_gives_the_same_problem():
    """Tube, obstacles, wrapped angles, heading and reference found by the layout, not by position."""
    obstacle = uo.Obstacle.circle((0.5, 0.2), 0.3)  # on the vessel's way: violated
    problems = [
        uo.TrackingProblem(
            vessel,
            uo.Reference.paper("s2"),
            horizon=8,
            terminal="cost",
            position_tube=0.1,
            obstacles=(obstacle,),
        )
        for vessel in (Vessel4DOF(), PermutedVessel())
    ]
    x0 = _on_reference(problems[0])
    x0[:4] += (0.3, -0.2, 2.0 * math.pi + 0.2, 0.1)  # off the tube, a turn away, heeled
    controls = np.random.default_rng(5).uniform(-0.05, 0.05, size=(8, 3)) * np.asarray(
        Vessel4DOF().control_bound
    )
    standard = uo.score(problems[0], controls, x0=x0, t0=0.0)
    permuted = uo.score(problems[1], controls, x0=x0[ORDER], t0=0.0)
    assert standard[0] > 100.0 and standard[1] > 0.01  # tube penalty, errors and the obstacle count
    assert permuted == pytest.approx(standard, rel=1e-10, abs=1e-12)


def test_user_vessel_is_tracked_by_ipopt():
    problem = _vessel_problem()
    assert problem.state_dim == 8 and problem.control_dim == 3 * problem.horizon
    window = problem.reference_window(0.0)
    expected = uo.Reference.paper("s2").evaluate(0.1 * np.arange(problem.horizon + 1))
    np.testing.assert_allclose(window[:, [0, 1, 2, 4, 5, 6]], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(window[:, [3, 7]], 0.0)  # roll referenced to zero
    x0 = _on_reference(problem)
    result = uo.solve(problem, "ipopt", x0=x0, t0=0.0)
    assert result.success, result.status
    assert result.states.shape == (problem.horizon + 1, 8) and result.controls.shape == (problem.horizon, 3)
    assert np.all(np.abs(result.controls) <= np.asarray(Vessel4DOF().control_bound) + 1e-6)
    # an independent rollout (numpy RK4 on the vessel's Function) gives the solver's states
    np.testing.assert_allclose(result.states, _rollout(x0, result.controls), rtol=1e-6, atol=1e-6)
    # started on the path and moving with it, it stays on it: every predicted position within
    # 1 cm of the reference
    assert np.max(np.abs(result.states[:, :2] - window[:, :2])) < 0.01


def test_user_vessel_closed_loop_error_decreases():
    problem = _vessel_problem(horizon=10)
    x0 = _on_reference(problem)
    x0[:2] += (0.4, -0.3)  # start 0.5 m off the path
    x0[3] = 0.1  # and heeled by 0.1 rad
    run = uo.simulate(uo.NMPC(problem, solver="ipopt"), x0=x0, duration=3.0, seed=1)
    assert run.states.shape == (31, 8) and run.reference.shape == (31, 8)
    assert run.state_names == VESSEL_LAYOUT.state_names
    error = np.hypot(*(run.states[:, :2] - run.reference[:, :2]).T)
    assert error[0] == pytest.approx(0.5)
    # the error closes and does not come back
    assert error[-1] < 0.02 * error[0]
    assert np.max(error[15:]) < 0.2 * error[0]
    assert np.max(np.abs(run.states[15:, 3])) < 0.05  # the heel decays and stays small
    assert uo.ClosedLoopResult.from_arrays(run.arrays()).state_names == run.state_names  # saved and read
    metrics = run.metrics()  # the horizontal errors, by the layout's names
    assert metrics["max_abs_ex"] == pytest.approx(np.max(np.abs(run.states[:, 0] - run.reference[:, 0])))
    assert "max_abs_ez" not in metrics
    assert run.failures == 0
    assert run.state_roles == ("x", "y", "psi", "", "velocity", "velocity", "velocity", "velocity")
    # the figures read the run through the layout's roles: ψ, then u, v, r, p (no z, no w)
    pytest.importorskip("matplotlib")
    from uuv_ocp import plotting

    figure = plotting.state_figure(run)
    visible = [axis for axis in figure.axes if axis.get_visible()]
    assert [axis.get_ylabel() for axis in visible][-1] == "p (rad/s)"  # the layout's unit
    for axis, column in zip(visible, (2, 4, 5, 6, 7), strict=True):
        reference, state = axis.get_lines()[:2]
        np.testing.assert_array_equal(reference.get_ydata(), run.reference[:, column])
        np.testing.assert_array_equal(state.get_ydata(), run.states[:, column])
    plotting.xoy_figure(run)
    thrust = plotting.thrust_figure(run, vehicle=Vessel4DOF())
    assert "Y (N)" in [axis.get_ylabel() for axis in thrust.axes]


def test_a_vehicle_steered_by_propeller_and_rudder_is_brought_onto_its_line():
    """Controls in rad/s and rad: bounds, rates and the NMPC act on the actuators themselves."""
    vehicle = Torpedo()
    line = uo.Reference.waypoints([[0.0, 0.0], [60.0, 0.0]], speed=1.0, turn_radius=2.0)
    problem = uo.TrackingProblem(vehicle, line, horizon=20, dt=0.1, terminal="cost")
    plant = uo.rk4_step(model_function("plant", vehicle), problem.dt, 10)
    controller = uo.NMPC(problem, "ipopt")
    state = problem.initial_state()
    state[1] += 0.5  # 0.5 m beside the line: only the rudder can close it (no sway actuator)
    state[3] = 1.0  # cruising at the line's speed
    # the propeller running at its cruise speed: thrust ∝ n|n| has no slope at n = 0, where a
    # Newton-type solver started from rest would stay
    cruise = math.sqrt(vehicle.damping[0] * 1.0 / vehicle.thrust_coefficient)
    command, commands, errors = np.array([cruise, 0.0]), [], []
    for k in range(80):
        record = controller.step(state, k * problem.dt, command)
        assert not record.fallback
        step_change = np.abs(record.control - command)
        assert np.all(step_change <= np.asarray(vehicle.control_rate_bound) * problem.dt + 1e-6)
        command = record.control
        commands.append(command)
        state = np.array(plant(state, command, np.zeros(2))).ravel()
        errors.append(state[:2] - line.evaluate(np.array([(k + 1) * problem.dt]))[0, :2])
    commands, errors = np.array(commands), np.array(errors)
    assert np.all(np.abs(commands) <= np.asarray(vehicle.control_bound) + 1e-6)
    assert np.max(np.abs(commands[:, 1])) > 0.1  # it steered with the rudder
    assert np.max(np.abs(errors[-20:])) < 0.02  # on the line, at its place, after 6 s


def test_model_parameters_are_validated_by_name():
    from uuv_ocp.model.base import ModelParameter, model_parameters, parametric_model_function

    with pytest.raises(ValueError, match="must not be one of"):
        ModelParameter("current", 2, (0, 0), (-1, -1), (1, 1))
    with pytest.raises(ValueError, match="size must be an integer >= 1"):
        ModelParameter("gain", 0, (), (), ())
    with pytest.raises(ValueError, match="default must be 2 finite numbers"):
        ModelParameter("gain", 2, (1.0,), (0, 0), (1, 1))
    with pytest.raises(ValueError, match="default must lie in"):
        ModelParameter("gain", 1, (2.0,), (0.0,), (1.0,))
    with pytest.raises(ValueError, match="lower must be <= upper"):
        ModelParameter("gain", 1, (0.0,), (1.0,), (0.0,))
    assert model_parameters(uo.Vehicle.rexrov()) == ()  # declares none: used as before
    boat = uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)
    assert [(item.name, item.size, item.unit) for item in model_parameters(boat)] == [
        ("health", 8, "1"),
        ("thrust_offset", 8, "N"),
    ]
    assert model_parameters(uo.Vehicle6DOF.bluerov2_heavy()) == ()
    assert parametric_model_function("vehicle", boat).n_in() == 5

    class Broken:  # declares a parameter whose function does not take it
        name = "broken"
        layout = boat.layout
        control_bound = boat.control_bound
        control_rate_bound = boat.control_rate_bound
        model_parameters = (ModelParameter("gain", 1, (1.0,), (0.0,), (2.0,)),)

        def model_function(self):
            return boat.model_function()

        def parametric_model_function(self):
            return boat.model_function()

    with pytest.raises(ValueError, match=r"parametric_model_function\(\) must map column vectors of sizes"):
        parametric_model_function("vehicle", Broken())
