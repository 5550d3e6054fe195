"""Thruster fault detection and isolation (uuv_ocp.estimation.faults), issue 27.

References: the regression against ``numpy.linalg.lstsq`` on a regressor matrix (and its ridge
and intercept rows) built here with explicit loops, and against a known health on noise-free
data built from ``T``, ``f`` and ``h``; isolation and false alarms on seeded closed loops of the
BlueROV2 Heavy survey (EKF with a bias, sqp-rti N = 10, 12 s, a drawn current direction), the
plant's fault drawn per seed.  An open-loop replay of recorded commands was tried first and
rejected: without the controller's reaction the commands barely vary after a fault, so the
replay would test a setting the detector never meets.  A stuck thruster's kind and force against
the fault injected into a synthetic bias.
"""

from __future__ import annotations

import numpy as np
import pytest

import uuv_ocp as uo
from tests.control.test_faults import Spy
from uuv_ocp.estimation.faults import (
    FaultDetectorOptions,
    ThrusterFaultDetector,
    loss_regression,
    step_regression,
)
from uuv_ocp.model import Vehicle6DOF

DT = 0.1
DURATION = 12.0  # s of each closed loop
SEEDS = 20
LONG = 40.0  # s: the survey (3 lanes of 6 m, 2 turns) at 0.5 m/s


@pytest.fixture(scope="module")
def boat():
    return Vehicle6DOF.bluerov2_heavy(thrusters=True)


@pytest.fixture(scope="module")
def survey(boat):
    reference = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.5, depth=2.0)
    return uo.TrackingProblem(boat, reference, horizon=10, dt=DT, terminal="cost")


@pytest.fixture(scope="module")
def controller(survey):
    return uo.NMPC(survey, "sqp-rti")


@pytest.fixture(scope="module")
def estimator(survey, boat):
    options = uo.EstimatorOptions(bias=True, bias_std=5.0, compiled=False)
    return uo.Estimator(survey, "ekf", sensors=uo.Sensors.auv(boat), options=options)


def _seeded_run(survey, controller, estimator, seed, faulty):
    """One closed loop of seed ``seed``; returns (run, fault thruster or None, fault step)."""
    rng = np.random.default_rng(1000 + seed)
    thruster, tenths = int(rng.integers(8)), int(rng.integers(50, 71))
    current = uo.Current(speed=0.3, direction=float(rng.uniform(0.0, 2.0 * np.pi)))
    # complete failures: a 50 % loss of a thruster this survey barely commands (the vertical
    # ones, ≈ 3 N RMS) is missed in 2 of 20 seeds (benchmarks/bench_faults.py measures both)
    fault = uo.ThrusterFault(thruster, tenths / 10, "failed")
    run = uo.simulate(
        controller,
        survey.initial_state(),
        DURATION,
        current=current,
        seed=seed,
        estimator=estimator,
        faults=(fault,) if faulty else (),
        fault_detector=FaultDetectorOptions(),
    )
    return run, thruster, tenths


def test_the_loss_regression_is_numpy_lstsq_on_the_same_data(boat):
    """Random windows: the loss equals lstsq on a regressor built here row by row."""
    rng = np.random.default_rng(3)
    T = np.array(boat.thrusters.allocation)
    forces = rng.normal(0.0, 20.0, (15, 8))
    bias = rng.normal(0.0, 5.0, (15, 6))
    rows = []
    for f in forces:  # block k: row j is −Σ_i ... written per entry: X[j, i] = −T[j, i] f_i
        rows.extend([[-T[j, i] * f[i] for i in range(8)] for j in range(6)])
    expected, *_ = np.linalg.lstsq(np.array(rows), bias.ravel(), rcond=None)
    fit = loss_regression(T, forces, bias)
    np.testing.assert_allclose(fit.loss, expected, rtol=1e-10, atol=1e-12)
    assert fit.rank == 8
    # the covariance σ̂² (XᵀX)⁻¹ (full rank, no ridge), σ̂² over the 6 W − 8 degrees of freedom
    X = np.array(rows)
    residual = bias.ravel() - X @ expected
    variance = residual @ residual / (X.shape[0] - 8)
    np.testing.assert_allclose(fit.covariance, variance * np.linalg.inv(X.T @ X), rtol=1e-8)
    np.testing.assert_allclose(np.sqrt(np.diag(fit.covariance)), fit.standard_error, rtol=1e-8)


