"""Matplotlib figures of closed-loop runs (paper Figs. 7–12 style).

Functions return the :class:`matplotlib.figure.Figure`; ``save_figure`` writes it and closes it.
The non-interactive Agg backend is used so that figures render on machines without a screen.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from uuv_ocp.control.simulation import ClosedLoopResult  # noqa: E402


def xoy_figure(runs: Sequence[ClosedLoopResult] | ClosedLoopResult, title: str = "") -> Figure:
    """Path in the XOY plane: reference and one or more closed-loop runs."""
    runs = [runs] if isinstance(runs, ClosedLoopResult) else list(runs)
    figure, axes = plt.subplots(figsize=(6.4, 4.8))
    axes.plot(runs[0].reference[:, 0], runs[0].reference[:, 1], "k--", lw=1.5, label="reference")
    for run in runs:
        axes.plot(run.states[:, 0], run.states[:, 1], lw=1.2, label=run.solver)
    axes.plot(*runs[0].states[0, :2], "o", color="tab:green", label="start")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(title or "XOY tracking")
    axes.axis("equal")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best")
    figure.tight_layout()
    return figure


def error_figure(runs: Sequence[ClosedLoopResult] | ClosedLoopResult, title: str = "") -> Figure:
    """Tracking errors e_x and e_y (m) against time (s)."""
    runs = [runs] if isinstance(runs, ClosedLoopResult) else list(runs)
    figure, axes = plt.subplots(2, 1, sharex=True, figsize=(6.4, 4.8))
    for run in runs:
        errors = run.errors
        axes[0].plot(run.t, errors[:, 0], lw=1.2, label=run.solver)
        axes[1].plot(run.t, errors[:, 1], lw=1.2, label=run.solver)
    axes[0].set_ylabel("e_x (m)")
    axes[1].set_ylabel("e_y (m)")
    axes[1].set_xlabel("t (s)")
    for axis in axes:
        axis.grid(True, alpha=0.3)
        axis.legend(loc="best")
    axes[0].set_title(title or "Tracking error")
    figure.tight_layout()
    return figure


def controls_figure(run: ClosedLoopResult, bounds: Sequence[float] | None = None) -> Figure:
    """Applied generalised thrust F_u, F_v (N) and F_r (N·m) against time (s)."""
    figure, axes = plt.subplots(3, 1, sharex=True, figsize=(6.4, 5.6))
    labels = ("F_u (N)", "F_v (N)", "F_r (N·m)")
    for index, axis in enumerate(axes):
        axis.step(run.t[:-1], run.controls[:, index], where="post", lw=1.2)
        if bounds is not None:
            axis.axhline(bounds[index], color="k", ls=":", lw=1)
            axis.axhline(-bounds[index], color="k", ls=":", lw=1)
        axis.set_ylabel(labels[index])
        axis.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t (s)")
    figure.tight_layout()
    return figure


def convergence_factor_figure(iterations: int = 30) -> Figure:
    """The paper's Figure 5: convergence-factor schedules a(t) of GWO variants."""
    t = np.linspace(0.0, iterations, 200)
    ratio = t / iterations
    figure, axes = plt.subplots(figsize=(6.4, 4.0))
    axes.plot(t, 2 - 2 * ratio, label="linear_a (GWO)")
    axes.plot(t, 2 * (1 - ratio**2), label="non_linear_a_1")
    axes.plot(t, 2 * (1 - ratio) ** 2, label="non_linear_a_2")
    axes.plot(t, 1 + np.cos(np.pi * ratio), label="non_linear_a_3 (IGWO, cosine)")
    axes.set_xlabel("iteration t")
    axes.set_ylabel("a(t)")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best")
    figure.tight_layout()
    return figure


def save_figure(figure: Figure, path: str | Path) -> Path:
    """Write ``figure`` as PNG (creating the folder) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
