"""Sensors: the multi-rate schedule against integer arithmetic, the presets, draws, bad inputs."""

import math

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.estimation import Measurement, Sensor, Sensors


def expected_steps(rate_num: int, rate_den: int, dt_num: int, dt_den: int, steps: int) -> set[int]:
    """Return the steps at which a sensor of rate p/q Hz reports with dt = a/b s (k dt >= j / f).

    Sample j is at j q / p s, i.e. at step ceil(j q b / (p a)): integers only.
    """
    due = set()
    j = 0
    while True:
        k = -(-j * rate_den * dt_den // (rate_num * dt_num))
        if k >= steps:
            return due
        due.add(k)
        j += 1


@pytest.mark.parametrize(
    ("rate", "fraction", "dt", "dt_fraction"),
    [
        (1.0, (1, 1), 0.1, (1, 10)),
        (5.0, (5, 1), 0.1, (1, 10)),
        (10.0, (10, 1), 0.1, (1, 10)),
        (3.0, (3, 1), 0.1, (1, 10)),
        (0.3, (3, 10), 0.1, (1, 10)),
        (7.0, (7, 1), 0.05, (1, 20)),
        (2.5, (5, 2), 0.2, (1, 5)),
    ],
)
def test_schedule_matches_integer_arithmetic_over_a_long_run(rate, fraction, dt, dt_fraction):
    steps = 20_000  # 2000 s at 0.1 s: no drift
    sensor = Sensor.of_states("s", [0], 2, rate, 0.1)
    due = {k for k in range(steps) if sensor.due(k, dt)}
    # a sensor faster than the control rate reports at every step
    expected = expected_steps(*fraction, *dt_fraction, steps) if rate * dt <= 1 else set(range(steps))
    assert due == expected


def test_collection_schedule_and_draws():
    x = np.array([1.0, 2.0, 0.5])
    sensors = Sensors(
        [
            Sensor.of_states("fix", [0, 1], 3, 1.0, 0.5),
            Sensor.of_states("heading", [2], 3, 10.0, 0.01, angular=(True,)),
        ]
    )
    assert sensors.due(0, 0.1) == (0, 1)
    assert sensors.due(5, 0.1) == (1,)
    assert sensors.due(10, 0.1) == (0, 1)
    a = sensors.measure(10, 0.1, x, np.random.default_rng(4))
    b = sensors.measure(10, 0.1, x, np.random.default_rng(4))
    np.testing.assert_array_equal(a.values, b.values)  # seeded: equal draws
    assert a.sensors == (0, 1) and a.values.shape == (3,)
    # the noise is what the standard deviations say (many draws)
    rng = np.random.default_rng(0)
    draws = np.array([sensors.measure(0, 0.1, x, rng).values for _ in range(4000)])
    np.testing.assert_allclose(draws.mean(axis=0), [1.0, 2.0, 0.5], atol=0.03)
    np.testing.assert_allclose(draws.std(axis=0), [0.5, 0.5, 0.01], rtol=0.05)
    np.testing.assert_array_equal(sensors.rows((1,)), [2])


def test_dropouts_and_outliers_happen_at_their_rates():
    sensor = Sensor.of_states(
        "dvl", [0], 1, 10.0, 0.01, dropout=0.3, outlier_probability=0.1, outlier_scale=50.0
    )
    sensors = Sensors([sensor])
    rng = np.random.default_rng(2)
    results = [sensors.measure(k, 0.1, [0.0], rng) for k in range(5000)]
    dropped = np.mean([bool(m.dropped) for m in results])
    outliers = [m for m in results if m.outliers]
    assert abs(dropped - 0.3) < 0.03
    assert abs(len(outliers) / sum(bool(m.sensors) for m in results) - 0.1) < 0.02
    assert np.std([m.values[0] for m in outliers]) > 10 * 0.01


@pytest.mark.parametrize("vehicle", [uo.Vehicle.rexrov(), uo.Vehicle6DOF.rexrov2()], ids=["3dof", "6dof"])
def test_auv_preset_is_built_from_the_layout(vehicle):
    layout = vehicle.layout
    sensors = Sensors.auv(vehicle)
    x = np.arange(1.0, layout.state_dim + 1)
    by_name = dict(zip(sensors.names, sensors, strict=True))
    np.testing.assert_array_equal(
        by_name["position"].function(x).full().ravel(), x[list(layout.positions[:2])]
    )
    linear = list(layout.velocities[: len(layout.positions)])
    np.testing.assert_array_equal(by_name["dvl"].function(x).full().ravel(), x[linear])
    np.testing.assert_array_equal(by_name["attitude"].function(x).full().ravel(), x[list(layout.angles)])
    assert by_name["position"].rate == 1.0 and by_name["position"].std == (0.5, 0.5)
    assert by_name["dvl"].rate == 5.0 and by_name["dvl"].dropout > 0
    assert by_name["attitude"].std[0] == pytest.approx(math.radians(0.5))
    assert all(by_name["attitude"].angular)
    if len(layout.positions) == 3:
        assert by_name["depth"].rate == 10.0 and by_name["depth"].std == (0.05,)
        assert by_name["depth"].function(x).full().ravel()[0] == x[layout.positions[2]]
    else:
        assert "depth" not in by_name


def test_user_measurement_function_on_an_ocp_state():
    x = ca.SX.sym("x", 2)
    range_sensor = Sensor("range", ca.Function("h", [x], [ca.norm_2(x)]), 2.0, 0.1)
    sensors = Sensors([range_sensor])
    m = sensors.measure(0, 0.1, [3.0, 4.0], np.random.default_rng(0))
    assert isinstance(m, Measurement) and abs(m.values[0] - 5.0) < 0.5


def test_bad_sensors_raise_naming_the_parameter():
    x = ca.SX.sym("x", 2)
    h = ca.Function("h", [x], [x[0]])
    with pytest.raises(ValueError, match="rate"):
        Sensor("s", h, 0.0, 0.1)
    with pytest.raises(ValueError, match="std"):
        Sensor("s", h, 1.0, (0.1, 0.2))
    with pytest.raises(ValueError, match="std"):
        Sensor("s", h, 1.0, -0.1)
    with pytest.raises(ValueError, match="dropout"):
        Sensor("s", h, 1.0, 0.1, dropout=1.0)
    with pytest.raises(ValueError, match="outlier_scale"):
        Sensor("s", h, 1.0, 0.1, outlier_scale=0.5)
    with pytest.raises(ValueError, match="function"):
        Sensor("s", "x[0]", 1.0, 0.1)
    with pytest.raises(ValueError, match="angular"):
        Sensor("s", h, 1.0, 0.1, angular=(True, False))
    with pytest.raises(ValueError, match="indices"):
        Sensor.of_states("s", [2], 2, 1.0, 0.1)
    with pytest.raises(ValueError, match="distinct names"):
        Sensors([Sensor("s", h, 1.0, 0.1), Sensor("s", h, 2.0, 0.1)])
    with pytest.raises(ValueError, match="one state"):
        Sensors([Sensor("a", h, 1.0, 0.1), Sensor.of_states("b", [0], 3, 1.0, 0.1)])
    with pytest.raises(ValueError, match="vehicle"):
        Sensors.auv("rexrov")
    sensors = Sensors([Sensor("s", h, 1.0, 0.1)])
    with pytest.raises(ValueError, match="rng"):
        sensors.measure(0, 0.1, [0.0, 0.0], 1)
    with pytest.raises(ValueError, match="step"):
        sensors.due(-1, 0.1)
    with pytest.raises(ValueError, match="state"):
        sensors.measure(0, 0.1, [0.0], np.random.default_rng(0))