def test_the_ridge_and_intercept_regression_is_lstsq_on_the_stacked_system(boat):
    rng = np.random.default_rng(6)
    T = np.array(boat.thrusters.allocation)
    forces = rng.normal(0.0, 20.0, (12, 8))
    bias = rng.normal(0.0, 5.0, (12, 6))
    ridge = 7.0
    rows, target = [], []
    for k, f in enumerate(forces):
        for j in range(6):
            rows.append([-T[j, i] * f[i] for i in range(8)] + [1.0 if m == j else 0.0 for m in range(6)])
            target.append(bias[k, j])
    for i in range(8):  # ridge rows on the losses only
        rows.append([ridge if m == i else 0.0 for m in range(14)])
        target.append(0.0)
    expected, *_ = np.linalg.lstsq(np.array(rows), np.array(target), rcond=None)
    fit = loss_regression(T, forces, bias, ridge=ridge, intercept=True)
    np.testing.assert_allclose(fit.loss, expected[:8], rtol=1e-10, atol=1e-12)
    # a fault hypothesis: thrusters 1 and 5 only, the others held healthy
    subset = np.array(rows)[:, [1, 5, *range(8, 14)]]
    rows_kept = [r for r in range(subset.shape[0]) if r < 72 or r - 72 in (1, 5)]
    expected, *_ = np.linalg.lstsq(subset[rows_kept], np.array(target)[rows_kept], rcond=None)
    fit = loss_regression(T, forces, bias, ridge=ridge, intercept=True, columns=[5, 1])
    np.testing.assert_allclose(fit.loss[[1, 5]], expected[:2], rtol=1e-10, atol=1e-12)
    assert np.all(np.delete(fit.loss, [1, 5]) == 0.0) and np.all(
        np.isinf(np.delete(fit.standard_error, [1, 5]))
    )


def test_the_loss_regression_recovers_a_known_health_on_noise_free_data(boat):
    """b̂ built as T(h ∘ f) − T f (what a healthy model sees of the plant): loss = 1 − h exactly."""
    rng = np.random.default_rng(4)
    T = np.array(boat.thrusters.allocation)
    h = np.array([1.0, 0.3, 1.0, 1.0, 0.0, 1.0, 0.75, 1.0])
    forces = rng.uniform(-30.0, 30.0, (20, 8))
    bias = np.array([T @ (h * f) - T @ f for f in forces])
    for intercept in (False, True):  # a constant offset is absorbed by the intercept, not the loss
        offset = np.array([3.0, -2.0, 5.0, 0.1, 0.2, -0.3]) if intercept else 0.0
        fit = loss_regression(T, forces, bias + offset, intercept=intercept)
        np.testing.assert_allclose(fit.loss, 1.0 - h, atol=1e-10)
        assert fit.residual_std < 1e-9


def test_the_detector_declares_a_clean_fault_on_synthetic_bias(boat):
    """Noise-free bias of a failed thruster 3 from step 40: detected after hold steps, at h ≈ 0."""
    rng = np.random.default_rng(5)
    T = np.array(boat.thrusters.allocation)
    options = FaultDetectorOptions(window=10, hold=3, arm_time=1.0, ridge=0.0, normalise=False)
    detector = ThrusterFaultDetector(T, options)
    for k in range(80):
        f = rng.uniform(-30.0, 30.0, 8)
        h = np.ones(8)
        if k >= 40:
            h[3] = 0.0
        b = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0]  # a thruster-space bias of it
        noise = rng.normal(0.0, 0.5, 8)  # keeps the residual, hence the statistic, finite
        detector.update(k, k * DT, f, b + noise)
    assert [item.thruster for item in detector.detections] == [3]
    first = detector.detections[0]
    assert 40 + options.hold - 1 <= first.step <= 40 + options.window
    # declared while the window still holds healthy steps; then the told health follows the loss
    assert first.health < 1.0 - options.threshold and detector.health[3] < 0.2
    assert np.all(np.delete(detector.health, 3) == 1.0)


@pytest.mark.parametrize(("window", "hold"), [(10, 3), (20, 5)])
def test_the_baseline_freeze_ends_after_window_plus_hold_steps(boat, window, hold):
    """A 20 % loss of thruster 3 from step 40: pending (>= 0.15), never a detection (< 0.3).

    Without the limit the baseline would stay frozen forever; it must move again exactly
    ``window + hold`` steps after the first step whose loss estimate (``1 − estimate``, read
    here, not the detector's flag) reached ``pending · threshold``.  A slow drift of the
    generalised bias keeps each baseline update non-zero.
    """
    rng = np.random.default_rng(21)
    T = np.array(boat.thrusters.allocation)
    # the baseline is the regression's: the increment test (off here) would declare this
    # noise-free, unlagged 20 % loss (its threshold, 0.18, is calibrated to an EKF's bias, which
    # takes about half of a step on the quiet steps)
    options = FaultDetectorOptions(window=window, hold=hold, arm_time=1.0, increment_period=0)
    detector = ThrusterFaultDetector(T, options)
    baselines, pending = [], []
    for k in range(40 + 4 * (window + hold)):
        f = rng.uniform(-30.0, 30.0, 8)
        h = np.ones(8)
        if k >= 40:
            h[3] = 0.8
        drift = np.linalg.lstsq(T, np.full(6, 0.05 * k), rcond=None)[0]
        b = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0] + drift
        detector.update(k, k * DT, f, b + rng.normal(0.0, 0.05, 8))
        baselines.append(detector.baseline)
        pending.append(bool(np.max(1.0 - detector.estimate) >= options.pending * options.threshold))
    assert detector.detections == []
    onset = pending.index(True)
    assert 40 <= onset < 40 + window and all(pending[onset:])  # it would freeze for ever
    moved = [not np.array_equal(baselines[k], baselines[k - 1]) for k in range(onset + 1, len(baselines))]
    assert moved[: window + hold] == [False] * (window + hold)  # frozen: window + hold steps
    assert all(moved[window + hold :])  # then learns again, every step


