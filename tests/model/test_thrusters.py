"""Thruster configurations (uuv_ocp.model.thrusters): allocation matrices against their geometry.

The columns are checked against direction and moment written out here, the BlueROV2 Heavy's
limits against its published geometry, the RexROV 2's matrix against uuv_simulator's TAM.yaml.
"""

import numpy as np
import pytest

from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.thrusters import ThrusterConfiguration


def test_allocation_columns_are_direction_and_moment():
    rng = np.random.default_rng(8)
    positions = rng.normal(size=(5, 3))
    directions = rng.normal(size=(5, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    config = ThrusterConfiguration(positions, directions, max_thrust=np.full(5, 10.0))
    allocation = config.allocation
    assert allocation.shape == (6, 5)
    for i, ((rx, ry, rz), (dx, dy, dz)) in enumerate(zip(positions, directions, strict=True)):
        moment = [ry * dz - rz * dy, rz * dx - rx * dz, rx * dy - ry * dx]
        np.testing.assert_allclose(allocation[:, i], [dx, dy, dz, *moment], rtol=1e-14, atol=1e-15)


def test_bluerov2_heavy_allocation_has_full_rank_and_known_limits():
    config = ThrusterConfiguration.bluerov2_heavy()
    assert config.count == 8
    assert np.linalg.matrix_rank(config.allocation) == 6
    h = np.sqrt(0.5)
    expected = [4 * 40 * h, 4 * 40 * h, 4 * 40, 4 * 40 * 0.218, 4 * 40 * 0.12, 4 * 40 * (0.156 + 0.111) * h]
    np.testing.assert_allclose(config.generalised_force_limits(), expected, rtol=1e-7)
    np.testing.assert_allclose(Vehicle6DOF.bluerov2_heavy().max_thrust, expected, rtol=1e-7)


def test_rexrov2_allocation_matches_the_simulator_tam():
    # rexrov2_control/config/TAM.yaml (uuvsimulator/rexrov2), ROS body frame x fwd, y port, z up
    tam = np.array(
        [
            [0.0, 0.2588192276583895, 0.0, 0.0, 0.9063078136609996, 0.9063078136609996],
            [1.0, 0.0, 0.3826835895134471, 0.3826835895134471, 0.4226182046445928, -0.4226182046445928],
            [0.0, 0.9659257773733522, 0.9238794674182862, -0.9238794674182862, 0.0, 0.0],
            [
                -0.2373,
                0.0,
                -0.6957355424885819,
                -0.6957355424885819,
                -0.10159741639656011,
                0.10159741639656011,
            ],
            [
                0.0,
                0.946145736358475,
                -0.7995252448269914,
                0.7995253373805782,
                0.2178763984041043,
                0.2178763984041043,
            ],
            [0.4878, 0.0, 0.3311744245549398, 0.33117433217493447, -0.7638899192332406, 0.7638899192332406],
        ]
    )
    flip = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])
    config = ThrusterConfiguration.rexrov2()
    np.testing.assert_allclose(flip @ config.allocation, tam, atol=1e-6)
    # square and invertible: the pure-axis limit is f_max / max_i |(T⁻¹)_ik|
    expected = 1540.0 / np.max(np.abs(np.linalg.inv(config.allocation)), axis=0)
    np.testing.assert_allclose(config.generalised_force_limits(), expected, rtol=1e-7)
    np.testing.assert_allclose(Vehicle6DOF.rexrov2().max_thrust, expected, rtol=1e-7)


def test_rexrov_allocation_matches_the_simulator_tam():
    # uuv_control/uuv_thruster_manager/config/rexrov/TAM.yaml (uuvsimulator/uuv_simulator),
    # ROS body frame x fwd, y port, z up; columns are thrusters 0..7
    tam = np.array(
        [
            [0.15974268848446743, 0.15974268848446743, -0.1597424266785477, -0.1597424266785477]
            + [0.7071068613706476, 0.7071068613706476, -0.7071065406341925, -0.7071065406341925],
            [-0.2136101154609486, 0.2136101154609486, -0.21360976537047976, 0.21360976537047976]
            + [0.7071067010024383, -0.7071067010024383, 0.7071070217388206, -0.7071070217388206],
            [0.9637701967007046, 0.9637701967007046, 0.9637703176884092, 0.9637703176884092]
            + [0.0, 0.0, 0.0, 0.0],
            [0.4352320257020549, -0.4352320257020549, 0.4352318810229865, -0.4352318810229865]
            + [-0.09121676442931455, 0.09121676442931455, -0.09121680580430785, 0.09121680580430785],
            [0.9430934973994073, 0.9430934973994073, -0.9430934667380182, -0.9430934667380182]
            + [0.09121678511681354, 0.09121678511681354, -0.09121674374181084, -0.09121674374181084],
            [0.13688862492470316, -0.13688862492470316, -0.1368884005748274, 0.1368884005748274]
            + [-0.6487987634902757, 0.6487987634902757, 0.6487987335687417, -0.6487987335687417],
        ]
    )
    flip = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])
    config = ThrusterConfiguration.rexrov()
    assert config.count == 8 and config.max_thrust == (2000.0,) * 8
    np.testing.assert_allclose(flip @ config.allocation, tam, atol=1e-6)


def test_rexrov_thrusters_reach_the_planar_box_corners_without_saturating():
    # DESIGN §6: every corner of the 2000 N / 2000 N / 1400 N·m (X, Y, N) box of Vehicle.rexrov
    # is reachable with |f_i| <= 2000 N; checked with its own LP (feasibility, Z = K = M = 0)
    from scipy.optimize import linprog

    config = ThrusterConfiguration.rexrov()
    for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
        target = np.zeros(6)
        target[[0, 1, 5]] = signs * np.array([2000.0, 2000.0, 1400.0])
        result = linprog(
            np.zeros(8), A_eq=config.allocation, b_eq=target, bounds=[(-2000.0, 2000.0)] * 8, method="highs"
        )
        assert result.status == 0, (signs, result.message)


def test_a_time_constant_is_broadcast_and_all_zero_or_all_positive():
    """A scalar τ applies to every thruster; 0 (default) means no response; mixed is refused."""
    layout = ThrusterConfiguration.bluerov2_heavy()
    assert layout.time_constant == (0.0,) * 8 and not layout.responds
    slow = ThrusterConfiguration(layout.positions, layout.directions, layout.max_thrust, time_constant=0.1)
    assert slow.time_constant == (0.1,) * 8 and slow.responds and slow != layout
    for bad in ((0.1,) * 7 + (0.0,), -0.1, (0.1,) * 7):
        with pytest.raises(ValueError, match="time_constant"):
            ThrusterConfiguration(layout.positions, layout.directions, layout.max_thrust, time_constant=bad)
