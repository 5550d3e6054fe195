"""Tracking metrics as the paper reports them, plus timing statistics.

The paper's Tables 1–4 report, per direction, the maximum absolute tracking error and the
"covariance" (mean square deviation) of the tracking error.  We report both the variance of the
error about its mean (``var_e*``, m²) and its standard deviation (``std_e*``, m) — the paper's
numbers (0.017–0.213 "m") are in metres, so ``std`` is the comparable one — together with the
RMS error and solve-time statistics.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from uuv_ocp.control.simulation import ClosedLoopResult


def tracking_metrics(run: ClosedLoopResult, settle_time: float = 5.0) -> dict[str, float | int]:
    """Metrics of a closed-loop run.

    Parameters
    ----------
    run : ClosedLoopResult
    settle_time : float
        Errors are also reported on ``t >= t[0] + settle_time`` (s), after the start-up
        transient from rest.

    Returns
    -------
    dict
        ``max_abs_ex``, ``max_abs_ey`` (m, whole run); ``max_abs_ex_settled``,
        ``max_abs_ey_settled`` (m, after ``settle_time``); ``rms_ex``, ``rms_ey``, ``std_ex``,
        ``std_ey`` (m); ``var_ex``, ``var_ey`` (m²); ``solve_time_median``, ``solve_time_p90``,
        ``solve_time_max``, ``solve_time_mean`` (s); the counts as ``int``: ``failures``,
        ``relaxed_steps``, ``steps`` and ``deadline_misses`` (steps whose solve the backend's
        deadline stopped or outlasted).
    """
    errors = run.errors
    settled = run.t >= run.t[0] + settle_time - 1e-9
    settled_errors = errors[settled] if np.any(settled) else np.full((1, 2), np.nan)
    times = run.solve_times if run.solve_times.size else np.array([np.nan])
    return {
        "max_abs_ex": float(np.max(np.abs(errors[:, 0]))),
        "max_abs_ey": float(np.max(np.abs(errors[:, 1]))),
        "max_abs_ex_settled": float(np.max(np.abs(settled_errors[:, 0]))),
        "max_abs_ey_settled": float(np.max(np.abs(settled_errors[:, 1]))),
        "rms_ex": float(np.sqrt(np.mean(errors[:, 0] ** 2))),
        "rms_ey": float(np.sqrt(np.mean(errors[:, 1] ** 2))),
        "std_ex": float(np.std(errors[:, 0])),
        "std_ey": float(np.std(errors[:, 1])),
        "var_ex": float(np.var(errors[:, 0])),
        "var_ey": float(np.var(errors[:, 1])),
        "solve_time_median": float(np.median(times)),
        "solve_time_p90": float(np.percentile(times, 90)),
        "solve_time_max": float(np.max(times)),
        "solve_time_mean": float(np.mean(times)),
        "failures": int(run.failures),
        "relaxed_steps": int(np.sum(run.relaxed_steps)),
        "steps": int(run.controls.shape[0]),
        "deadline_misses": int(run.deadline_misses),
    }