def _second_fault_run(boat, hold_isolated, second_steps):
    """Synthetic bias: thruster 3 fails at step 30; thruster 6 loses 70 % over ``second_steps``."""
    rng = np.random.default_rng(13)
    T = np.array(boat.thrusters.allocation)
    options = FaultDetectorOptions(window=10, hold=3, hold_isolated=hold_isolated, arm_time=1.0, settle=0.5)
    detector = ThrusterFaultDetector(T, options)
    for k in range(160):
        f = rng.uniform(-30.0, 30.0, 8)
        h = np.ones(8)
        if k >= 30:
            h[3] = 0.0
        if k in second_steps:
            h[6] = 0.3
        b = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0]
        detector.update(k, k * DT, f, b + rng.normal(0.0, 0.3, 8))
    return detector


@pytest.mark.parametrize("hold_isolated", [3, 15])
def test_a_second_detection_needs_hold_isolated_steps(boat, hold_isolated):
    """After thruster 3 is isolated, a loss of 6 must pass ``hold_isolated`` steps, not ``hold``.

    A 12-step loss (a drift at a turn reads so) is declared with ``hold_isolated = hold`` = 3 and
    not with 15; a lasting one is declared either way, no earlier than 15 passing steps.
    """
    brief = _second_fault_run(boat, hold_isolated, range(100, 112))
    lasting = _second_fault_run(boat, hold_isolated, range(100, 160))
    assert [item.thruster for item in brief.detections[:1]] == [3]
    assert [item.thruster for item in brief.detections] == ([3, 6] if hold_isolated == 3 else [3])
    assert [item.thruster for item in lasting.detections] == [3, 6]
    assert lasting.detections[1].step >= 100 + hold_isolated - 1


