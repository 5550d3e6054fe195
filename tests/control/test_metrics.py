"""Tracking metrics: planar figures for 3-DOF runs, depth and 3-D figures for 6-DOF runs.

Every expected value is computed here from the run's arrays, element by element in plain
Python, not with the package's code.
"""

import math

import numpy as np
import pytest

from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.studies.compare import TrackingRow, format_tracking_table

PLANAR_KEYS = {
    "max_abs_ex", "max_abs_ey", "max_abs_ex_settled", "max_abs_ey_settled", "rms_ex", "rms_ey",
    "std_ex", "std_ey", "var_ex", "var_ey", "solve_time_median", "solve_time_p90",
    "solve_time_max", "solve_time_mean", "failures", "relaxed_steps", "steps", "deadline_misses",
}  # fmt: skip
SPATIAL_KEYS = {
    "max_abs_ez",
    "max_abs_ez_settled",
    "rms_ez",
    "std_ez",
    "var_ez",
    "max_e3d",
    "max_e3d_settled",
    "rms_e3d",
}


def _run(nx: int, steps: int = 40, seed: int = 3) -> ClosedLoopResult:
    """Return a synthetic run: random states about a random reference, dt = 0.25 s from t = 2 s."""
    rng = np.random.default_rng(seed)
    reference = rng.normal(size=(steps + 1, nx))
    states = reference + rng.normal(scale=[0.3] + [0.1] * (nx - 1), size=(steps + 1, nx))
    return ClosedLoopResult(
        t=2.0 + 0.25 * np.arange(steps + 1),
        states=states,
        controls=np.zeros((steps, 6 if nx == 12 else 3)),
        reference=reference,
        solve_times=rng.uniform(0.01, 0.02, steps),
        iterations=np.ones(steps, dtype=int),
        fallback_steps=np.zeros(steps, dtype=bool),
        relaxed_steps=np.zeros(steps, dtype=bool),
        currents=np.zeros((steps + 1, 3 if nx == 12 else 2)),
        statuses=("Solve_Succeeded",) * steps,
        solver="ipopt",
    )


def _expected(values: list[float]) -> dict[str, float]:
    n = len(values)
    mean = sum(values) / n
    return {
        "max_abs": max(abs(v) for v in values),
        "rms": math.sqrt(sum(v * v for v in values) / n),
        "var": sum((v - mean) ** 2 for v in values) / n,
    }


def test_planar_run_keeps_exactly_its_planar_keys():
    metrics = _run(6).metrics()
    assert set(metrics) == PLANAR_KEYS


def test_six_dof_metrics_report_depth_and_3d_errors_from_the_run_arrays():
    run = _run(12)
    settle = 5.0
    metrics = run.metrics(settle_time=settle)
    assert set(metrics) == PLANAR_KEYS | SPATIAL_KEYS
    rows = list(range(len(run.t)))
    settled_rows = [k for k in rows if run.t[k] >= run.t[0] + settle]
    assert 0 < len(settled_rows) < len(rows)
    ez = [float(run.states[k, 2] - run.reference[k, 2]) for k in rows]
    whole = _expected(ez)
    assert metrics["max_abs_ez"] == pytest.approx(whole["max_abs"], rel=1e-12)
    assert metrics["rms_ez"] == pytest.approx(whole["rms"], rel=1e-12)
    assert metrics["var_ez"] == pytest.approx(whole["var"], rel=1e-12)
    assert metrics["std_ez"] == pytest.approx(math.sqrt(whole["var"]), rel=1e-12)
    assert metrics["max_abs_ez_settled"] == pytest.approx(max(abs(ez[k]) for k in settled_rows), rel=1e-12)
    distance = [
        math.sqrt(sum(float(run.states[k, i] - run.reference[k, i]) ** 2 for i in range(3))) for k in rows
    ]
    assert metrics["max_e3d"] == pytest.approx(max(distance), rel=1e-12)
    assert metrics["max_e3d_settled"] == pytest.approx(max(distance[k] for k in settled_rows), rel=1e-12)
    assert metrics["rms_e3d"] == pytest.approx(math.sqrt(sum(d * d for d in distance) / len(rows)), rel=1e-12)
    # the horizontal figures are those of x and y alone
    ex = [float(run.states[k, 0] - run.reference[k, 0]) for k in rows]
    assert metrics["max_abs_ex"] == pytest.approx(_expected(ex)["max_abs"], rel=1e-12)


def test_six_dof_settled_metrics_are_nan_when_nothing_has_settled():
    metrics = _run(12).metrics(settle_time=1e3)
    assert math.isnan(metrics["max_abs_ez_settled"]) and math.isnan(metrics["max_e3d_settled"])
    assert math.isfinite(metrics["max_abs_ez"])


def test_tracking_table_has_depth_columns_for_six_dof_rows_only():
    planar = TrackingRow("s2", "ipopt", _run(6).metrics(), 10.0, 1.0, "")
    spatial_metrics = _run(12).metrics()
    spatial = TrackingRow("s2", "ipopt", spatial_metrics, 10.0, 1.0, "")
    assert "ez" not in format_tracking_table([planar])
    table = format_tracking_table([planar, spatial]).splitlines()
    header = table[0].split()
    assert {"max|ez|", "|ez|t>5", "rms_ez", "max|e|", "rms|e|"} <= set(header)
    cells = table[3].split()
    assert cells[header.index("max|ez|")] == f"{spatial_metrics['max_abs_ez']:.3f}"
    assert cells[header.index("rms|e|")] == f"{spatial_metrics['rms_e3d']:.3f}"
    # the 3-DOF row leaves them blank, under the header's depth titles
    start, end = table[0].index(" max|ez|"), table[0].index(" rms|e|") + len(" rms|e|")
    assert table[2][start:end].strip() == ""
    assert table[3][start:end].split() == [cells[header.index(title)] for title in header[9:14]]
