"""The moving-horizon estimator against independent references.

A numpy Kalman filter and Rauch–Tung–Striebel smoother on a linear system, the EKF on the
RexROV, ipopt on the window.
"""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.estimation.helpers import (
    DT,
    A,
    B,
    beacon_ocp,
    compass_ocp,
    linear_ocp,
    linear_sensors,
    rk4_linear,
)
from uuv_ocp.estimation import Estimator, EstimatorOptions, Measurement, MovingHorizonEstimator
from uuv_ocp.native.compile import CompilerNotFoundError, find_c_compiler

STATE_STD = np.array([0.01, 0.02])
PRIOR_STD = np.array([0.5, 0.3])
SENSOR_VAR = np.array([0.1**2, 0.05**2])  # linear_sensors(): position 10 Hz, velocity 5 Hz


def kalman_and_smoother(x0, controls, measurements):
    """Numpy Kalman filter over all steps and the RTS smoother of all of them (independent code)."""
    phi, gamma = rk4_linear(A, B, DT)
    Q = np.diag(STATE_STD**2)
    predicted, predicted_P, filtered, filtered_P = [], [], [], []
    x, P = np.asarray(x0, float), np.diag(PRIOR_STD**2)
    for k, measurement in enumerate(measurements):
        if k:
            x, P = phi @ x + gamma @ controls[k], phi @ P @ phi.T + Q
        predicted.append(x)
        predicted_P.append(P)
        rows = list(measurement.sensors)  # position is row 0, velocity row 1
        if rows:
            H = np.eye(2)[rows]
            S = H @ P @ H.T + np.diag(SENSOR_VAR[rows])
            K = P @ H.T @ np.linalg.inv(S)
            x = x + K @ (measurement.values - H @ x)
            P = (np.eye(2) - K @ H) @ P
        filtered.append(x)
        filtered_P.append(P)
    smoothed = [filtered[-1]]
    for k in reversed(range(len(measurements) - 1)):
        C = filtered_P[k] @ phi.T @ np.linalg.inv(predicted_P[k + 1])
        smoothed.insert(0, filtered[k] + C @ (smoothed[0] - predicted[k + 1]))
    return np.array(filtered), np.array(filtered_P), np.array(smoothed)


def linear_run(steps, seed=7):
    """Return the controls and the multi-rate, dropping measurements of the damped spring."""
    sensors = linear_sensors()
    rng = np.random.default_rng(seed)
    phi, gamma = rk4_linear(A, B, DT)
    truth = np.array([1.0, -0.5])
    controls, measurements = [], []
    for k in range(steps):
        u = np.array([np.sin(0.3 * k)])
        if k:
            truth = phi @ truth + gamma @ u + rng.normal(0, STATE_STD)
        controls.append(u)
        measurements.append(sensors.measure(k, DT, truth, rng))
    return controls, measurements


