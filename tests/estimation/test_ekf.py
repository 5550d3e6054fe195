"""The EKF (uuv_ocp.estimation.ekf): a numpy Kalman filter on a linear Ocp, compiled = VM, NaN masks."""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from tests.estimation.helpers import (
    DT,
    A,
    B,
    beacon_ocp,
    linear_ocp,
    linear_sensors,
    rk4_linear,
)
from uuv_ocp.estimation import Estimator, EstimatorOptions, Measurement, Sensor, Sensors


def test_ekf_on_a_linear_ocp_equals_a_numpy_kalman_filter():
    problem, sensors = linear_ocp(), linear_sensors()
    options = EstimatorOptions(state_std=(0.01, 0.02), initial_state_std=(0.5, 0.3))
    ekf = Estimator(problem, "ekf", sensors=sensors, options=options)
    x0 = np.array([1.0, -0.5])
    ekf.reset(x0 + [0.3, 0.1])
    rng = np.random.default_rng(7)
    phi, gamma = rk4_linear(A, B, DT)
    Q, R = np.diag([0.01**2, 0.02**2]), np.array([0.1**2, 0.05**2])
    H_all = np.eye(2)
    x_ref, P_ref = x0 + [0.3, 0.1], np.diag([0.5**2, 0.3**2])
    truth = x0.copy()
    used = 0
    for k in range(60):
        u = np.array([np.sin(0.3 * k)])
        if k:
            truth = phi @ truth + gamma @ u + rng.normal(0, [0.01, 0.02])
            x_ref, P_ref = phi @ x_ref + gamma @ u, phi @ P_ref @ phi.T + Q
        measurement = sensors.measure(k, DT, truth, rng)
        estimate = ekf.correct(measurement) if k == 0 else ekf.step(u, measurement)
        rows = list(measurement.sensors)  # position is row 0, velocity row 1
        if rows:
            H = H_all[rows]
            S = H @ P_ref @ H.T + np.diag(R[rows])
            K = P_ref @ H.T @ np.linalg.inv(S)
            x_ref = x_ref + K @ (measurement.values - H @ x_ref)
            P_ref = (np.eye(2) - K @ H) @ P_ref
            used += len(rows)
        np.testing.assert_allclose(estimate.state, x_ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(estimate.covariance, P_ref, rtol=0, atol=1e-10)
    assert used > 60  # the velocity sensor reported at some steps and dropped out at others


@needs_compiler
def test_the_compiled_ekf_step_equals_the_virtual_machines():
    """The one-call step compiled to C (the default where a compiler exists) is the VM's, to rounding."""
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=5)
    sensors = uo.Sensors.auv(vehicle)
    filters = [
        uo.Estimator(problem, "ekf", sensors=sensors, options=EstimatorOptions(compiled=compiled))
        for compiled in (True, False)
    ]
    assert [f.compiled for f in filters] == [True, False]
    x0 = problem.reference.initial_state(0.0)
    rng = np.random.default_rng(3)
    for ekf in filters:
        ekf.reset(x0)
    for k in range(60):
        measurement = sensors.measure(k, problem.dt, x0 + 0.01 * k, rng)
        u = rng.normal(0.0, 100.0, 3)
        compiled, interpreted = (ekf.step(u, measurement) for ekf in filters)
        np.testing.assert_allclose(compiled.augmented, interpreted.augmented, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(compiled.covariance, interpreted.covariance, rtol=1e-10, atol=1e-14)
    with pytest.raises(ValueError, match="options.compiled"):
        EstimatorOptions(compiled="yes")


def test_a_sensor_that_did_not_report_never_poisons_the_ekf():
    """A range to a beacon is undefined (NaN Jacobian) at the beacon.

    When it did not report, the one-call step equals predict-then-correct on the reporting rows,
    which never touch it.
    """
    ocp, at, beacon_range = beacon_ocp()
    # and a signal strength ∝ 1/range, infinite there (its innovation is too)
    strength = ca.Function("strength", [at], [1.0 / ca.sqrt(at[0] ** 2 + at[1] ** 2)])
    fix = Sensor.of_states("fix", [0, 1], 2, 10.0, 0.1)
    sensors = Sensors([fix, Sensor("range", beacon_range, 1.0, 0.1), Sensor("strength", strength, 1.0, 0.1)])
    options = EstimatorOptions(compiled=False)
    fused, split = (Estimator(ocp, "ekf", sensors=sensors, options=options) for _ in range(2))
    for ekf in (fused, split):
        ekf.reset([0.0, 0.0])
    measurement = Measurement(1, (0,), np.array([0.01, -0.02]))  # the fix only, at the beacon
    one_call = fused.step([0.0, 0.0], measurement)
    split.predict([0.0, 0.0])
    reference = split.correct(measurement)
    assert np.all(np.isfinite(one_call.augmented)) and np.all(np.isfinite(one_call.covariance))
    np.testing.assert_allclose(one_call.augmented, reference.augmented, atol=1e-12)
    np.testing.assert_allclose(one_call.covariance, reference.covariance, atol=1e-12)


def test_per_axis_current_noise_gives_the_analytic_kalman_steady_state():
    """A current of different intensity per axis settles where the discrete Riccati equation says.

    A point moved by its control and a 2-D current, ``ṗ = u + c``, a position fix every step:
    the augmented model is linear, so the EKF's covariance must reach scipy's solution of the
    discrete algebraic Riccati equation for ``Q = diag(σ_p², σ_p², q_1² dt, q_2² dt)``, axis by
    axis; the quieter axis's current variance (and its gain: the estimate's bandwidth) is smaller.
    """
    from scipy.linalg import solve_discrete_are

    dt, position_std, fix_std, intensities = 0.5, 1e-3, 0.5, (0.01, 1e-4)
    ocp = uo.Ocp(horizon=3, dt=dt)
    p = ocp.state("p", 2)
    u = ocp.control("u", 2, lower=-1.0, upper=1.0)
    current = ocp.parameter("current", 2, stagewise=True)
    ocp.set_der(p, u + current)
    ocp.add_stage_cost(residual=p, weight=(1.0, 1.0))
    sensors = Sensors([Sensor.of_states("fix", [0, 1], 2, 1.0 / dt, fix_std)])
    options = EstimatorOptions(state_std=position_std, current_std=intensities, compiled=False)
    ekf = Estimator(ocp, "ekf", sensors=sensors, options=options, parameters={"current": (0.0, 0.0)})
    ekf.reset(np.zeros(2))
    rng = np.random.default_rng(3)
    for k in range(1, 4000):  # the covariance does not depend on the data: any fixes do
        ekf.step(np.zeros(2), sensors.measure(k, dt, np.zeros(2), rng))
    for axis, q in enumerate(intensities):
        # one axis: [p, c], p⁺ = p + dt c (RK4 is exact on it), c⁺ = c
        F = np.array([[1.0, dt], [0.0, 1.0]])
        H = np.array([[1.0, 0.0]])
        Q = np.diag([position_std**2, q**2 * dt])
        prior = solve_discrete_are(F.T, H.T, Q, np.array([[fix_std**2]]))
        gain = prior @ H.T / (H @ prior @ H.T + fix_std**2)
        posterior = (np.eye(2) - gain @ H) @ prior
        rows = [axis, 2 + axis]
        np.testing.assert_allclose(ekf.P[np.ix_(rows, rows)], posterior, rtol=1e-6, atol=1e-14)
    assert ekf.P[3, 3] < 0.05 * ekf.P[2, 2]
    with pytest.raises(ValueError, match=r"options.current_std must have shape \(2,\)"):
        Estimator(
            ocp,
            "ekf",
            sensors=sensors,
            options=EstimatorOptions(current_std=(0.01, 0.01, 0.01)),
            parameters={"current": (0.0, 0.0)},
        )
    with pytest.raises(ValueError, match="options.current_std must be a finite number > 0"):
        EstimatorOptions(current_std=0.0)
