"""Thruster faults in a closed loop (uuv_ocp.control.faults, simulate(faults=...)), issue 27.

References: the schedule is rebuilt here on an integer grid (times in tenths of a second),
the plant is replayed by RK4 of the force model with ``τ = T (h ∘ f + s)`` written out with
numpy, the pseudo-inverse allocation by ``numpy.linalg.lstsq`` (its minimum-norm solution).
"""

from __future__ import annotations

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.control.faults import ThrusterFault, fault_schedule, fault_step
from uuv_ocp.model import Vehicle6DOF

DT = 0.1


@pytest.fixture(scope="module")
def boat():
    return Vehicle6DOF.bluerov2_heavy(thrusters=True)


@pytest.fixture(scope="module")
def station(boat):
    hold = uo.Reference.hold((0.0, 0.0, 1.0, 0.0), duration=20.0)
    return uo.TrackingProblem(boat, hold, horizon=5, dt=DT, terminal="cost")


class Spy(uo.NMPC):
    """An NMPC that remembers the parameters each step was given (what the controller is told)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.told = []

    def step(self, x, t=0.0, u_prev=None, current=None, parameters=None):
        self.told.append(parameters)
        return super().step(x, t, u_prev, current, parameters)


def _expected_health(faults_in_tenths, start_tenths, steps, count):
    """Return the schedule on the integer grid: a fault at m tenths acts from step m − start (>= 0)."""
    health, offset = np.ones((steps, count)), np.zeros((steps, count))
    for thruster, tenths, h, s in sorted(faults_in_tenths, key=lambda item: item[1]):
        first = max(0, tenths - start_tenths)
        health[first:, thruster] = h
        offset[first:, thruster] = s
    return health, offset


def _replay(boat, run, health, offset):
    """RK4 (10 sub-steps) of the force model with τ = T (h ∘ f + s) from the run's controls."""
    step = uo.rk4_step(boat.dynamics, DT, 10)
    allocation = np.array(boat.thrusters.allocation)
    x, states = run.states[0], [run.states[0]]
    for k, f in enumerate(run.controls):
        x = np.array(step(x, allocation @ (health[k] * f + offset[k]), np.zeros(3))).ravel()
        states.append(x)
    return np.array(states)


def test_the_plant_health_over_time_is_the_schedule(boat, station, tmp_path):
    # fault times written in tenths of a second: 0.3, 0.7 and 1.3 s are not multiples of 0.1
    # in floating point, so a float comparison of times would put them one step late
    table = [(6, 3, 0.5, 0.0), (0, 7, 0.0, 15.0), (6, 13, 0.0, 0.0), (2, 0, 0.25, 0.0)]
    faults = (
        ThrusterFault(6, 0.3, "loss", effectiveness=0.5),
        ThrusterFault(0, 0.7, "stuck", value=15.0),
        ThrusterFault(6, 1.3, "failed"),  # replaces its loss from 1.3 s on
        ThrusterFault(2, 0.0, "loss", effectiveness=0.25),
    )
    start_tenths, steps = 2, 15
    controller = Spy(station, "ipopt")
    run = uo.simulate(controller, station.initial_state(0.2), 1.5, t0=0.2, faults=faults)
    health, offset = _expected_health(table, start_tenths, steps, 8)
    np.testing.assert_array_equal(run.thruster_health, health)
    np.testing.assert_allclose(run.thruster_forces, health * run.controls + offset, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.states, _replay(boat, run, health, offset), rtol=0, atol=1e-9)
    # not the oracle: the controller is told nothing (its warm-up's two steps included)
    assert controller.told == [None] * (steps + 2)
    path = tmp_path / "run.npz"
    run.save(path)
    loaded = uo.ClosedLoopResult.load(path)
    np.testing.assert_array_equal(loaded.thruster_health, health)
    np.testing.assert_array_equal(loaded.thruster_forces, run.thruster_forces)


def test_the_oracle_is_told_the_true_health_at_every_step(station):
    faults = (ThrusterFault(5, 0.4), ThrusterFault(1, 0.6, "stuck", value=-8.0))
    controller = Spy(station, "ipopt")
    run = uo.simulate(controller, station.initial_state(), 1.0, faults=faults, health_known=True)
    health, offset = _expected_health([(5, 4, 0.0, 0.0), (1, 6, 0.0, -8.0)], 0, 10, 8)
    told = controller.told[-10:]  # the loop's steps, after the warm-up's two
    assert len(controller.told) == 12 and run.failures == 0
    np.testing.assert_array_equal([t["health"] for t in told], health)
    np.testing.assert_array_equal([t["thrust_offset"] for t in told], offset)
    np.testing.assert_array_equal(run.thruster_health, health)


