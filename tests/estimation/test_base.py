"""The Estimator API (uuv_ocp.estimation.base) over every registered estimator: NEES/NIS, offset-free NMPC.

Registry-wide tests (a new estimator is tested by registering it), the closed loop with an
estimator against the naive controller, bad inputs, refused steps and resets.
"""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.estimation.helpers import DT, A, B, compass_ocp, linear_ocp, linear_sensors, rk4_linear
from uuv_ocp.estimation import Estimator, EstimatorOptions, Measurement, Sensor, Sensors


@pytest.mark.parametrize("method", uo.available_estimators())  # every registered estimator
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
    assert type(Estimator(problem, "mhe", sensors=sensors)).__name__ == "MovingHorizonEstimator"
    assert set(uo.available_estimators()) >= {"ekf", "ukf", "mhe"}
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


def _precise_sensors():
    """Precise sensors, so that the estimate's own noise (not the offset) is far below the naive offset."""
    return uo.Sensors(
        [
            uo.Sensor.of_states("pose", [0, 1, 2], 6, 10.0, (1e-3, 1e-3, 5e-4), angular=(False, False, True)),
            uo.Sensor.of_states("dvl", [3, 4, 5], 6, 10.0, (1e-3, 1e-3, 5e-4)),
        ]
    )


@pytest.fixture(scope="module")
def offset_runs():
    """s2 (RexROV) under a constant current of 0.8 m/s unknown to the controller: EKF vs naive."""
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=10)
    sensors = _precise_sensors()
    x0, current = problem.reference.initial_state(0.0), uo.Current(0.8, 1.0)
    estimator = uo.Estimator(problem, "ekf", sensors=sensors)
    common = dict(x0=x0, duration=30.0, current=current, seed=1)
    estimated = uo.simulate(uo.NMPC(problem, "sqp-rti"), estimator=estimator, **common)
    naive = uo.simulate(uo.NMPC(problem, "sqp-rti"), current_known=False, **common)
    return estimated, naive


def test_an_estimator_that_models_no_current_leaves_the_controller_naive(offset_runs):
    estimated, naive = offset_runs
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=10)
    options = uo.EstimatorOptions(current_model="none")
    blind = uo.Estimator(problem, "ekf", sensors=_precise_sensors(), options=options)
    assert blind.model.nc == 0 and blind.model.size == 6
    run = uo.simulate(
        uo.NMPC(problem, "sqp-rti"),
        x0=problem.reference.initial_state(0.0),
        duration=30.0,
        current=uo.Current(0.8, 1.0),
        seed=1,
        estimator=blind,
    )
    assert run.estimates.currents.shape == (run.controls.shape[0], 0)
    offset = np.linalg.norm(run.errors[-100:].mean(axis=0))
    naive_offset = np.linalg.norm(naive.errors[-100:].mean(axis=0))
    # on estimated states the controller keeps the naive controller's offset (the filter takes
    # the current's push for process noise), ten times what the current-estimating loop leaves
    assert offset > 0.5 * naive_offset
    assert offset > 10 * np.linalg.norm(estimated.errors[-100:].mean(axis=0))


def test_offset_free_nmpc_with_the_ekf_removes_the_naive_controllers_offset(offset_runs):
    estimated, naive = offset_runs
    # the mean position error over the last 10 s: the offset (the noise averages out)
    offset = np.linalg.norm(estimated.errors[-100:].mean(axis=0))
    naive_offset = np.linalg.norm(naive.errors[-100:].mean(axis=0))
    assert naive_offset > 5e-3
    assert offset < 1e-3 and offset < naive_offset / 10
    # the controller was told the estimated current, which converged to the true one
    np.testing.assert_allclose(estimated.estimates.currents[-1], estimated.currents[-1], atol=0.01)
    assert naive.estimates is None and naive.measurements is None


def test_a_run_records_its_estimates_and_measurements_and_saves_them(offset_runs, tmp_path):
    run = offset_runs[0]
    n = run.controls.shape[0]
    estimates, measurements = run.estimates, run.measurements
    assert estimates.states.shape == (n, 6) and estimates.currents.shape == (n, 2)
    assert estimates.variances.shape == (n, 8) and np.all(estimates.variances > 0)
    assert measurements.sensors == ("pose", "dvl") and measurements.sizes == (3, 3)
    assert measurements.values.shape == (n, 6) and np.all(np.isfinite(measurements.values))
    # the estimate the controller got at step 0 is the reset state corrected by the first fixes
    assert np.linalg.norm(estimates.states[0] - run.states[0]) < 0.01
    run.save(tmp_path / "run.npz")
    loaded = uo.ClosedLoopResult.load(tmp_path / "run.npz")
    for field in uo.ClosedLoopResult.ESTIMATION_FIELDS:
        np.testing.assert_array_equal(getattr(loaded, field), getattr(run, field))
    assert loaded.measurements.sensors == ("pose", "dvl") and loaded.measurements.sizes == (3, 3)