def test_the_offset_columns_are_lstsq_and_recover_a_stuck_thruster(boat):
    """Stuck thruster 2 at 12 N (h = 0, s = 12): bias T_2 (12 − f_2); lstsq on columns built here."""
    rng = np.random.default_rng(8)
    T = np.array(boat.thrusters.allocation)
    forces = rng.uniform(-30.0, 30.0, (20, 8))
    bias = np.array([T[:, 2] * (12.0 - f[2]) for f in forces])
    rows = []
    for f in forces:
        rows.extend([[-T[j, i] * f[i] for i in range(8)] + [T[j, 2]] for j in range(6)])
    expected, *_ = np.linalg.lstsq(np.array(rows), bias.ravel(), rcond=None)
    fit = loss_regression(T, forces, bias, offsets=[2])
    np.testing.assert_allclose(fit.loss, expected[:8], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(fit.offset[2], expected[8], rtol=1e-10)
    np.testing.assert_allclose(fit.loss, np.eye(8)[2], atol=1e-10)  # ℓ = e_2: thruster 2 lost
    assert abs(fit.offset[2] - 12.0) < 1e-9 and np.all(np.delete(fit.offset, 2) == 0.0)


def test_the_step_regression_is_lstsq_with_the_step_column_added(boat):
    """Each change point's fit against lstsq on a design built here entry by entry.

    Null model: the eight losses, the ridge rows, the intercept and the per-axis ramp; the
    hypothesis adds thruster i's column on the steps k >= p.  The change is the added
    coefficient, its standard error the null model's σ̂ times the square root of the augmented
    inverse's last entry (Frisch–Waugh), and a pair's separation the difference of the two
    coefficients of a design with both columns over its standard error.
    """
    rng = np.random.default_rng(17)
    T = np.array(boat.thrusters.allocation)
    W, ridge, margin = 12, 4.0, 3
    forces = rng.normal(0.0, 20.0, (W, 8))
    bias = rng.normal(0.0, 5.0, (W, 6))
    ramp = np.linspace(-1.0, 1.0, W)
    null = []
    for k, f in enumerate(forces):
        for j in range(6):
            unit = [1.0 if m == j else 0.0 for m in range(6)]
            null.append([-T[j, i] * f[i] for i in range(8)] + unit + [ramp[k] * u for u in unit])
    for i in range(8):
        null.append([ridge if m == i else 0.0 for m in range(20)])
    null = np.array(null)
    target = np.concatenate([bias.ravel(), np.zeros(8)])
    fitted, *_ = np.linalg.lstsq(null, target, rcond=None)
    residual = (target - null @ fitted)[: 6 * W]
    sigma = np.sqrt(residual @ residual / (6 * W - 20))

    def step_column(i, p):
        column = [-T[j, i] * forces[k, i] if k >= p else 0.0 for k in range(W) for j in range(6)]
        return np.array(column + [0.0] * 8)

    fit = step_regression(T, forces, bias, margin=margin, ridge=ridge, intercept=True, trend=True)
    assert fit.first == margin and fit.change.shape == (W - 2 * margin + 1, 8)
    np.testing.assert_allclose(fit.residual_std, sigma, rtol=1e-10)
    for p, i in [(3, 0), (5, 4), (9, 7), (6, 2)]:
        design = np.column_stack([null, step_column(i, p)])
        coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
        variance = np.linalg.inv(design.T @ design)[-1, -1]
        np.testing.assert_allclose(fit.change[p - margin, i], coefficients[-1], rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(fit.standard_error[p - margin, i], sigma * np.sqrt(variance), rtol=1e-8)
    pair = np.column_stack([null, step_column(1, 7), step_column(6, 7)])
    coefficients, *_ = np.linalg.lstsq(pair, target, rcond=None)
    inverse = np.linalg.inv(pair.T @ pair)[-2:, -2:]
    expected = (coefficients[-2] - coefficients[-1]) / (
        sigma * np.sqrt(inverse[0, 0] + inverse[1, 1] - 2 * inverse[0, 1])
    )
    np.testing.assert_allclose(fit.separation(7 - margin, 1, [6]), expected, rtol=1e-8)


@pytest.mark.parametrize("losses", [True, False])
def test_the_increment_test_is_weighted_lstsq_on_differenced_equations(boat, losses):
    """``whiten=1`` and ``scale``: lstsq on a design differenced and weighted here entry by entry.

    Row (k, j), k = 1 .. W − 1, of every column (the losses, the intercept, the ramp, the step
    column) is ``s_kj (x_kj − x_(k−1)j)``; the ridge rows stay as they are.  ``losses=False``
    leaves the eight loss columns (and their ridge rows) out of the null model.
    """
    rng = np.random.default_rng(23)
    T = np.array(boat.thrusters.allocation)
    W, ridge, margin = 10, 4.0, 2
    forces = rng.normal(0.0, 20.0, (W, 8))
    bias = np.cumsum(rng.normal(0.0, 2.0, (W, 6)), axis=0)
    scale = rng.uniform(0.5, 20.0, (W - 1, 6))
    ramp = np.linspace(-1.0, 1.0, W)

    def entry(column, k, j):  # column(k, j): the undifferenced equation's coefficient
        return scale[k - 1, j] * (column(k, j) - column(k - 1, j))

    null_columns = [(lambda k, j, i=i: -T[j, i] * forces[k, i]) for i in range(8)] if losses else []
    null_columns += [(lambda k, j, a=a: 1.0 if j == a else 0.0) for a in range(6)]
    null_columns += [(lambda k, j, a=a: ramp[k] if j == a else 0.0) for a in range(6)]
    rows = [[entry(c, k, j) for c in null_columns] for k in range(1, W) for j in range(6)]
    count = 8 if losses else 0
    rows += [[ridge if m == i else 0.0 for m in range(len(null_columns))] for i in range(count)]
    null = np.array(rows)
    target = np.concatenate(
        [
            [scale[k - 1, j] * (bias[k, j] - bias[k - 1, j]) for k in range(1, W) for j in range(6)],
            np.zeros(count),
        ]
    )
    fitted, _, rank, _ = np.linalg.lstsq(null, target, rcond=None)
    residual = (target - null @ fitted)[: 6 * (W - 1)]
    sigma = np.sqrt(residual @ residual / (6 * (W - 1) - rank))
    fit = step_regression(
        T,
        forces,
        bias,
        margin=margin,
        ridge=ridge,
        intercept=True,
        trend=True,
        losses=losses,
        whiten=1.0,
        scale=scale,
    )
    np.testing.assert_allclose(fit.residual_std, sigma, rtol=1e-8)
    for p, i in [(2, 0), (4, 5), (8, 3)]:
        step = [
            entry(lambda k, j, i=i, p=p: -T[j, i] * forces[k, i] if k >= p else 0.0, k, j)
            for k in range(1, W)
            for j in range(6)
        ]
        design = np.column_stack([null, np.concatenate([step, np.zeros(count)])])
        coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
        np.testing.assert_allclose(fit.change[p - margin, i], coefficients[-1], rtol=1e-7, atol=1e-10)
        # Frisch–Waugh on the rank-deficient null (the differenced intercept is zero): the step
        # column's norm once residualised on what the null spans
        basis = np.linalg.svd(null, full_matrices=False)[0][:, : int(rank)]
        column = design[:, -1] - basis @ (basis.T @ design[:, -1])
        np.testing.assert_allclose(
            fit.standard_error[p - margin, i], sigma / np.linalg.norm(column), rtol=1e-7
        )


def test_the_null_models_ramp_absorbs_a_drift_a_step_column_would_fit(boat):
    """A bias drifting linearly (a survey turn) is no change with the ramp; without it, it reads as one.

    Thruster 2 held at 25 N: its step column is a step along T_2, which a ramp along T_2 fits
    in part (the step at the window's middle).  The ramp is in the null model's span, so with
    ``trend=True`` every change of every thruster is 0 up to the noise; without it the drift
    reads as a large, significant loss change of thruster 2.
    """
    rng = np.random.default_rng(5)
    T = np.array(boat.thrusters.allocation)
    W = 20
    forces = rng.normal(0.0, 10.0, (W, 8))
    forces[:, 2] = 25.0
    drift = -np.linspace(0.0, 20.0, W)[:, None] * T[:, 2][None, :]  # 20 N along T_2 over 2 s
    bias = drift + rng.normal(0.0, 0.05, (W, 6))
    with_ramp = step_regression(T, forces, bias, margin=3, ridge=10.0, intercept=True, trend=True)
    without = step_regression(T, forces, bias, margin=3, ridge=10.0, intercept=True, trend=False)
    assert np.max(np.abs(with_ramp.change[:, 2])) < 0.02, with_ramp.change[:, 2]
    assert np.max(without.change[:, 2]) > 0.3 and np.max(without.statistic[:, 2]) > 4.0


def _constant_command_loss(boat, options, seed):
    """Synthetic bias: thruster 3 held at 30 N loses 50 % at step 60 (the benchmark's saturated case).

    The bias follows the true one through a first-order lag of 2 steps (the benchmark's EKF: most
    of the step within 0.2 s on its trial 33), with a slow generalised drift and noise; the other
    thrusters' commands vary.  Returns the detector.
    """
    rng = np.random.default_rng(seed)
    T = np.array(boat.thrusters.allocation)
    detector = ThrusterFaultDetector(T, options, bounds=np.full(8, 40.0))
    lagged = np.zeros(8)
    for k in range(140):
        f = rng.uniform(-20.0, 20.0, 8)
        f[3] = 30.0
        h = np.ones(8)
        if k >= 60:
            h[3] = 0.5
        truth = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0]
        lagged += (truth - lagged) / 2.0
        # the current's estimation error: a slow surge and sway force (N)
        drift = np.linalg.lstsq(T, 3.0 * np.sin(0.05 * k) * np.array([1.0, 1.0, 0, 0, 0, 0]), rcond=None)[0]
        detector.update(k, k * DT, f, lagged + drift + rng.normal(0.0, 0.5, 8))
    return detector


@pytest.mark.parametrize("seed", range(3))
def test_a_constant_command_loss_is_detected_within_two_seconds(boat, seed):
    """The change-point test declares it within 20 steps; the regression alone does not.

    Under a constant command the loss is a constant force, which the window's intercept absorbs
    once the fault is older than the window: the regression alone (``step_significance=0`` and
    ``increment_period=0``, the detector before the change-point tests) declares nothing in the
    8 s after the fault.
    """
    detector = _constant_command_loss(boat, FaultDetectorOptions(), seed)
    assert [item.thruster for item in detector.detections] == [3]
    first = detector.detections[0]
    assert 60 <= first.step <= 60 + 20
    # told the loss after the change (not the window's, 0 under a constant command), and as a
    # loss: under a steady command stuck and loss are one regressor, the bias not yet settled
    assert first.kind == "loss" and first.offset == 0.0, first
    assert abs(first.health - 0.5) < 0.15, first
    late = _constant_command_loss(boat, FaultDetectorOptions(step_significance=0.0, increment_period=0), seed)
    assert late.detections == []


@pytest.mark.parametrize("separation", [0.0, 2.0])
def test_a_loss_split_evenly_between_two_thrusters_is_not_isolated(boat, separation):
    """Thrusters 0 and 3 both lose 40 % from step 40, their commands opposite.

    Nearly collinear regressors, as at a survey turn: the largest loss is a coin flip, and only
    the separation test keeps it from being declared.
    """
    rng = np.random.default_rng(11)
    T = np.array(boat.thrusters.allocation)
    options = FaultDetectorOptions(arm_time=1.0, separation=separation)
    detector = ThrusterFaultDetector(T, options)
    for k in range(100):
        f = rng.uniform(-30.0, 30.0, 8)
        f[3] = -f[0] + rng.normal(0.0, 1.0)  # 0 and 3 push against each other
        h = np.ones(8)
        if k >= 40:
            h[[0, 3]] = 0.6
        b = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0]
        detector.update(k, k * DT, f, b + rng.normal(0.0, 0.3, 8))
    if separation:
        assert detector.detections == []
    else:  # the same data without the test: one of the pair is declared (either may be)
        assert [item.thruster for item in detector.detections][:1] in ([0], [3])