def test_a_run_without_faults_records_no_health_and_is_unchanged(station):
    x0 = station.initial_state() + np.r_[0.05, 0.0, 0.05, np.zeros(9)]
    plain = uo.simulate(uo.NMPC(station, "ipopt"), x0, 0.5)
    told_ones = uo.simulate(uo.NMPC(station, "ipopt"), x0, 0.5, health_known=True)
    assert plain.thruster_health.size == 0 and "thruster_health" not in plain.arrays()
    # the oracle told "all healthy" is the loop without faults
    np.testing.assert_allclose(told_ones.states, plain.states, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(told_ones.thruster_health, np.ones((5, 8)))


def test_pseudo_inverse_allocation_maps_the_planned_force_to_thrusters(boat):
    forces = Vehicle6DOF.bluerov2_heavy()
    hold = uo.Reference.hold((0.0, 0.0, 1.0, 0.0), duration=20.0)
    problem = uo.TrackingProblem(forces, hold, horizon=5, dt=DT, terminal="cost")
    x0 = problem.initial_state() + np.r_[0.1, -0.1, 0.1, np.zeros(9)]
    config = boat.thrusters
    run = uo.simulate(
        uo.NMPC(problem, "ipopt"), x0, 1.0, allocation=config, faults=(ThrusterFault(3, 0.5, "failed"),)
    )
    allocation = np.array(config.allocation)
    health = np.ones((10, 8))
    health[5:, 3] = 0.0
    commanded = np.array([np.linalg.lstsq(allocation, tau, rcond=None)[0] for tau in run.controls])
    commanded = np.clip(commanded, -40.0, 40.0)
    np.testing.assert_array_equal(run.thruster_health, health)
    np.testing.assert_allclose(run.thruster_forces, health * commanded, rtol=0, atol=1e-9)
    # the plant is the force model under τ = T (h ∘ f): replayed with the delivered forces
    step = uo.rk4_step(forces.dynamics, DT, 10)
    x = x0
    for k in range(10):
        x = np.array(step(x, allocation @ run.thruster_forces[k], np.zeros(3))).ravel()
    np.testing.assert_allclose(run.states[-1], x, rtol=0, atol=1e-9)
    # before the fault and unsaturated, T clip(T⁺ τ) = τ: the plant got the planned force
    assert np.max(np.abs(commanded[:5])) < 40.0
    np.testing.assert_allclose(run.thruster_forces[:5] @ allocation.T, run.controls[:5], atol=1e-9)


def test_fault_steps_use_the_integer_grid():
    for tenths in range(0, 200):
        assert fault_step(tenths * 0.1, 0.0, 0.1) == tenths
        assert fault_step(tenths / 10, 0.3, 0.1) == max(0, tenths - 3)
    assert fault_step(0.05, 0.0, 0.1) == 1  # between two instants: from the next one


def test_faults_are_refused_by_name(boat, station):
    with pytest.raises(ValueError, match="kind must be one of"):
        ThrusterFault(0, 1.0, "broken")
    with pytest.raises(ValueError, match="effectiveness is required for kind='loss'"):
        ThrusterFault(0, 1.0, "loss")
    with pytest.raises(ValueError, match=r"effectiveness must lie in \[0, 1\]"):
        ThrusterFault(0, 1.0, "loss", effectiveness=1.5)
    with pytest.raises(ValueError, match="value is required for kind='stuck'"):
        ThrusterFault(0, 1.0, "stuck")
    with pytest.raises(ValueError, match="value is for kind='stuck' only"):
        ThrusterFault(0, 1.0, "failed", value=3.0)
    with pytest.raises(ValueError, match="time"):
        ThrusterFault(0, -1.0)
    with pytest.raises(ValueError, match="thruster"):
        ThrusterFault(-1, 1.0)

    def schedule(faults, problem=station, **options):
        return fault_schedule(faults, problem, steps=10, t0=0.0, **options)

    with pytest.raises(ValueError, match="faults must be a tuple of uuv_ocp.ThrusterFault"):
        schedule(ThrusterFault(0, 1.0))
    with pytest.raises(ValueError, match=r"faults\[1\] must be a uuv_ocp.ThrusterFault"):
        schedule((ThrusterFault(0, 1.0), (1, 1.0)))
    with pytest.raises(ValueError, match=r"faults\[0\].thruster must be an index in \[0, 8\)"):
        schedule((ThrusterFault(8, 1.0),))
    with pytest.raises(ValueError, match=r"faults\[0\].value must lie within thruster 2's bound ±40 N"):
        schedule((ThrusterFault(2, 1.0, "stuck", value=41.0),))
    with pytest.raises(ValueError, match=r"faults\[1\] is a second fault of thruster 2 at t = 1.0 s"):
        schedule((ThrusterFault(2, 1.0), ThrusterFault(2, 1.0, "loss", effectiveness=0.5)))
    forces = uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), station.reference, horizon=5, dt=DT)
    with pytest.raises(ValueError, match="need a vehicle whose controls are thruster forces"):
        schedule((ThrusterFault(0, 1.0),), forces)
    with pytest.raises(ValueError, match="health_known=True needs a controller whose model takes the health"):
        schedule((), forces, allocation=boat.thrusters, health_known=True)
    with pytest.raises(ValueError, match="controller's vehicle must plan in it"):
        schedule((), station, allocation=boat.thrusters)
    with pytest.raises(ValueError, match="allocation must be a uuv_ocp.ThrusterConfiguration"):
        schedule((), forces, allocation="pinv")
    with pytest.raises(ValueError, match="health_known must be"):
        schedule((), station, health_known="yes")
    ocp = uo.Ocp(5, DT)
    x = ocp.state("x")
    u = ocp.control("u", lower=-1, upper=1)
    ocp.set_der(x, u)
    ocp.add_stage_cost(residual=x)
    with pytest.raises(ValueError, match="need a TrackingProblem, got a Ocp"):
        schedule((ThrusterFault(0, 1.0),), ocp)
    # and through simulate, before anything runs
    with pytest.raises(ValueError, match=r"faults\[0\].thruster must be an index"):
        uo.simulate(uo.NMPC(station, "ipopt"), station.initial_state(), 0.5, faults=(ThrusterFault(9, 0.1),))


