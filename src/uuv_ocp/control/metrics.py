"""Tracking metrics as the paper reports them, plus timing statistics.

The paper's Tables 1–4 report, per direction, the maximum absolute tracking error and the
"covariance" (mean square deviation) of the tracking error.  We report both the variance of the
error about its mean (``var_e*``, m²) and its standard deviation (``std_e*``, m) — the paper's
numbers (0.017–0.213 "m") are in metres, so ``std`` is the comparable one — together with the
RMS error and solve-time statistics.

A 6-DOF run (12 states ``[x, y, z, φ, θ, ψ, ...]``) is not planar: its metrics add the same
figures for the depth error ``e_z = z − z_R`` and for the 3-D position error ``|e| =
sqrt(e_x² + e_y² + e_z²)``.  A 3-DOF run's metrics keep exactly their planar keys, so records
written before stay comparable.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

#: Number of states of a 6-DOF vehicle run (``[x, y, z, φ, θ, ψ, u, v, w, p, q, r]``).
SPATIAL_STATES = 12

if TYPE_CHECKING:
    from uuv_ocp.control.simulation import ClosedLoopResult


def position_errors(run: ClosedLoopResult) -> np.ndarray:
    """Position errors of a run (m): ``[e_x, e_y]``, or ``[e_x, e_y, e_z]`` for a 6-DOF run.

    Parameters
    ----------
    run : ClosedLoopResult

    Returns
    -------
    numpy.ndarray, shape (n+1, 2) or (n+1, 3)
        Plant position minus reference position at each sample time, found by the state
        roles the run records (the vehicle's layout's positions), else by the state names
        ``x``, ``y``, ``z``; the depth column ``z − z_R`` (z down) only for a vehicle with a
        third position.  A run without roles or names is read by its width (12 states: 6-DOF).
    """
    roles = tuple(getattr(run, "state_roles", ()))
    if {"x", "y"} <= set(roles):  # the vehicle's layout, recorded by simulate
        columns = [roles.index(role) for role in ("x", "y", "z") if role in roles]
        return run.states[:, columns] - run.reference[:, columns]
    names = tuple(getattr(run, "state_names", ()))
    if names and {"x", "y"} <= set(names):  # a run saved before roles were recorded
        columns = [names.index(name) for name in ("x", "y", "z") if name in names]
        return run.states[:, columns] - run.reference[:, columns]
    # a run built by hand without names: a 3-DOF or 6-DOF vehicle's state, by its length
    width = 3 if run.states.shape[1] == SPATIAL_STATES else 2
    return run.states[:, :width] - run.reference[:, :width]


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
        deadline stopped or outlasted).  A 6-DOF run (12 states) adds the depth error
        ``e_z = z − z_R``: ``max_abs_ez``, ``max_abs_ez_settled``, ``rms_ez``, ``std_ez`` (m),
        ``var_ez`` (m²); and the 3-D position error ``|e|`` (Euclidean norm of ``e_x, e_y,
        e_z``): ``max_e3d``, ``max_e3d_settled``, ``rms_e3d`` (m).
    """
    errors = position_errors(run)
    settled = run.t >= run.t[0] + settle_time - 1e-9
    settled_errors = errors[settled] if np.any(settled) else np.full((1, errors.shape[1]), np.nan)
    times = run.solve_times if run.solve_times.size else np.array([np.nan])
    x, y = (_axis_metrics(axis, errors[:, i], settled_errors[:, i]) for i, axis in enumerate("xy"))
    # the planar keys in their historical order, x before y for each figure
    metrics: dict[str, float | int] = {}
    for x_key, y_key in zip(x, y, strict=True):
        metrics.update({x_key: x[x_key], y_key: y[y_key]})
    metrics.update(
        {
            "solve_time_median": float(np.median(times)),
            "solve_time_p90": float(np.percentile(times, 90)),
            "solve_time_max": float(np.max(times)),
            "solve_time_mean": float(np.mean(times)),
            "failures": int(run.failures),
            "relaxed_steps": int(np.sum(run.relaxed_steps)),
            "steps": int(run.controls.shape[0]),
            "deadline_misses": int(run.deadline_misses),
        }
    )
    if errors.shape[1] == 3:
        metrics.update(_axis_metrics("z", errors[:, 2], settled_errors[:, 2]))
        distance = np.linalg.norm(errors, axis=1)
        metrics["max_e3d"] = float(np.max(distance))
        metrics["max_e3d_settled"] = float(np.max(np.linalg.norm(settled_errors, axis=1)))
        metrics["rms_e3d"] = float(np.sqrt(np.mean(distance**2)))
    return metrics


def _axis_metrics(axis: str, error: np.ndarray, settled: np.ndarray) -> dict[str, float]:
    """Return the five error figures of one direction (m, and m² for the variance)."""
    return {
        f"max_abs_e{axis}": float(np.max(np.abs(error))),
        f"max_abs_e{axis}_settled": float(np.max(np.abs(settled))),
        f"rms_e{axis}": float(np.sqrt(np.mean(error**2))),
        f"std_e{axis}": float(np.std(error)),
        f"var_e{axis}": float(np.var(error)),
    }
