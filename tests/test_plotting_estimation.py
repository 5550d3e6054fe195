"""plotting.estimation_figure: estimates against the truth with ±2σ bands, innovations, dropouts.

One short closed loop with the EKF (3 s, s2, N = 5) is shared by the tests; every line the
figure draws is read back and compared with a computation from the run's own logs and the
sensors' schedule (integer arithmetic on the rates, as docs/estimation.md states it).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp import plotting

DT = 0.1


@pytest.fixture(scope="module")
def estimated_run():
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, uo.Reference.paper("s2"), horizon=5, dt=DT)
    # a DVL that drops 30 % of its samples, so that a 3-s run has dropouts to mark
    sensors = uo.Sensors.auv(vehicle, dvl_dropout=0.3)
    estimator = uo.Estimator(problem, "ekf", sensors=sensors)
    run = uo.simulate(
        uo.NMPC(problem, "ipopt"),
        x0=problem.reference.initial_state(0.0),
        duration=3.0,
        current=uo.Current(0.5, 1.0),
        estimator=estimator,
        seed=3,
        progress=False,
    )
    return run, sensors


def lines(axis, gid):
    return [line for line in axis.get_lines() if line.get_gid() == gid]


def only(axis, gid):
    (line,) = lines(axis, gid)
    return line


def visible_axes(figure):
    return [axis for axis in figure.axes if axis.get_visible()]


def due_steps(rate, steps):
    """Return the steps a sensor of ``rate`` Hz is due: floor(k a) > floor((k-1) a), a = dt·rate exact."""
    a = Fraction(DT).limit_denominator(10**6) * Fraction(rate).limit_denominator(10**6)
    return [k for k in range(steps) if k == 0 or math.floor(k * a) > math.floor((k - 1) * a)]


def test_panels_are_the_current_the_states_by_role_and_one_per_sensor(estimated_run):
    run, sensors = estimated_run
    figure = plotting.estimation_figure(run)
    axes = visible_axes(figure)
    roles = run.state_roles
    state_panels = [i for i, role in enumerate(roles) if role in ("x", "y", "z", "psi", "velocity")]
    nc = run.estimated_currents.shape[1]
    assert len(axes) == nc + len(state_panels) + len(sensors)
    labels = [axis.get_ylabel() for axis in axes]
    assert labels[:nc] == ["c_x (m/s)", "c_y (m/s)"]
    assert labels[nc : nc + 6] == ["x (m)", "y (m)", "ψ (rad)", "u (m/s)", "v (m/s)", "r (rad/s)"]
    assert labels[nc + 6 :] == ["ν/√S (-)"] * len(sensors)
    for axis, name in zip(axes[nc + 6 :], sensors.names, strict=True):
        assert axis.get_title().startswith(name)
        assert len(lines(axis, "innovation")) == sensors.sizes[sensors.names.index(name)]
    for axis in axes[: nc + 6]:
        for gid in ("true", "estimate", "band_lower", "band_upper"):
            assert len(lines(axis, gid)) == 1, (axis.get_ylabel(), gid)
    assert {text.get_text() for text in axes[0].get_legend().get_texts()} == {"±2σ", "true", "estimate"}
    assert all(axis.get_xlabel() == "t (s)" for axis in axes[-3:])


def test_bands_are_the_estimate_plus_minus_two_standard_deviations(estimated_run):
    run, _ = estimated_run
    axes = visible_axes(plotting.estimation_figure(run))
    n, nx = run.estimated_states.shape
    t = run.t[:n]
    # independent of the figure's code: columns by the roles of the vehicle's layout, the
    # augmented covariance's diagonal [x, c] as the run logged it
    layout = uo.Vehicle.rexrov().layout
    order = [layout.state_roles.index(role) for role in ("x", "y", "psi")]
    order += [i for i, role in enumerate(layout.state_roles) if role == "velocity"]
    expected = [(run.currents[:n, i], run.estimated_currents[:, i], nx + i) for i in range(2)]
    expected += [(run.states[:n, i], run.estimated_states[:, i], i) for i in order]
    for axis, (truth, mean, column) in zip(axes, expected, strict=False):
        sigma = np.sqrt(run.estimate_variances[:, column])
        assert np.all(sigma > 0)
        np.testing.assert_allclose(only(axis, "estimate").get_xdata(), t, rtol=0, atol=0)
        np.testing.assert_allclose(only(axis, "estimate").get_ydata(), mean, rtol=1e-15)
        np.testing.assert_allclose(only(axis, "true").get_ydata(), truth, rtol=1e-15)
        np.testing.assert_allclose(
            only(axis, "band_lower").get_ydata(), mean - 2 * sigma, rtol=1e-12, atol=1e-15
        )
        np.testing.assert_allclose(
            only(axis, "band_upper").get_ydata(), mean + 2 * sigma, rtol=1e-12, atol=1e-15
        )
    # sigmas= sets the width
    wide = visible_axes(plotting.estimation_figure(run, sigmas=3.0))[0]
    sigma = np.sqrt(run.estimate_variances[:, nx])
    np.testing.assert_allclose(
        only(wide, "band_upper").get_ydata(), run.estimated_currents[:, 0] + 3 * sigma, rtol=1e-12
    )


def test_innovations_are_normalised_by_the_logged_S(estimated_run):
    run, sensors = estimated_run
    axes = visible_axes(plotting.estimation_figure(run))[-len(sensors) :]
    n = run.innovations.shape[0]
    std = sensors.std
    column = 0
    for axis in axes:
        for line in lines(axis, "innovation"):
            nu, s = run.innovations[:, column], run.innovation_variances[:, column]
            reported = ~np.isnan(run.measurement_values[:, column])
            # S = H P Hᵀ + R: at least the sensor's own noise variance wherever it reported
            assert np.all(s[reported] >= std[column] ** 2 * (1 - 1e-12))
            assert np.all(np.isnan(nu[~reported])) and np.all(np.isnan(s[~reported]))
            np.testing.assert_array_equal(line.get_xdata(), run.t[:n][reported])
            np.testing.assert_allclose(line.get_ydata(), nu[reported] / np.sqrt(s[reported]), rtol=1e-14)
            column += 1
        assert column == sum(sensors.sizes[: sensors.names.index(axis.get_title().split(":")[0]) + 1])


def test_dropouts_are_marked_exactly_where_a_due_sensor_did_not_report(estimated_run):
    run, sensors = estimated_run
    axes = visible_axes(plotting.estimation_figure(run))[-len(sensors) :]
    n = run.measurement_values.shape[0]
    offsets = np.concatenate([[0], np.cumsum(sensors.sizes)])
    marked_somewhere = False
    for number, (axis, sensor) in enumerate(zip(axes, sensors, strict=True)):
        values = run.measurement_values[:, offsets[number] : offsets[number + 1]]
        # due by the schedule and absent from the log: a dropout (independent of the dropped flags)
        expected = [k for k in due_steps(sensor.rate, n) if np.all(np.isnan(values[k]))]
        markers = lines(axis, "dropout")
        if not expected:
            assert markers == [], sensor.name
            continue
        marked_somewhere = True
        (marker,) = markers
        np.testing.assert_array_equal(marker.get_xdata(), run.t[expected])
        np.testing.assert_array_equal(marker.get_ydata(), 0.0)
    assert marked_somewhere  # the 30 % DVL dropped samples in this run (seed 3)


def test_a_run_without_estimates_or_a_bad_width_is_refused_by_name(estimated_run):
    run, _ = estimated_run
    bare = uo.ClosedLoopResult(
        **{key: getattr(run, key) for key in ("t", "states", "controls", "reference", "solve_times")},
        **{key: getattr(run, key) for key in ("iterations", "fallback_steps", "relaxed_steps", "currents")},
        statuses=run.statuses,
        solver=run.solver,
    )
    with pytest.raises(ValueError, match="run must come from uo.simulate"):
        plotting.estimation_figure(bare)
    for bad in (0.0, -1.0, math.inf, True, "2"):
        with pytest.raises(ValueError, match="sigmas must be a finite number > 0"):
            plotting.estimation_figure(run, sigmas=bad)


def test_a_saved_run_keeps_S_and_one_saved_without_it_shows_raw_innovations(estimated_run, tmp_path):
    run, sensors = estimated_run
    run.save(tmp_path / "run.npz")
    loaded = uo.ClosedLoopResult.load(tmp_path / "run.npz")
    np.testing.assert_array_equal(loaded.estimates.innovation_variances, run.innovation_variances)
    data = dict(np.load(tmp_path / "run.npz"))
    del data["innovation_variances"]  # a file written before S was logged
    older = uo.ClosedLoopResult.from_arrays(data)
    assert np.all(np.isnan(older.estimates.innovation_variances))
    axis = visible_axes(plotting.estimation_figure(older))[-1]
    assert axis.get_ylabel() == "ν (output units)"
    line = lines(axis, "innovation")[0]
    gyro = run.innovations[:, -1]
    np.testing.assert_array_equal(line.get_ydata(), gyro[np.isfinite(gyro)])


def test_a_six_dof_run_gets_three_current_components_depth_and_every_velocity():
    """A 6-DOF run made by hand (no solver): panels by the layout's roles, units from it."""
    from uuv_ocp.model import Vehicle6DOF

    layout = Vehicle6DOF.bluerov2_heavy().layout
    sensors = uo.Sensors.auv(layout)
    rng = np.random.default_rng(0)
    n, nx, m = 20, layout.state_dim, sum(sensors.sizes)
    dropped = np.zeros((n, len(sensors)), dtype=bool)
    dropped[[3, 7], 1] = True  # the DVL dropped two samples
    run = uo.ClosedLoopResult(
        t=0.1 * np.arange(n + 1),
        states=rng.standard_normal((n + 1, nx)),
        controls=np.zeros((n, 6)),
        reference=np.zeros((n + 1, nx)),
        solve_times=np.zeros(n),
        iterations=np.zeros(n, dtype=int),
        fallback_steps=np.zeros(n, dtype=bool),
        relaxed_steps=np.zeros(n, dtype=bool),
        currents=rng.standard_normal((n + 1, 3)),
        statuses=("ok",) * n,
        solver="fake",
        state_names=layout.state_names,
        state_units=layout.state_units,
        state_roles=layout.state_roles,
        estimated_states=rng.standard_normal((n, nx)),
        estimated_currents=rng.standard_normal((n, 3)),
        estimate_variances=rng.uniform(0.01, 1.0, (n, nx + 3)),
        innovations=rng.standard_normal((n, m)),
        estimate_times=np.zeros(n),
        innovation_variances=rng.uniform(0.5, 2.0, (n, m)),
        measurement_values=rng.standard_normal((n, m)),
        measurement_dropped=dropped,
        sensor_names=sensors.names,
        sensor_sizes=sensors.sizes,
    )
    axes = visible_axes(plotting.estimation_figure(run))
    labels = [axis.get_ylabel() for axis in axes]
    assert labels[:3] == ["c_x (m/s)", "c_y (m/s)", "c_z (m/s)"]
    assert labels[3:7] == ["x (m)", "y (m)", "z (m)", "ψ (rad)"]
    assert [label.split(" ")[-1] for label in labels[7:13]] == [
        f"({unit})" for unit in layout.state_units[6:]
    ]
    assert len(axes) == 3 + 10 + len(sensors)
    dvl = axes[13 + 1]
    np.testing.assert_array_equal(only(dvl, "dropout").get_xdata(), run.t[[3, 7]])
    depth = axes[-1]
    assert depth.get_title().startswith("depth") and lines(depth, "dropout") == []
    z = axes[5]
    sigma = np.sqrt(run.estimate_variances[:, 2])
    np.testing.assert_allclose(only(z, "band_upper").get_ydata(), run.estimated_states[:, 2] + 2 * sigma)