def test_simulate_refuses_bad_estimation_arguments_by_name(offset_runs):
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=5)
    mpc = uo.NMPC(problem, "sqp-rti")
    x0 = problem.reference.initial_state(0.0)
    sensors = uo.Sensors.auv(vehicle)
    estimator = uo.Estimator(problem, "ekf", sensors=sensors)
    with pytest.raises(ValueError, match="estimator must be a uuv_ocp.Estimator"):
        uo.simulate(mpc, x0, 1.0, estimator="ekf")
    with pytest.raises(ValueError, match="sensors needs an estimator"):
        uo.simulate(mpc, x0, 1.0, sensors=sensors)
    with pytest.raises(ValueError, match="noise is the full-state noise"):
        uo.simulate(mpc, x0, 1.0, estimator=estimator, noise=uo.MeasurementNoise((0.1,) * 6))
    with pytest.raises(ValueError, match="sensors must be the estimator's own"):
        uo.simulate(mpc, x0, 1.0, estimator=estimator, sensors=uo.Sensors(list(sensors)[:2]))
    other = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=6)
    with pytest.raises(ValueError, match="estimator must be built on the controller's problem"):
        uo.simulate(mpc, x0, 1.0, estimator=uo.Estimator(other, "ekf", sensors=sensors))


@pytest.mark.parametrize("method", uo.available_estimators())  # every registered estimator
def test_heading_innovations_are_wrapped_across_pi(method):
    """A heading of π − 0.005 measured as −π + 0.005: an innovation of 0.01 rad, not −2π."""
    # a compass reports the heading wrapped into (−π, π]: the sigma points straddle ±π
    ocp, sensors = compass_ocp(DT, rate_bound=1.0, std=0.01)
    estimator = Estimator(ocp, method, sensors=sensors, options=EstimatorOptions(initial_state_std=0.02))
    for use_step in (False, True):
        estimator.reset([np.pi - 0.005])
        measurement = Measurement(1, (0,), np.array([-np.pi + 0.005]))
        estimate = estimator.step([0.0], measurement) if use_step else estimator.correct(measurement)
        np.testing.assert_allclose(estimate.innovations, [0.01], atol=1e-6)
        assert abs(np.angle(np.exp(1j * (estimate.state[0] - np.pi)))) < 0.006


def test_closed_loop_on_a_user_ocp_runs_on_the_estimate():
    """An Ocp without a current: the controller gets the EKF's state, which follows the plant."""
    problem = linear_ocp()
    estimator = Estimator(problem, "ekf", sensors=linear_sensors())
    run = uo.simulate(uo.NMPC(problem, "ipopt"), x0=[1.0, 0.0], duration=3.0, estimator=estimator, seed=2)
    n = run.controls.shape[0]
    assert run.fault is None and n == 30
    assert run.estimates.currents.shape == (n, 0)
    error = run.estimates.states - run.states[:n]
    assert np.sqrt(np.mean(error**2)) < 0.1  # sensors of 0.1 and 0.05 σ
    # the position sensor reports at every step, the velocity one at 5 Hz when it does not drop out
    assert np.all(np.isfinite(run.measurements.values[:, 0]))
    assert np.all(np.isnan(run.measurements.values[1::2, 1]))


def test_review_fixes_name_what_is_wrong():
    """A misspelt current parameter, a method another class implements, and PSD rounding."""
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5)
    sensors = Sensors.auv(problem.vehicle)
    with pytest.raises(ValueError, match="options.current_parameter must name a stagewise parameter"):
        Estimator(problem, "ekf", sensors=sensors, options=EstimatorOptions(current_parameter="curent"))
    from uuv_ocp.estimation.ekf import ExtendedKalmanFilter

    with pytest.raises(ValueError, match="method 'ukf' names UnscentedKalmanFilter"):
        ExtendedKalmanFilter(problem, "ukf", sensors=sensors)
    estimator = Estimator(problem, "ekf", sensors=sensors)
    estimator.reset(problem.initial_state())
    covariance = estimator.P.copy()
    covariance[0, 0] = -1e-18  # rounding below zero on a PSD matrix: accepted
    estimator.reset(problem.initial_state(), covariance=covariance)
    covariance[0, 0] = -1e-3
    with pytest.raises(ValueError, match="covariance must be symmetric positive semi-definite"):
        estimator.reset(problem.initial_state(), covariance=covariance)


