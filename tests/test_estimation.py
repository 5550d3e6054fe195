"""Estimators against independent references: a numpy Kalman filter, filterpy's UKF, NEES."""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.estimation import Estimator, EstimatorOptions, Measurement, Sensor, Sensors

DT = 0.1
A = np.array([[0.0, 1.0], [-1.0, -0.4]])
B = np.array([[0.0], [1.0]])


def linear_ocp() -> uo.Ocp:
    """``ẋ = A x + B u``: position and velocity of a damped spring, force input."""
    ocp = uo.Ocp(horizon=5, dt=DT)
    x = ocp.state("x", 2)
    u = ocp.control("u", 1, lower=-10.0, upper=10.0)
    ocp.set_der(x, ca.DM(A) @ x + ca.DM(B) @ u)
    ocp.add_stage_cost(residual=x, weight=(1.0, 1.0))
    return ocp


def rk4_linear(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step of ``ẋ = a x + b u`` (u held) as ``x⁺ = Φ x + Γ u``: its Taylor polynomial."""
    n = a.shape[0]
    ah = a * h
    phi = np.eye(n) + ah + ah @ ah / 2 + ah @ ah @ ah / 6 + ah @ ah @ ah @ ah / 24
    gamma = (np.eye(n) * h + ah * h / 2 + ah @ ah * h / 6 + ah @ ah @ ah * h / 24) @ b
    return phi, gamma


def linear_sensors() -> Sensors:
    return Sensors(
        [
            Sensor.of_states("position", [0], 2, 10.0, 0.1),
            Sensor.of_states("velocity", [1], 2, 5.0, 0.05, dropout=0.2),
        ]
    )


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


def pendulum_ocp() -> uo.Ocp:
    ocp = uo.Ocp(horizon=5, dt=DT)
    x = ocp.state("x", 2)
    u = ocp.control("u", 1, lower=-5.0, upper=5.0)
    ocp.set_der(x, ca.vertcat(x[1], -ca.sin(x[0]) - 0.2 * x[1] + u))
    ocp.add_stage_cost(residual=x, weight=(1.0, 1.0))
    return ocp


def pendulum_rk4(x: np.ndarray, u: float) -> np.ndarray:
    def f(s):
        return np.array([s[1], -np.sin(s[0]) - 0.2 * s[1] + u])

    k1 = f(x)
    k2 = f(x + DT / 2 * k1)
    k3 = f(x + DT / 2 * k2)
    k4 = f(x + DT * k3)
    return x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def test_ukf_on_a_nonlinear_example_equals_filterpy():
    filterpy = pytest.importorskip("filterpy.kalman")
    x = ca.SX.sym("x", 2)
    # a nonlinear scalar measurement of the pendulum's angle
    sensors = Sensors([Sensor("sine", ca.Function("h", [x], [ca.sin(x[0]) + 0.1 * x[0] ** 3]), 10.0, 0.05)])
    alpha, beta, kappa = 0.5, 2.0, 1.0
    options = EstimatorOptions(
        state_std=(0.02, 0.05), initial_state_std=(0.4, 0.3), alpha=alpha, beta=beta, kappa=kappa
    )
    ukf = Estimator(pendulum_ocp(), "ukf", sensors=sensors, options=options)
    start = np.array([0.8, 0.0])
    ukf.reset(start)

    control = {"u": 0.0}
    points = filterpy.MerweScaledSigmaPoints(2, alpha=alpha, beta=beta, kappa=kappa)
    reference = filterpy.UnscentedKalmanFilter(
        dim_x=2,
        dim_z=1,
        dt=DT,
        hx=lambda s: np.array([np.sin(s[0]) + 0.1 * s[0] ** 3]),
        fx=lambda s, _dt: pendulum_rk4(s, control["u"]),
        points=points,
    )
    reference.x, reference.P = start.copy(), np.diag([0.4**2, 0.3**2])
    reference.Q, reference.R = np.diag([0.02**2, 0.05**2]), np.array([[0.05**2]])
    rng = np.random.default_rng(3)
    truth = np.array([1.0, 0.3])
    for k in range(40):
        u = 0.5 * np.cos(0.2 * k)
        control["u"] = u
        truth = pendulum_rk4(truth, u)
        z = np.sin(truth[0]) + 0.1 * truth[0] ** 3 + 0.05 * rng.standard_normal()
        reported = k % 3 != 2  # some steps without a measurement
        measurement = Measurement(k + 1, (0,) if reported else (), np.array([z]) if reported else np.zeros(0))
        estimate = ukf.step(np.array([u]), measurement)
        reference.predict()
        if reported:
            reference.update(np.array([z]))
        np.testing.assert_allclose(estimate.state, reference.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(estimate.covariance, reference.P, rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_nees_and_nis_over_seeded_runs_lie_in_their_chi_square_bands(method):
    """Over 50 seeded runs of the linear system the mean NEES and NIS are χ²-consistent."""
    chi2 = pytest.importorskip("scipy.stats").chi2
    problem, sensors = linear_ocp(), linear_sensors()
    std = np.array([0.01, 0.02])
    options = EstimatorOptions(state_std=tuple(std), initial_state_std=(0.5, 0.3))
    estimator = Estimator(problem, method, sensors=sensors, options=options)
    phi, gamma = rk4_linear(A, B, DT)
    runs, steps = 50, 40
    nees = np.zeros(runs)
    nis, nis_dof = 0.0, 0
    for run in range(runs):
        rng = np.random.default_rng(100 + run)
        truth = np.array([1.0, -0.5]) + rng.normal(0, [0.5, 0.3])
        estimator.reset([1.0, -0.5])
        for k in range(steps):
            u = np.array([np.sin(0.3 * k)])
            if k:
                truth = phi @ truth + gamma @ u + rng.normal(0, std)
            measurement = sensors.measure(k, DT, truth, rng)
            estimate = estimator.correct(measurement) if k == 0 else estimator.step(u, measurement)
            y, S = estimate.innovations, estimate.innovation_covariance
            if y.size:
                nis += float(y @ np.linalg.solve(S, y))
                nis_dof += y.size
        error = truth - estimate.state
        nees[run] = error @ np.linalg.solve(estimate.covariance, error)
    low, high = chi2.ppf([0.025, 0.975], 2 * runs) / runs
    assert low <= nees.mean() <= high
    low, high = chi2.ppf([0.025, 0.975], nis_dof) / nis_dof
    assert low <= nis / nis_dof <= high


def test_estimator_by_name_and_bad_inputs_name_the_parameter():
    problem, sensors = linear_ocp(), linear_sensors()
    assert type(Estimator(problem, "ekf", sensors=sensors)).__name__ == "ExtendedKalmanFilter"
    assert type(Estimator(problem, "UKF", sensors=sensors)).__name__ == "UnscentedKalmanFilter"
    assert set(uo.available_estimators()) >= {"ekf", "ukf"}
    with pytest.raises(ValueError, match="method must be one of"):
        Estimator(problem, "kalman", sensors=sensors)
    with pytest.raises(ValueError, match="sensors must be a uuv_ocp.Sensors"):
        Estimator(problem, "ekf", sensors=[1])
    with pytest.raises(ValueError, match="sensors must measure the problem's 2 states"):
        Estimator(problem, "ekf", sensors=Sensors([Sensor.of_states("p", [0], 3, 1.0, 0.1)]))
    with pytest.raises(ValueError, match="options.current_model"):
        EstimatorOptions(current_model="brownian")
    with pytest.raises(ValueError, match="options.alpha"):
        EstimatorOptions(alpha=2.0)
    with pytest.raises(ValueError, match="options.state_std"):
        Estimator(problem, "ekf", sensors=sensors, options=EstimatorOptions(state_std=(0.1, -1.0)))
    estimator = Estimator(problem, "ekf", sensors=sensors)
    with pytest.raises(ValueError, match="x0 must have shape"):
        estimator.reset([1.0])
    estimator.reset([1.0, 0.0])
    with pytest.raises(ValueError, match="u must"):
        estimator.predict([np.nan])
    with pytest.raises(ValueError, match="measurement.values must have 2 entries"):
        estimator.correct(Measurement(0, (0, 1), np.zeros(1)))


def test_tracking_problem_state_is_augmented_with_the_layout_current():
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=5)
    estimator = Estimator(problem, "ekf", sensors=Sensors.auv(vehicle), options=EstimatorOptions(bias=True))
    assert estimator.model.nc == vehicle.layout.current_dim == 2
    assert estimator.model.size == 6 + 2 + 3
    estimator.reset(np.zeros(6), current=[0.1, -0.2])
    estimate = estimator.estimate()
    np.testing.assert_array_equal(estimate.current, [0.1, -0.2])
    assert estimate.bias.shape == (3,)