def test_random_faults_are_drawn_from_the_generator_within_their_ranges():
    """Seeded draws: equal for equal seeds, distinct thrusters, times/kinds/forces in range."""
    spec = uo.RandomFaults(count=3, window=(2.0, 4.0), kinds=("failed", "loss", "stuck"), effectiveness=0.5)
    bounds = np.linspace(30.0, 60.0, 8)
    first = spec.draw(np.random.default_rng(5), bounds, t0=1.0)
    assert first == spec.draw(np.random.default_rng(5), bounds, t0=1.0)
    draws = [spec.draw(np.random.default_rng(seed), bounds, t0=1.0) for seed in range(200)]
    assert any(draw != first for draw in draws[1:])
    seen_thrusters, seen_kinds = set(), set()
    for draw in draws:
        assert len(draw) == 3 and len({item.thruster for item in draw}) == 3
        assert [item.time for item in draw] == sorted(item.time for item in draw)
        for item in draw:
            assert 3.0 <= item.time <= 5.0  # the window counted from t0 = 1 s
            seen_thrusters.add(item.thruster)
            seen_kinds.add(item.kind)
            if item.kind == "loss":
                assert item.effectiveness == 0.5
            if item.kind == "stuck":
                assert 0.25 * bounds[item.thruster] <= abs(item.value) <= 0.75 * bounds[item.thruster]
    assert seen_thrusters == set(range(8)) and seen_kinds == {"failed", "loss", "stuck"}
    assert uo.RandomFaults(count=0).draw(np.random.default_rng(0), bounds) == ()


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"count": -1}, "count"),
        ({"window": (5.0, 1.0)}, "window must be"),
        ({"window": (-1.0, 1.0)}, "window"),
        ({"kinds": ()}, "kinds must be a non-empty"),
        ({"kinds": ("failed", "failed")}, "kinds must be a non-empty"),
        ({"kinds": ("broken",)}, "kinds must be one of"),
        ({"effectiveness": 1.0}, "effectiveness must lie in"),
        ({"stuck_range": (0.5, 1.5)}, "stuck_range must be"),
    ],
)
def test_bad_random_faults_are_refused_by_name(changes, match):
    with pytest.raises(ValueError, match=match):
        uo.RandomFaults(**changes)
    with pytest.raises(ValueError, match="count must be at most"):
        uo.RandomFaults(count=3).draw(np.random.default_rng(0), np.ones(2))
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        uo.RandomFaults().draw(0, np.ones(8))