def _drifting_integrator(horizon: int, dt: float) -> tuple[uo.Ocp, Sensors]:
    """``ẋ = u + current`` (a stagewise current parameter) and a 10 Hz fix of ``x``."""
    ocp = uo.Ocp(horizon=horizon, dt=dt)
    x = ocp.state("x")
    u = ocp.control("u", lower=-1.0, upper=1.0)
    current = ocp.parameter("current", stagewise=True)
    ocp.set_der(x, u + current)
    ocp.add_stage_cost(x**2 + u**2)
    return ocp, Sensors([Sensor.of_states("fix", [0], 1, 10.0, 0.01)])


def test_an_estimated_current_the_loop_cannot_hand_over_is_refused():
    ocp, sensors = _drifting_integrator(horizon=5, dt=0.1)
    estimator = Estimator(ocp, "ekf", sensors=sensors, parameters={"current": 0.0})
    assert estimator.model.nc == 1
    with pytest.raises(ValueError, match="estimator estimates a current of 1 entries"):
        uo.simulate(uo.NMPC(ocp, "ipopt"), [1.0], 1.0, estimator=estimator, parameters={"current": 0.0})


def estimator_state(estimator):
    """Everything a refused call must leave as it was: mean, covariance, steps (the MHE: window)."""
    state = [estimator.x.copy(), estimator.P.copy(), estimator.steps]
    if hasattr(estimator, "window"):
        steps, window = estimator.window
        state += [steps, window]
    return state


def assert_same_state(before, after):
    assert len(before) == len(after)
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", uo.available_estimators())  # every registered estimator
def test_a_refused_step_leaves_the_estimator_as_it_was(method):
    """A measurement that does not fit is refused before the prediction moves anything.

    The estimator that refused it then steps exactly as a twin that never saw the call.
    """
    options = EstimatorOptions(horizon=3)
    estimator, twin = (
        Estimator(linear_ocp(), method, sensors=linear_sensors(), options=options) for _ in "ab"
    )
    for e in (estimator, twin):
        e.reset([1.0, 0.0])
        for k in range(1, 3):  # a window holding data
            e.step([0.5], Measurement(k, (0,), np.array([1.0 + 0.1 * k])))
    before = estimator_state(estimator)
    for bad in (Measurement(3, (0, 1), np.zeros(1)), "not a measurement"):
        with pytest.raises(ValueError, match="measurement"):
            estimator.step([0.5], bad)
        assert_same_state(before, estimator_state(estimator))
    good = Measurement(3, (0, 1), np.array([1.3, 0.2]))
    ours, theirs = estimator.step([0.5], good), twin.step([0.5], good)
    np.testing.assert_array_equal(ours.state, theirs.state)
    np.testing.assert_array_equal(ours.covariance, theirs.covariance)


@pytest.mark.parametrize("method", uo.available_estimators())  # every registered estimator
def test_a_refused_reset_leaves_the_estimator_as_it_was(method):
    """A covariance the estimator cannot start from is refused before anything is assigned.

    Indefinite: every estimator refuses it; semi-definite: the MHE (its arrival cost is P⁻¹).
    The estimator that refused the reset then steps exactly as a twin that never saw the call.
    """
    options = EstimatorOptions(horizon=3)
    estimator, twin = (
        Estimator(linear_ocp(), method, sensors=linear_sensors(), options=options) for _ in "ab"
    )
    for e in (estimator, twin):
        e.reset([1.0, 0.0])
        for k in range(1, 6):  # a full window, its arrival cost updated
            e.step([0.5], Measurement(k, (0,), np.array([1.0 + 0.1 * k])))
    before = estimator_state(estimator)
    refused = [np.diag([1.0, -1.0])] + ([np.diag([1.0, 0.0])] if method == "mhe" else [])
    for covariance in refused:
        with pytest.raises(ValueError, match="covariance must be"):
            estimator.reset([5.0, 5.0], covariance=covariance)
        assert_same_state(before, estimator_state(estimator))
    good = Measurement(6, (0, 1), np.array([1.3, 0.2]))
    ours, theirs = estimator.step([0.5], good), twin.step([0.5], good)
    np.testing.assert_array_equal(ours.state, theirs.state)
    np.testing.assert_array_equal(ours.covariance, theirs.covariance)