@pytest.mark.parametrize(("mode", "compiled"), [("full", False), ("rti", False), ("rti", True)])
def test_mhe_on_a_linear_ocp_equals_the_kalman_filter_and_the_rts_smoother(mode, compiled):
    """Window M = 5 over 40 steps: after the window is full its arrival cost carries the past."""
    horizon, steps = 5, 40
    options = EstimatorOptions(
        state_std=tuple(STATE_STD),
        initial_state_std=tuple(PRIOR_STD),
        horizon=horizon,
        mode=mode,
        compiled=compiled,
    )
    if compiled:
        try:
            find_c_compiler()
        except CompilerNotFoundError:
            pytest.skip("no C compiler")
    mhe = Estimator(linear_ocp(), "mhe", sensors=linear_sensors(), options=options)
    assert isinstance(mhe, MovingHorizonEstimator) and mhe.compiled == compiled
    start = np.array([1.3, -0.4])
    mhe.reset(start)
    controls, measurements = linear_run(steps)
    filtered, filtered_P, _ = kalman_and_smoother(start, controls, measurements)
    compared = 0
    for k, (u, measurement) in enumerate(zip(controls, measurements, strict=True)):
        estimate = mhe.correct(measurement) if k == 0 else mhe.step(u, measurement)
        np.testing.assert_allclose(estimate.state, filtered[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(estimate.covariance, filtered_P[k], rtol=0, atol=1e-10)
        window_steps, window = mhe.window
        assert window_steps[-1] == k and window_steps.size == min(k, horizon) + 1
        if k >= 2 * horizon and k % 3 == 0:  # the smoother over all data up to k, on the window
            _, _, smoothed = kalman_and_smoother(start, controls[: k + 1], measurements[: k + 1])
            np.testing.assert_allclose(window.T, smoothed[window_steps], rtol=0, atol=1e-9)
            compared += 1
    assert compared >= 8
    assert mhe.iterations == (1 if mode == "rti" else 2)  # the full solve confirms its one step


def test_mhe_innovations_are_the_kalman_filters():
    """The newest step's innovations and S are the Kalman filter's (what NIS uses)."""
    options = EstimatorOptions(state_std=tuple(STATE_STD), initial_state_std=tuple(PRIOR_STD), horizon=3)
    mhe = Estimator(linear_ocp(), "mhe", sensors=linear_sensors(), options=options)
    ekf = Estimator(linear_ocp(), "ekf", sensors=linear_sensors(), options=options)
    for estimator in (mhe, ekf):
        estimator.reset([1.3, -0.4])
    controls, measurements = linear_run(20, seed=3)
    for k, (u, measurement) in enumerate(zip(controls, measurements, strict=True)):
        ours = mhe.correct(measurement) if k == 0 else mhe.step(u, measurement)
        theirs = ekf.correct(measurement) if k == 0 else ekf.step(u, measurement)
        assert ours.sensors == theirs.sensors
        np.testing.assert_allclose(ours.innovations, theirs.innovations, rtol=0, atol=1e-10)
        np.testing.assert_allclose(
            ours.innovation_covariance, theirs.innovation_covariance, rtol=0, atol=1e-12
        )


def window_by_ipopt(mhe):
    """Solve the window's MHE problem, written out independently and solved by ipopt."""
    m = mhe.model
    steps, window = mhe.window
    L = steps.size - 1
    f = ca.Function("f", m.inputs, [m.f])
    h = ca.Function("h", [m.xa], [m.h])
    X = ca.SX.sym("X", m.size, L + 1)
    Qinv, Rinv = np.linalg.inv(m.Q), 1.0 / mhe.R
    deviation = X[:, 0] - mhe._prior
    cost = ca.bilin(ca.DM(mhe._prior_Pinv), deviation, deviation)
    first = mhe.horizon - L
    for i in range(L + 1):
        node = first + i
        rows = np.flatnonzero(mhe._W[:, node])
        if rows.size:
            y = ca.DM(mhe._Z[rows, node]) - h(X[:, i])[rows.tolist()]
            y = ca.vertcat(
                *[
                    ca.atan2(ca.sin(y[j]), ca.cos(y[j])) if mhe.angular[r] else y[j]
                    for j, r in enumerate(rows)
                ]
            )
            cost += ca.sumsqr(y * np.sqrt(Rinv[rows]))
        if i < L:
            w = X[:, i + 1] - f(X[:, i], mhe._U[:, node], m.p_stage, m.p_global)
            cost += ca.bilin(ca.DM(Qinv), w, w)
    solver = ca.nlpsol(
        "window",
        "ipopt",
        {"x": ca.vec(X), "f": cost},
        {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-10},
    )
    # started away from the MHE's answer (from it ipopt stops at once: search direction too small)
    start = window + np.random.default_rng(0).normal(0.0, 0.01, window.shape)
    solution = solver(x0=ca.vec(ca.DM(start)))
    assert solver.stats()["success"], solver.stats()["return_status"]
    return np.asarray(solution["x"]).reshape(m.size, L + 1, order="F")


@pytest.fixture(scope="module")
def rexrov_runs():
    """s2 (RexROV) under a constant unknown current: the full-solve MHE and the EKF, 20 s."""
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=10)
    x0, current = problem.reference.initial_state(0.0), uo.Current(0.5, 1.0)
    runs = {}
    for method in ("mhe", "ekf"):
        estimator = uo.Estimator(problem, method, sensors=uo.Sensors.auv(vehicle))
        runs[method] = (
            uo.simulate(
                uo.NMPC(problem, "sqp-rti"),
                x0=x0,
                duration=20.0,
                current=current,
                estimator=estimator,
                seed=1,
            ),
            estimator,
        )
    return runs


def test_mhe_on_the_rexrov_converges_the_unknown_current_as_the_ekf_does(rexrov_runs):
    true_current = 0.5 * np.array([np.cos(1.0), np.sin(1.0)])
    for method in ("mhe", "ekf"):
        run = rexrov_runs[method][0]
        assert run.fault is None
        np.testing.assert_allclose(run.currents[-1], true_current, atol=1e-12)
        # the estimated current after 20 s (the prior guessed zero, σ 0.5 m/s)
        assert np.linalg.norm(run.estimates.currents[-1] - true_current) < 0.02, method
        position_error = run.estimates.states[-50:, :2] - run.states[-51:-1, :2]
        assert np.sqrt(np.mean(position_error**2)) < 0.2, method  # USBL σ 0.5 m at 1 Hz
    mhe_current = rexrov_runs["mhe"][0].estimates.currents[-1]
    ekf_current = rexrov_runs["ekf"][0].estimates.currents[-1]
    assert np.linalg.norm(mhe_current - ekf_current) < 0.02


def test_the_full_solve_is_ipopts_minimiser_of_the_nonlinear_window(rexrov_runs):
    mhe = rexrov_runs["mhe"][1]
    assert mhe.options.mode == "full" and mhe.window[0].size == mhe.horizon + 1
    _, window = mhe.window
    np.testing.assert_allclose(window, window_by_ipopt(mhe), rtol=0, atol=1e-7)


def test_bad_mhe_options_are_named():
    for kwargs, name in [
        ({"horizon": 0}, "options.horizon"),
        ({"horizon": 2.5}, "options.horizon"),
        ({"mode": "fast"}, "options.mode"),
        ({"max_iterations": 0}, "options.max_iterations"),
        ({"tolerance": -1.0}, "options.tolerance"),
        ({"compiled": "yes"}, "options.compiled"),
    ]:
        with pytest.raises(ValueError, match=name):
            EstimatorOptions(**kwargs)
    mhe = Estimator(linear_ocp(), "mhe", sensors=linear_sensors(), options=EstimatorOptions(horizon=2))
    mhe.reset([0.0, 0.0])
    with pytest.raises(ValueError, match="measurement.values must have 2 entries"):
        mhe.correct(Measurement(0, (0, 1), np.zeros(1)))
    with pytest.raises(ValueError, match="u must"):
        mhe.predict([np.nan])
    with pytest.raises(ValueError, match="covariance must be positive definite for the MHE"):
        mhe.reset([0.0, 0.0], covariance=np.diag([1.0, 0.0]))


def test_heading_crossing_pi_many_times_equals_the_ekf():
    """A compass on a turning vehicle: every residual of the window and the arrival cost wrapped.

    ``h = atan2(sin ψ, cos ψ)`` has derivative 1 everywhere, so with wrapped residuals the
    model is linear-Gaussian and the MHE equals the EKF (which wraps its innovations).
    """
    ocp, sensors = compass_ocp(DT, rate_bound=2.0, std=0.05)
    options = EstimatorOptions(state_std=0.01, initial_state_std=0.1, horizon=3)
    mhe, ekf = (Estimator(ocp, method, sensors=sensors, options=options) for method in ("mhe", "ekf"))
    rng = np.random.default_rng(5)
    truth = 3.0
    for estimator in (mhe, ekf):
        estimator.reset([truth])
    crossings = 0
    for k in range(120):
        u = np.array([1.5])
        if k:
            crossings += int(
                np.floor((truth + np.pi) / (2 * np.pi)) != np.floor((truth + 0.15 + np.pi) / (2 * np.pi))
            )
            truth = truth + 0.15 + rng.normal(0.0, 0.01)
        measurement = sensors.measure(k, DT, np.array([truth]), rng)
        ours = mhe.correct(measurement) if k == 0 else mhe.step(u, measurement)
        theirs = ekf.correct(measurement) if k == 0 else ekf.step(u, measurement)
        np.testing.assert_allclose(ours.state, theirs.state, rtol=0, atol=1e-9)
    assert crossings >= 2


def beacon_problem() -> tuple[uo.Ocp, uo.Sensors]:
    """``ẋ = u`` in the plane: a position fix at 10 Hz and a range to a beacon at the origin at 1 Hz.

    The range ``sqrt(x² + y²)`` has no Jacobian at the beacon (0/0: NaN).
    """
    ocp, _, beacon_range = beacon_ocp()
    sensors = uo.Sensors(
        [uo.Sensor.of_states("position", [0, 1], 2, 10.0, 0.1), uo.Sensor("range", beacon_range, 1.0, 0.1)]
    )
    return ocp, sensors


@pytest.mark.parametrize(("mode", "compiled"), [("full", False), ("rti", False), ("rti", True)])
def test_a_silent_sensor_undefined_at_the_estimate_does_not_poison_the_mhe(mode, compiled):
    """Only the position fix reports; the range's NaN Jacobian at the beacon must not enter.

    The estimate sits exactly at the beacon for the first steps (zero fixes, zero controls): every
    window node and the arrival cost's linearisation point are at the origin.  The model and the
    position fix are linear, so the MHE equals the EKF's ``predict`` then ``correct``, which uses
    the reporting rows only (an independent reference).
    """
    if compiled:
        try:
            find_c_compiler()
        except CompilerNotFoundError:
            pytest.skip("no C compiler")
    ocp, sensors = beacon_problem()
    options = EstimatorOptions(horizon=2, mode=mode, compiled=compiled)
    mhe = Estimator(ocp, "mhe", sensors=sensors, options=options)
    ekf = Estimator(ocp, "ekf", sensors=sensors, options=EstimatorOptions(compiled=False))
    for estimator in (mhe, ekf):
        estimator.reset([0.0, 0.0])
    rng = np.random.default_rng(3)
    for k in range(1, 10):
        fix = np.zeros(2) if k < 6 else rng.normal(0.0, 0.1, 2)  # at the beacon, then off it
        measurement = Measurement(k, (0,), fix)
        ours = mhe.step(np.zeros(2), measurement)
        ekf.predict(np.zeros(2))
        theirs = ekf.correct(measurement)
        assert np.isfinite(ours.state).all() and np.isfinite(ours.covariance).all()
        np.testing.assert_allclose(ours.state, theirs.state, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours.covariance, theirs.covariance, rtol=0, atol=1e-12)
    assert mhe.window[0].size == 3  # the window slid: the arrival cost was updated at the beacon


@pytest.mark.parametrize("mode", ["full", "rti"])
def test_a_reporting_sensor_undefined_at_the_estimate_does_not_move_the_mhe(mode):
    """The range reports while the estimate sits on its beacon: no Gauss–Newton direction exists.

    The range's Jacobian at the beacon is 0/0 on a reporting row (no mask can remove it), so the
    step is NaN.  The solve must not move: the estimate stays the prediction (the EKF's
    ``predict``).  While that node is in the window no solve can move; when it leaves, its range is
    dropped from the arrival cost, and the model and the position fix being linear, the MHE then
    equals the EKF that was given the position fixes only (an independent reference).
    """
    ocp, sensors = beacon_problem()
    mhe = Estimator(ocp, "mhe", sensors=sensors, options=EstimatorOptions(horizon=2, mode=mode))
    ekf = Estimator(ocp, "ekf", sensors=sensors, options=EstimatorOptions(compiled=False))
    for estimator in (mhe, ekf):
        estimator.reset([0.0, 0.0])
    predicted = Estimator(ocp, "ekf", sensors=sensors, options=EstimatorOptions(compiled=False))
    predicted.reset([0.0, 0.0])
    predicted.predict(np.zeros(2))
    ours = mhe.step(np.zeros(2), Measurement(1, (0, 1), np.zeros(3)))  # at the beacon: range 0
    np.testing.assert_array_equal(ours.state, predicted.x)
    np.testing.assert_allclose(ours.covariance, predicted.P, rtol=0, atol=1e-15)
    ekf.predict(np.zeros(2))
    ekf.correct(Measurement(1, (0,), np.zeros(2)))
    rng = np.random.default_rng(4)
    for k in range(2, 9):
        measurement = Measurement(k, (0,), rng.normal(0.0, 0.1, 2))
        ours = mhe.step(np.zeros(2), measurement)
        ekf.predict(np.zeros(2))
        theirs = ekf.correct(measurement)
        assert np.isfinite(ours.state).all() and np.isfinite(ours.covariance).all()
        if mhe.window[0][0] > 1:  # step 1's node has left the window
            np.testing.assert_allclose(ours.state, theirs.state, rtol=0, atol=1e-12)
            np.testing.assert_allclose(ours.covariance, theirs.covariance, rtol=0, atol=1e-12)
    assert mhe.window[0][0] > 1


def test_the_full_solve_does_not_move_when_no_step_decreases_the_cost():
    """Armijo failing down to the smallest step: the window keeps its iterate.

    No smooth window makes Gauss–Newton's descent direction fail at every step length, so the
    cost the line search sees is raised by 1e6 (the cost at the iterate, from the Gauss–Newton
    Function, is not): every trial fails.  The window must then stay the prediction exactly.
    """
    mhe = Estimator(linear_ocp(), "mhe", sensors=linear_sensors(), options=EstimatorOptions(horizon=3))
    mhe.reset([1.0, 0.0])
    true_cost = mhe._cost
    trials = []

    def raised(*arguments):
        trials.append(1)
        (cost,) = true_cost(*arguments)
        return (cost + 1e6,)

    mhe._cost = raised
    predicted = Estimator(
        linear_ocp(), "ekf", sensors=linear_sensors(), options=EstimatorOptions(compiled=False)
    )
    predicted.reset([1.0, 0.0])
    predicted.predict([0.5])
    estimate = mhe.step([0.5], Measurement(1, (0,), np.array([1.2])))
    assert len(trials) > 20  # the line search ran down to its smallest step
    np.testing.assert_array_equal(estimate.state, predicted.x)
    assert mhe.iterations == 1