@pytest.mark.parametrize(("kind", "value"), [("stuck", 15.0), ("stuck", -20.0), ("failed", None)])
def test_the_detector_tells_a_stuck_thruster_from_a_failed_one(boat, kind, value):
    """Synthetic bias of the injected fault of thruster 3 from step 40: its kind and stuck force."""
    rng = np.random.default_rng(9)
    T = np.array(boat.thrusters.allocation)
    options = FaultDetectorOptions(window=10, hold=5, arm_time=1.0, ridge=0.0, normalise=False)
    detector = ThrusterFaultDetector(T, options, bounds=np.full(8, 40.0))
    fault = uo.ThrusterFault(3, 4.0, kind, value=value)
    for k in range(80):
        f = rng.uniform(-30.0, 30.0, 8)
        h, s = np.ones(8), np.zeros(8)
        if k >= 40:
            h[3], s[3] = fault.health, fault.offset
        b = np.linalg.lstsq(T, T @ (h * f + s) - T @ f, rcond=None)[0]
        detector.update(k, k * DT, f, b + rng.normal(0.0, 0.3, 8))
    assert [item.thruster for item in detector.detections] == [3]
    first = detector.detections[0]
    assert first.kind == ("stuck" if kind == "stuck" else "loss")
    if kind == "stuck":
        assert abs(first.offset - value) < 0.1 * abs(value) and first.health == 0.0
        assert abs(detector.offset[3] - value) < 0.1 * abs(value) and detector.stuck == (3,)
    else:
        assert first.offset == 0.0 and detector.offset[3] == 0.0 and detector.stuck == ()


