"""Steady motion against linear plus quadratic damping, shared by the 3-DOF and 6-DOF models."""

from __future__ import annotations

import numpy as np


def steady_speed(linear_damping: object, quadratic_damping: object, force: object) -> np.ndarray:
    """Speed ``s >= 0`` per axis at which ``d_lin s + d_quad s² = force`` (m/s or rad/s).

    Computed as ``2 F / (d_lin + sqrt(d_lin² + 4 d_quad F))``: no cancellation when the linear
    damping dominates, ``F / d_lin`` without quadratic damping, ``inf`` without any damping.
    Arguments broadcast (magnitudes: N·s/m, N·s²/m², N, or their rotational counterparts).
    """
    d_lin = np.asarray(linear_damping, dtype=float)
    d_quad = np.asarray(quadratic_damping, dtype=float)
    tau = np.asarray(force, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        speed = 2.0 * tau / (d_lin + np.sqrt(d_lin**2 + 4.0 * d_quad * tau))
    return np.where(np.isfinite(speed), speed, np.inf)
