"""Top speeds of a 6-DOF vehicle and the reference-speed check that uses them.

The analytic cases are solved here by hand; the presets are checked against the model's own
dynamics (the force that makes the acceleration zero), not against the code under test.
"""

import math
import warnings

import numpy as np
import pytest

from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.reference.path import Reference
from uuv_ocp.specs import reference_from_spec
from uuv_ocp.studies.compare import _reach, unreachable_from
from uuv_ocp.tracking import ReferenceSpeedWarning, warn_if_reference_too_fast


def _box_vehicle(
    *, linear=(0.0,) * 6, quadratic=(50.0, 50.0, 80.0, 1.0, 1.0, 1.0), weight=100.0, buoyancy=100.0
):
    """Return a symmetric vehicle: equal added mass in surge and sway (no Munk moment), r_g = r_b = 0."""
    return Vehicle6DOF(
        mass=20.0,
        inertia=(1.0, 1.0, 1.0),
        added_mass=(5.0, 5.0, 10.0, 0.1, 0.1, 0.1),
        linear_damping=linear,
        quadratic_damping=quadratic,
        weight=weight,
        buoyancy=buoyancy,
        max_thrust=(100.0, 100.0, 50.0, 10.0, 10.0, 10.0),
        name="box",
    )


def test_max_speed_solves_the_on_axis_balance():
    vehicle = _box_vehicle(linear=(10.0, 0.0, 20.0, 1.0, 0.0, 2.0))
    for axis, speed in enumerate(vehicle.max_speed()):
        d_lin, d_quad = vehicle.linear_damping[axis], vehicle.quadratic_damping[axis]
        limit = vehicle.max_thrust[axis]
        # positive root of d_quad s² + d_lin s − limit, by the textbook formula
        expected = (-d_lin + math.sqrt(d_lin**2 + 4 * d_quad * limit)) / (2 * d_quad)
        assert speed == pytest.approx(expected, rel=1e-12)
    assert Vehicle6DOF.bluerov2_heavy().max_speed()[0] == pytest.approx(
        (-13.7 + math.sqrt(13.7**2 + 4 * 141.0 * 113.13708498984761)) / (2 * 141.0), rel=1e-9
    )


def test_top_horizontal_speed_of_a_symmetric_vehicle_is_the_45_degree_crab():
    # X = d s² cos²β <= L and Y = d s² sin²β <= L: best at β = ±45°, s = sqrt(2 L / d)
    vehicle = _box_vehicle()
    speed, crab = vehicle.max_horizontal_speed(resolution=9001)
    assert speed == pytest.approx(math.sqrt(2 * 100.0 / 50.0), rel=1e-9)
    assert abs(crab) == pytest.approx(math.pi / 4, abs=1e-9)
    assert speed > vehicle.max_speed()[0]  # crabbing beats surge alone


def test_a_vehicle_that_cannot_hold_depth_has_no_top_speed():
    # 80 N net weight against 50 N of heave force: it sinks even at rest
    speed, _ = _box_vehicle(weight=180.0, buoyancy=100.0).max_horizontal_speed()
    assert speed == 0.0


@pytest.mark.parametrize("preset", [Vehicle6DOF.bluerov2_heavy, Vehicle6DOF.rexrov2])
def test_top_horizontal_speed_is_the_largest_steady_level_motion_the_force_box_holds(preset):
    vehicle = preset()
    speed, crab = vehicle.max_horizontal_speed()
    limits = np.asarray(vehicle.max_thrust)
    dynamics = vehicle.dynamics
    mass = vehicle.mass_matrix

    def needed(s, beta):
        """Force that holds level motion at (s, β) steady: −M ν̇ under zero force."""
        state = np.zeros(12)
        state[6:8] = s * np.cos(beta), s * np.sin(beta)
        drift = np.array(dynamics(state, np.zeros(6), np.zeros(3))).ravel()[6:]
        return -mass @ drift

    tau = needed(speed, crab)
    assert np.max(np.abs(tau) / limits) == pytest.approx(1.0, rel=1e-6)  # one axis saturated
    state = np.zeros(12)
    state[6:8] = speed * np.cos(crab), speed * np.sin(crab)
    np.testing.assert_allclose(np.array(dynamics(state, tau, np.zeros(3))).ravel()[6:], 0.0, atol=1e-9)
    for beta in np.linspace(-np.pi / 2, np.pi / 2, 721):
        assert np.any(np.abs(needed(1.002 * speed, beta)) > limits), beta


def test_bluerov2_on_s2_is_flagged_like_a_3dof_vehicle():
    """BlueROV2 Heavy tops out below s2's path speed (1.12 m/s at the start): warned, noted, shaded."""
    vehicle = Vehicle6DOF.bluerov2_heavy()
    reference = reference_from_spec(["s2"], spatial=True)
    top, _ = vehicle.max_horizontal_speed()
    times = np.linspace(0.0, 30.0, 301)
    states = reference.evaluate(times)
    speed = np.hypot(states[:, 6], states[:, 7])
    first = float(times[np.flatnonzero(speed > top)[0]])
    with pytest.warns(ReferenceSpeedWarning, match="bluerov2-heavy"):
        assert warn_if_reference_too_fast(reference, vehicle, times) == first
    assert unreachable_from(reference, vehicle, 0.0, 30.0) == pytest.approx(first, abs=0.01)
    peak, _, note = _reach(reference, vehicle, 0.0, 30.0)  # what a compare row's note says
    assert peak == pytest.approx(speed.max(), rel=1e-3)
    assert note.startswith(f"path speed > {top:.2f} m/s")


def test_a_reachable_or_mismatched_reference_is_not_flagged():
    reference = reference_from_spec(["s2"], spatial=True)
    times = np.linspace(0.0, 30.0, 301)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ReferenceSpeedWarning)
        assert warn_if_reference_too_fast(reference, Vehicle6DOF.rexrov2(), times) is None  # 2.2 m/s
        # a planar reference is not the 6-DOF vehicle's: no check (as before)
        assert warn_if_reference_too_fast(Reference.paper("s2"), Vehicle6DOF.bluerov2_heavy(), times) is None
    assert unreachable_from(reference, Vehicle6DOF.rexrov2(), 0.0, 30.0) is None