@pytest.mark.slow
def test_a_seeded_stuck_thruster_is_isolated_in_19_of_20_seeds(survey, controller, estimator):
    """A random thruster sticks at ±10..25 N at 5..7 s; the first detection names it."""
    right = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(2000 + seed)
        thruster, tenths = int(rng.integers(8)), int(rng.integers(50, 71))
        value = float(rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 25.0))
        run = uo.simulate(
            controller,
            survey.initial_state(),
            DURATION,
            current=uo.Current(speed=0.3, direction=float(rng.uniform(0.0, 2.0 * np.pi))),
            seed=seed,
            estimator=estimator,
            faults=(uo.ThrusterFault(thruster, tenths / 10, "stuck", value=value),),
            fault_detector=FaultDetectorOptions(),
        )
        right += bool(run.detections.size and int(run.detections[0, 1]) == thruster)
    assert right >= 19, f"isolated {right}/{SEEDS}"  # measured 20/20


@pytest.mark.slow
def test_a_seeded_fault_is_isolated_to_its_thruster_in_19_of_20_seeds(survey, controller, estimator):
    """A random thruster fails at a random time in 5..7 s; the first detection names it."""
    right = 0
    for seed in range(SEEDS):
        run, thruster, _ = _seeded_run(survey, controller, estimator, seed, faulty=True)
        right += bool(run.detections.size and int(run.detections[0, 1]) == thruster)
    # the goal; measured 20/20 (a per-window intercept, before the baseline, gave 18/20:
    # seeds 0 and 11 saturate the failed thruster, a constant command the intercept absorbed)
    assert right >= 19, f"isolated {right}/{SEEDS}"


@pytest.mark.parametrize("step_significance", [4.0, 0.0])
def test_a_seeded_half_loss_is_detected_within_two_seconds_by_the_change_point_test(
    survey, controller, estimator, step_significance
):
    """Seed 7, thruster 0 at 50 % from 5.1 s: within 2 s with the change-point test, late without.

    The closed loop of the other seeded tests with a 50 % loss instead of a failure.  Found by
    replaying 18 such seeds' recorded inputs (detection disabled) through both detectors: seed
    7 was declared 6.1 s after its fault without the test (the regression alone, the detector
    before it) and 1.2 s after with it; the closed loop is the same until the first detection.
    """
    rng = np.random.default_rng(1000 + 7)
    thruster, tenths = int(rng.integers(8)), int(rng.integers(50, 71))
    current = uo.Current(speed=0.3, direction=float(rng.uniform(0.0, 2.0 * np.pi)))
    assert (thruster, tenths) == (0, 51)  # the draw of _seeded_run, a loss instead of a failure
    run = uo.simulate(
        controller,
        survey.initial_state(),
        DURATION,
        current=current,
        seed=7,
        estimator=estimator,
        faults=(uo.ThrusterFault(thruster, tenths / 10, "loss", effectiveness=0.5),),
        fault_detector=FaultDetectorOptions(
            step_significance=step_significance, increment_period=2 if step_significance else 0
        ),
    )
    assert run.detections.size and int(run.detections[0, 1]) == thruster, run.detections
    delay = run.detections[0, 0] - tenths / 10
    if step_significance:
        assert delay <= 2.0, delay
    else:
        assert delay > 2.0, delay


