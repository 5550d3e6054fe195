"""The UKF (uuv_ocp.estimation.ukf) against filterpy's UnscentedKalmanFilter; its square root."""

import casadi as ca
import numpy as np
import pytest

from tests.estimation.helpers import (
    DT,
    pendulum_ocp,
    pendulum_rk4,
)
from uuv_ocp.estimation import Estimator, EstimatorOptions, Measurement, Sensor, Sensors


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


def test_ukf_square_root_survives_a_sensor_far_more_precise_than_the_prior():
    from uuv_ocp.estimation.ukf import _square_root

    vectors = np.linalg.qr(np.random.default_rng(0).normal(size=(4, 4)))[0]
    broken = vectors @ np.diag([1e6, 1.0, 1e-6, -1e-10]) @ vectors.T  # lost definiteness to rounding
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(broken)
    root = _square_root(broken)
    np.testing.assert_allclose(root @ root.T, vectors @ np.diag([1e6, 1.0, 1e-6, 0.0]) @ vectors.T, atol=1e-8)
