"""The null-space dither of the fault-tolerant NMPC (uuv_ocp.control.dither), issue 27.

References: the null space by ``scipy.linalg.null_space`` (an SVD of its own) compared through
the basis-independent projector; the admissible scale by bisection on the bounds written out
here; "no dither" against the loop without the option (bit for bit); the detection of a
constant-command 50 % loss on the benchmark's survey with and without the dither.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

import uuv_ocp as uo
from uuv_ocp.control.dither import DitherOptions, NullSpaceDither, dither_scale, null_space_basis
from uuv_ocp.model import Vehicle6DOF

BOAT = Vehicle6DOF.bluerov2_heavy(thrusters=True)
T = np.array(BOAT.thrusters.allocation)
BOUNDS = np.array(BOAT.control_bound)
RATES = np.array(BOAT.control_rate_bound)
DT = 0.1


def _projector(basis):
    return basis @ basis.T


@pytest.mark.parametrize(
    "health",
    [
        None,
        [1, 1, 1, 1, 1, 1, 1, 1],
        [0.5, 1, 1, 1, 1, 1, 1, 1],
        [1, 1, 0, 1, 1, 0.3, 1, 1],
        [0, 1, 1, 1, 1, 1, 1, 0],
    ],
)
def test_the_basis_spans_the_null_space_of_the_health_weighted_matrix(health):
    h = np.ones(8) if health is None else np.array(health, dtype=float)
    basis = null_space_basis(T, health)
    np.testing.assert_allclose(basis.T @ basis, np.eye(basis.shape[1]), atol=1e-12)  # orthonormal
    np.testing.assert_allclose(T @ np.diag(h) @ basis, 0.0, atol=1e-12)
    # the same subspace as scipy's SVD of the working thrusters' columns (dead ones: no dither)
    alive = np.flatnonzero(h > 0)
    reference = np.zeros((8, 0))
    independent = scipy.linalg.null_space(T[:, alive] * h[alive])
    reference = np.zeros((8, independent.shape[1]))
    reference[alive] = independent
    assert basis.shape[1] == reference.shape[1] == len(alive) - 6
    np.testing.assert_allclose(_projector(basis), _projector(reference), atol=1e-12)
    assert np.all(basis[h == 0] == 0.0)


def test_the_healthy_basis_is_the_two_physical_modes_whatever_the_rotation():
    """Canonical: the horizontal and the vertical quadruple, each pushing equally (±1/2)."""
    basis = null_space_basis(T)
    expected = np.zeros((8, 2))
    expected[:4, 0] = 0.5
    expected[4:, 1] = 0.5
    signs = np.sign(basis[np.argmax(np.abs(basis), axis=0), [0, 1]])
    np.testing.assert_allclose(basis * signs, expected, atol=1e-12)
    # a rotated copy of T's rows (another SVD rotation of the same null space) gives the same basis
    rotation = np.linalg.qr(np.random.default_rng(4).normal(size=(6, 6)))[0]
    np.testing.assert_allclose(np.abs(null_space_basis(rotation @ T)), np.abs(basis), atol=1e-12)


def _admissible(applied, previous):
    return np.all(np.abs(applied) <= BOUNDS + 1e-9) and np.all(
        np.abs(applied - previous) <= RATES * DT + 1e-9
    )


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    amplitude=st.floats(0.1, 60.0),
    dead=st.sampled_from([(), (0,), (5,), (2, 7)]),
)
def test_the_applied_commands_hold_the_bounds_and_add_no_wrench(seed, amplitude, dead):
    """Random admissible plans (many at the box or rate bound): u + d admissible, T diag(h) d = 0."""
    rng = np.random.default_rng(seed)
    health = np.ones(8)
    health[list(dead)] = 0.0
    health[rng.integers(8)] *= 0.5 if not dead else 1.0
    dither = NullSpaceDither(T, DitherOptions(amplitude=amplitude), BOUNDS, RATES, DT)
    previous = np.zeros(8)
    for k in range(40):
        # a plan within the box and the rate bound around the last applied command, often at a bound
        step = rng.uniform(-1.5, 1.5, 8) * RATES * DT
        plan = np.clip(
            np.clip(previous + step, previous - RATES * DT, previous + RATES * DT), -BOUNDS, BOUNDS
        )
        applied = dither.applied(k * DT, plan, previous, health)
        assert _admissible(applied, previous)
        np.testing.assert_allclose(T @ (health * (applied - plan)), 0.0, atol=1e-12 * max(1.0, amplitude))
        # the scale is the largest admissible one: bisection on the bounds written out here
        direction = dither.direction(k * DT, health)
        low, high = 0.0, 1.0
        if _admissible(plan + direction, previous):
            low = 1.0
        for _ in range(60):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if _admissible(plan + middle * direction, previous) else (low, middle)
        scale = dither_scale(direction, plan, previous, BOUNDS, RATES * DT)
        assert scale == pytest.approx(low, abs=1e-6)
        previous = applied


def test_the_dither_is_the_sinusoids_along_the_basis():
    options = DitherOptions(amplitude=4.0, frequencies=(0.2, 0.5))
    dither = NullSpaceDither(T, options, BOUNDS, RATES, DT, t0=1.0)
    basis = null_space_basis(T)
    for t in (1.0, 1.7, 3.3):
        expected = 4.0 * (
            basis[:, 0] * np.sin(2 * np.pi * 0.2 * (t - 1.0)) + basis[:, 1] * np.sin(np.pi * (t - 1.0))
        )
        np.testing.assert_allclose(dither.direction(t), expected, atol=1e-12)
    # one dead thruster of each group leaves a one-dimensional null space: one sinusoid
    health = np.array([0, 1, 1, 1, 1, 1, 1, 1.0])
    assert null_space_basis(T, health).shape[1] == 1


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"amplitude": -1.0}, "amplitude"),
        ({"amplitude": float("nan")}, "amplitude"),
        ({"frequencies": ()}, "frequencies"),
        ({"frequencies": (0.3, 0.0)}, r"frequencies\[1\]"),
        ({"frequencies": "0.3"}, "frequencies"),
    ],
)
def test_bad_dither_options_are_refused_by_name(changes, match):
    with pytest.raises(ValueError, match=match):
        DitherOptions(**changes)


def test_bad_detector_dither_is_refused_by_name():
    with pytest.raises(ValueError, match="dither"):
        uo.FaultDetectorOptions(dither=5.0)


@pytest.fixture(scope="module")
def bench():
    """Return the fault benchmark's survey problem and EKF with a bias (benchmarks/bench_faults.py)."""
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    reference = uo.Reference.lawnmower((0.0, 0.0), width=10.0, spacing=3.0, lanes=3, speed=0.5, depth=2.0)
    problem = uo.TrackingProblem(boat, reference, horizon=10, dt=DT, terminal="cost")
    options = uo.EstimatorOptions(bias=True, bias_std=5.0, compiled=False)
    return problem, uo.Estimator(problem, "ekf", sensors=uo.Sensors.auv(boat), options=options)