def _phased_noise_loss(boat, options, seed):
    """Synthetic bias: thruster 1, commanded ±15 N, loses 50 % at step 80 under phased noise.

    The benchmark's EKF moves its bias by about 1.6 N (surge, sway, heave) on the steps with a
    DVL sample (5 Hz at dt = 0.1 s) and by 0.04–0.15 N on the others; here the noise's increments
    alternate the same way (1.5 N and 0.05 N, a slowly reverting sum), and the bias follows the
    true one through a first-order lag taking 0.6 of a step on its first step (the benchmark
    EKF's, measured on its large faults).  The loss removes about 4.3 N (8.7 N RMS command).
    """
    rng = np.random.default_rng(seed)
    T = np.array(boat.thrusters.allocation)
    detector = ThrusterFaultDetector(T, options, bounds=np.full(8, 40.0))
    lagged, noise = np.zeros(8), np.zeros(6)
    for k in range(110):
        f = rng.uniform(-15.0, 15.0, 8)
        h = np.ones(8)
        if k >= 80:
            h[1] = 0.5
        truth = np.linalg.lstsq(T, T @ (h * f) - T @ f, rcond=None)[0]
        lagged += 0.6 * (truth - lagged)  # the benchmark EKF: 0.6 of a step on its first step
        loud = (
            np.array([1.5, 1.5, 1.5, 0.15, 0.4, 0.07])
            if k % 2
            else np.array([0.08, 0.04, 0.15, 0.1, 0.15, 0.07])
        )
        noise = 0.98 * noise + rng.normal(0.0, 1.0, 6) * loud
        detector.update(k, k * DT, f, lagged + np.linalg.lstsq(T, noise, rcond=None)[0])
    return detector


def test_a_light_loss_under_phased_noise_is_detected_within_2_s_by_the_increment_test(boat):
    """The increment test declares it within 20 steps in 7 of 8 seeds; the tests on the bias in 1.

    ``increment_period=0`` (detector 9) weighs every step's bias alike, and the loud steps'
    wander hides the change (seed 1 passes it at step 97, 1.7 s after); the increment test
    weighs each increment by its phase's noise (steps 84–96; seed 5's change stays under
    ``increment_threshold``).
    """

    def on_time(options, seed):
        found = _phased_noise_loss(boat, options, seed).detections
        assert all(80 <= item.step for item in found), found  # nothing before the fault
        return bool(found) and found[0].thruster == 1 and found[0].step <= 80 + 20

    assert sum(on_time(FaultDetectorOptions(), seed) for seed in range(8)) >= 7
    assert sum(on_time(FaultDetectorOptions(increment_period=0), seed) for seed in range(8)) <= 1


def test_after_a_detection_the_thruster_pushing_against_it_is_not_declared(survey, controller, estimator):
    """Seed 3: thruster 2 fails at 5.3 s and is isolated at 6.0 s; nothing else is declared.

    Before the window restarted at a detection (``settle``), thruster 0 was declared at 7.0 s:
    the estimator's bias along thruster 2 decays for a second after the controller reallocates,
    and a window spanning both regimes read that decay as thruster 0's loss.
    """
    run, thruster, _ = _seeded_run(survey, controller, estimator, 3, faulty=True)
    assert [int(row[1]) for row in run.detections] == [thruster], run.detections


@pytest.mark.slow
def test_no_false_alarm_on_fault_free_seeded_runs(survey, controller, estimator):
    alarms = [
        seed
        for seed in range(SEEDS)
        if _seeded_run(survey, controller, estimator, seed, faulty=False)[0].detections.size
    ]
    assert alarms == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_no_false_alarm_on_long_fault_free_runs_through_the_turns(survey, controller, estimator, seed):
    """40 s: the whole survey, its turns relative to the current included (where the bias drifts).

    The benchmark's 50-s runs alarmed in 8 of 20 with a baseline alone (no per-window intercept):
    the bias swings by tens of newtons with the heading relative to the current.
    """
    rng = np.random.default_rng(3000 + seed)
    run = uo.simulate(
        controller,
        survey.initial_state(),
        LONG,
        current=uo.Current(speed=0.3, direction=float(rng.uniform(0.0, 2.0 * np.pi))),
        seed=seed,
        estimator=estimator,
        fault_detector=FaultDetectorOptions(),
    )
    assert run.t[-1] > LONG - 1.0 and run.detections.size == 0, run.detections