def test_an_estimator_of_a_thruster_vehicle_predicts_with_healthy_thrusters():
    # the estimator's model is the problem's step at fixed parameters: a thruster vehicle's
    # health must be its default 1 there (zeros would leave the thrusters out of the model);
    # reference: RK4 of the force model with τ = T f
    boat = uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)
    problem = uo.TrackingProblem(boat, uo.Reference.hold((0.0, 0.0, 1.0, 0.0)), horizon=3, dt=0.1)
    sensors = Sensors([Sensor.of_states("all", range(12), 12, 10.0, 0.01)])
    model = Estimator(problem, "ekf", sensors=sensors).model
    prediction = ca.Function("f", model.inputs, [model.f])
    x = np.r_[0.1, -0.1, 0.9, 0.05, -0.02, 0.4, 0.1, 0.0, -0.05, 0.0, 0.02, 0.1]
    forces = np.linspace(-30.0, 30.0, 8)
    xa = np.concatenate([x, np.zeros(model.size - 12)])
    predicted = np.array(prediction(xa, forces, model.p_stage, model.p_global)).ravel()[:12]
    expected = np.array(uo.rk4_step(boat.dynamics, 0.1)(x, boat.allocation @ forces, np.zeros(3))).ravel()
    np.testing.assert_allclose(predicted, expected, rtol=1e-12, atol=1e-12)


def test_the_current_handed_to_a_controller_is_low_passed_at_the_filters_bandwidth():
    """``current_filter = T``: a sinusoidal estimate at ω = 1/T comes out at 1/√2 of its amplitude.

    The filter is driven by writing the estimate's current between steps; the reference is the
    continuous first-order low-pass ``1/(1 + jωT)`` (dt = T/100: the discrete filter's gain is
    within 1e-3 of it).  A second record of the same step does not move it; ``reset`` restarts it.
    """
    dt, T = 0.1, 10.0
    ocp, sensors = _drifting_integrator(horizon=3, dt=dt)
    options = EstimatorOptions(current_filter=T, compiled=False)
    estimator = Estimator(ocp, "ekf", sensors=sensors, options=options, parameters={"current": 0.0})
    estimator.reset([0.0], current=[0.2])
    omega = 1.0 / T
    steps = np.arange(4000)
    filtered = np.empty(steps.size)
    for k in steps:
        estimator.x[1] = np.sin(omega * k * dt)
        record = estimator.estimate(int(k))
        assert record.current[0] == estimator.x[1]  # the estimate itself is not filtered
        filtered[k] = record.current_filtered[0]
        if k == 0:  # one step from the prior mean 0.2 towards sin(0) = 0
            np.testing.assert_allclose(filtered[0], 0.2 * np.exp(-dt / T), rtol=1e-12)
    np.testing.assert_array_equal(estimator.estimate(int(steps[-1])).current_filtered, filtered[-1])
    settled = steps > 10 * T / dt  # the start's transient has decayed by e^-10
    t = steps[settled] * dt
    basis = np.column_stack([np.sin(omega * t), np.cos(omega * t)])
    (a, b), *_ = np.linalg.lstsq(basis, filtered[settled], rcond=None)
    np.testing.assert_allclose(np.hypot(a, b), 1.0 / np.sqrt(2.0), rtol=1e-3)
    # the lag: −45° at ω = 1/T, less half a sample (the filter takes the step's own estimate)
    np.testing.assert_allclose(np.arctan2(b, a), -np.pi / 4 + omega * dt / 2, atol=1e-3)
    estimator.reset([0.0], current=[-0.1])
    estimator.x[1] = 0.5
    step = 1.0 - np.exp(-dt / T)
    assert estimator.estimate(0).current_filtered[0] == pytest.approx(-0.1 + step * 0.6, rel=1e-12)
    unfiltered = Estimator(
        ocp, "ekf", sensors=sensors, options=EstimatorOptions(compiled=False), parameters={"current": 0.0}
    )
    unfiltered.reset([0.0])
    unfiltered.x[1] = 0.3
    assert unfiltered.estimate(5).current_filtered[0] == 0.3  # current_filter = 0: the estimate
    with pytest.raises(ValueError, match="options.current_filter"):
        EstimatorOptions(current_filter=-1.0)