#: The benchmark's trial 33: a 50 % loss of thruster 0, which the controller holds saturated after it
LOSS = uo.ThrusterFault(0, 5.88, "loss", effectiveness=0.5)
DIRECTION = float(np.random.default_rng([33, 0]).uniform(0.0, 2.0 * np.pi))


def _trial_run(bench, options, duration):
    """Fly the benchmark's trial 33 (its current and fault) with ``fault_detector=options``."""
    problem, estimator = bench
    # no real-time deadline (the benchmark's): a wall-clock cut of the fallback chain is not repeatable
    run = uo.simulate(
        uo.NMPC(problem, "sqp-rti"),
        problem.initial_state(),
        duration,
        current=uo.Current(speed=0.3, direction=DIRECTION),
        seed=33,
        estimator=estimator,
        faults=(LOSS,),
        fault_detector=options,
    )
    return run, LOSS


def test_amplitude_zero_is_the_loop_without_dither_bit_for_bit(bench):
    plain, _ = _trial_run(bench, uo.FaultDetectorOptions(), 2.0)
    zero, _ = _trial_run(bench, uo.FaultDetectorOptions(dither=DitherOptions(0.0, (0.7,))), 2.0)
    assert zero.dither.size == 0 and plain.dither.size == 0
    for name in ("states", "controls", "estimated_states", "estimated_health"):
        np.testing.assert_array_equal(getattr(zero, name), getattr(plain, name), err_msg=name)
    # the comparison sees a dither of 1 mN (so it would see a change of the loop)
    tiny, _ = _trial_run(bench, uo.FaultDetectorOptions(dither=DitherOptions(1e-3)), 2.0)
    assert not np.array_equal(tiny.controls, plain.controls)


def test_a_constant_command_loss_is_detected_within_2_s_with_the_dither_only(bench):
    """Trial 33: without the dither the saturated thruster's loss is not seen for > 2 s; with it, it is.

    The regression alone (``step_significance=0, increment_period=0``): the change-point test,
    which also sees it within 2 s without a dither, is the next test.
    """
    limit = 2.0
    regression = uo.FaultDetectorOptions(step_significance=0.0, increment_period=0)
    plain, fault = _trial_run(bench, regression, fault_time := 5.88 + limit + 0.5)
    assert not any(row[0] <= fault.time + limit and int(row[1]) == fault.thruster for row in plain.detections)
    options = uo.FaultDetectorOptions(
        dither=DitherOptions(amplitude=5.0), step_significance=0.0, increment_period=0
    )
    dithered, _ = _trial_run(bench, options, fault_time)
    first = dithered.detections[0]
    assert int(first[1]) == fault.thruster and fault.time <= first[0] <= fault.time + limit
    # what the plant got: admissible, the dither wrench-free on the (then healthy) thrusters
    before = dithered.t[:-1] < first[0]
    np.testing.assert_allclose(dithered.dither[before] @ T.T, 0.0, atol=1e-9)
    assert np.all(np.abs(dithered.controls) <= BOUNDS + 1e-9)
    assert np.all(np.abs(np.diff(dithered.controls, axis=0)) <= RATES * DT + 1e-9)
    assert np.max(np.abs(dithered.dither)) > 1.0  # it acted


def test_the_change_point_test_detects_the_saturated_half_loss_within_2_s(bench):
    """Trial 33 with the default detector, no dither: declared on thruster 0 within 2 s, told ≈ 50 %.

    The NMPC holds thruster 0 at its 40 N bound after the fault: a step of the bias the window's
    intercept absorbs (the previous test: the regression alone declares nothing within 2 s).
    Measured 0.7 s after the fault on the benchmark (detector 8), told health 0.50.
    """
    limit = 2.0
    run, fault = _trial_run(bench, uo.FaultDetectorOptions(), 5.88 + limit + 0.5)
    assert run.detections.size, "not declared"
    first = run.detections[0]
    assert int(first[1]) == fault.thruster and fault.time <= first[0] <= fault.time + limit, first
    # a loss at the saturated command: told as a loss near 50 %, or stuck at the same force there
    assert abs(first[2] * 40.0 + first[3] - 20.0) < 6.0, first