def test_the_fault_tolerant_nmpc_is_told_the_estimated_health(survey, boat, tmp_path):
    """Closed loop: thruster 2 fails at 6 s; detected and the controller's health follows it."""
    controller = Spy(survey, "sqp-rti")
    options = uo.EstimatorOptions(bias=True, bias_std=5.0, compiled=False)
    estimator = uo.Estimator(survey, "ekf", sensors=uo.Sensors.auv(boat), options=options)
    run = uo.simulate(
        controller,
        survey.initial_state(),
        DURATION,
        current=uo.Current(speed=0.3, direction=np.pi / 4),
        seed=1,
        estimator=estimator,
        faults=(uo.ThrusterFault(2, 6.0),),
        fault_detector=uo.FaultDetectorOptions(),
    )
    assert run.detections.shape == (1, 4) and int(run.detections[0, 1]) == 2
    assert run.detections[0, 3] == 0.0  # told a loss (a complete failure), not stuck
    declared = int(round((run.detections[0, 0] - run.t[0]) / DT))
    steps = controller.told[-run.controls.shape[0] :]  # warm_up's own steps come first
    # the detector decides on step k's estimate, before the controller's step k
    assert all(told is None for told in steps[:declared])
    after = steps[declared:]
    told_health = np.array([told["health"][2] for told in after])
    assert told_health.size and told_health[0] < 0.5 and np.median(told_health) < 0.5
    # a thruster is told unhealthy only once detected (a later detection may add one)
    detected = set(run.detections[:, 1].astype(int))
    for k, told in enumerate(after, start=declared):
        lowered = set(np.flatnonzero(told["health"] < 1.0))
        assert lowered <= {int(row[1]) for row in run.detections if row[0] <= run.t[k] + 1e-9} <= detected
    assert run.estimated_health.shape == (run.controls.shape[0], 8)
    run.save(tmp_path / "run.npz")  # the detections survive a save
    loaded = uo.ClosedLoopResult.load(tmp_path / "run.npz")
    np.testing.assert_array_equal(loaded.detections, run.detections)
    np.testing.assert_array_equal(loaded.estimated_health, run.estimated_health)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("window", 1, "window"),
        ("threshold", 1.5, "threshold must lie in"),
        ("threshold", 0.0, "threshold"),
        ("significance", -1.0, "significance"),
        ("hold", 0, "hold"),
        ("hold_isolated", 0, "hold_isolated"),
        ("arm_time", -1.0, "arm_time"),
        ("min_force", 0.0, "min_force"),
        ("ridge", -1.0, "ridge"),
        ("baseline", 0.5, "baseline must be >= 1"),
        ("pending", 1.5, "pending must lie in"),
        ("stuck_force", 0.0, "stuck_force"),
        ("isolation", "bank", "isolation"),
        ("normalise", "yes", "normalise"),
        ("intercept", 1, "intercept"),
        ("separation", -1.0, "separation"),
        ("settle", -0.5, "settle"),
        ("step_significance", -1.0, "step_significance"),
        ("step_margin", 0, "step_margin"),
        ("step_margin", 11, "step_margin must be at most window // 2 = 10"),
        ("step_losses", 1, "step_losses"),
        ("increment_period", -1, "increment_period"),
        ("increment_period", 1.5, "increment_period"),
        ("increment_significance", 0.0, "increment_significance"),
        ("increment_threshold", 1.5, "increment_threshold must lie in"),
        ("increment_threshold", 0.0, "increment_threshold"),
    ],
)
def test_bad_options_are_refused_by_name(field, value, match):
    with pytest.raises(ValueError, match=match):
        FaultDetectorOptions(**{field: value})


def test_bad_detector_arguments_are_refused_by_name(boat, survey):
    T = np.array(boat.thrusters.allocation)
    with pytest.raises(ValueError, match="allocation must be a finite"):
        ThrusterFaultDetector(T[:3])
    with pytest.raises(ValueError, match="options must be"):
        ThrusterFaultDetector(T, options={"window": 3})
    x0 = survey.initial_state()
    with pytest.raises(ValueError, match="fault_detector must be"):
        uo.simulate(uo.NMPC(survey, "ipopt"), x0, 0.5, fault_detector={"window": 3})
    with pytest.raises(ValueError, match="bias=True"):
        uo.simulate(uo.NMPC(survey, "ipopt"), x0, 0.5, fault_detector=FaultDetectorOptions())
    with pytest.raises(ValueError, match="not with health_known"):
        uo.simulate(
            uo.NMPC(survey, "ipopt"), x0, 0.5, health_known=True, fault_detector=FaultDetectorOptions()
        )
    forces = uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), survey.reference, horizon=5, dt=DT)
    with pytest.raises(ValueError, match="vehicle has thrusters"):
        uo.simulate(
            uo.NMPC(forces, "ipopt"), forces.initial_state(), 0.5, fault_detector=FaultDetectorOptions()
        )