def test_simulate_tells_the_controller_the_low_passed_current():
    """With ``current_filter = T`` the NMPC gets the first-order low-pass of the logged estimates.

    The reference recursion runs here on ``run.estimates.currents`` (the filter's own estimates)
    from the prior mean 0; a spy records what ``NMPC.step`` was handed.
    """
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=5)
    T = 2.0
    options = uo.EstimatorOptions(current_filter=T)
    estimator = uo.Estimator(problem, "ekf", sensors=_precise_sensors(), options=options)
    told = []

    class Spy(uo.NMPC):
        def step(self, x, t=0.0, u_prev=None, current=None, parameters=None):
            told.append(np.array(current, dtype=float))
            return super().step(x, t, u_prev, current, parameters)

    x0 = problem.reference.initial_state(0.0)
    run = uo.simulate(
        Spy(problem, "sqp-rti"), x0, 3.0, current=uo.Current(0.8, 1.0), seed=1, estimator=estimator
    )
    assert run.estimates is not None
    estimates = run.estimates.currents
    assert estimates.shape[0] == 30
    told = told[-30:]  # the loop's steps (the warm-up before them calls step too)
    a = 1.0 - np.exp(-problem.dt / T)
    expected, filtered = [], np.zeros(estimates.shape[1])
    for current in estimates:
        filtered = filtered + a * (current - filtered)
        expected.append(filtered.copy())
    np.testing.assert_allclose(np.array(told), np.array(expected), rtol=0, atol=1e-12)
    # the filter lags its estimate: what the controller was told moved less than the estimate
    assert np.linalg.norm(told[-1]) < 0.95 * np.linalg.norm(estimates[-1])


def test_reading_the_estimate_mid_run_does_not_move_the_low_passed_current():
    """Review F2: ``estimate()`` (no step, or an earlier one) is a read; only a later step advances.

    Two estimators see the same current estimates; one is also read mid-run.  Their filtered
    currents agree bit for bit, and match the recursion from 0 (50 steps towards 0.5).
    """
    dt, T = 0.1, 10.0
    ocp, sensors = _drifting_integrator(horizon=3, dt=dt)
    options = EstimatorOptions(current_filter=T, compiled=False)
    quiet, peeked = (
        Estimator(ocp, "ekf", sensors=sensors, options=options, parameters={"current": 0.0}) for _ in range(2)
    )
    for estimator in (quiet, peeked):
        estimator.reset([0.0], current=[0.0])
    peeked.estimate()  # a read before the first step
    records: dict[int, list[float]] = {id(quiet): [], id(peeked): []}
    for k in range(50):
        for estimator in (quiet, peeked):
            estimator.x[1] = 0.5
            records[id(estimator)].append(estimator.estimate(k).current_filtered[0])
        if k == 25:
            assert peeked.estimate().current_filtered[0] == records[id(peeked)][-1]
            peeked.estimate(3)  # an earlier step: a read too
    assert records[id(peeked)] == records[id(quiet)]
    expected = 0.5 * (1.0 - np.exp(-50 * dt / T))
    assert records[id(quiet)][-1] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("name", ["state_std", "initial_state_std", "current_std"])
@pytest.mark.parametrize("value", [np.float32(0.01), np.int64(1), 0.5, 2])
def test_a_scalar_std_option_is_accepted_as_a_float(name, value):
    """Review F3: numpy scalars are scalars, stored as the same positive float."""
    stored = getattr(EstimatorOptions(**{name: value}), name)
    assert type(stored) is float and stored == float(value)


@pytest.mark.parametrize("name", ["state_std", "initial_state_std", "current_std"])
@pytest.mark.parametrize(
    "value",
    [
        -1.0,
        0.0,
        float("nan"),
        "abc",
        True,
        (0.01, -1.0, 0.01),
        (0.01, float("nan")),
        (True, 1.0),
        [[0.1]],
        (),
    ],
)
def test_a_bad_std_option_is_refused_when_the_options_are_made(name, value):
    """Review F3: bad values fail in ``__post_init__``, naming the option (not at build time)."""
    with pytest.raises(ValueError, match=f"options.{name}"):
        EstimatorOptions(**{name: value})


def test_a_numpy_scalar_current_std_builds_an_estimator():
    """Review F3: ``np.float32`` current_std reaches the model as the float it is."""
    ocp, sensors = _drifting_integrator(horizon=3, dt=0.1)
    for value in (np.float32(0.25), (0.25,), np.array([0.25])):
        options = EstimatorOptions(current_std=value, compiled=False)
        estimator = Estimator(ocp, "ekf", sensors=sensors, options=options, parameters={"current": 0.0})
        assert estimator.options.current_std in (0.25, (0.25,))
