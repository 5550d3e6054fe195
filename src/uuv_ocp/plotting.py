"""Matplotlib figures of closed-loop runs (paper Figs. 7–12 style).

Functions return a :class:`matplotlib.figure.Figure`; ``save_figure`` writes it as PNG.
Figures are built with matplotlib's object-oriented API, without pyplot: no backend is chosen
or changed (figures render on machines without a screen, and a notebook's backend is left
alone), no global figure list keeps them alive, and matplotlib is imported only when the
first figure is made, so ``import uuv_ocp`` does not load it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uuv_ocp.control.simulation import ClosedLoopResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["error_figure", "obstacle_figure", "save_figure", "xoy_figure"]


def _subplots(*grid: int, **options: Any) -> tuple[Figure, Any]:
    """Make a figure (not registered with pyplot) and its axes, as ``pyplot.subplots`` does."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=options.pop("figsize", None))
    return figure, figure.subplots(*grid, **options)


def xoy_figure(runs: Sequence[ClosedLoopResult] | ClosedLoopResult, title: str = "") -> Figure:
    """Path in the XOY plane: reference and one or more closed-loop runs."""
    runs = [runs] if isinstance(runs, ClosedLoopResult) else list(runs)
    figure, axes = _subplots(figsize=(6.4, 4.8))
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
    figure, axes = _subplots(2, 1, sharex=True, figsize=(6.4, 4.8))
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


def save_figure(figure: Figure, path: str | Path) -> Path:
    """Write ``figure`` as PNG (creating the folder) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    return path


def obstacle_figure(
    runs: Sequence[ClosedLoopResult],
    obstacles: Sequence[Any],
    labels: Sequence[str] | None = None,
    title: str = "",
) -> Figure:
    """Paths of closed-loop runs among keep-out zones (enlarged by their margin, dashed).

    Moving obstacles are drawn where they are at the first run's start time.
    """
    import numpy as np
    from matplotlib.patches import Ellipse

    figure, axes = _subplots(figsize=(7.2, 4.8))
    first = runs[0]
    axes.plot(first.reference[:, 0], first.reference[:, 1], "k--", lw=1.0, label="reference")
    for run, label in zip(runs, labels or [run.solver for run in runs], strict=True):
        axes.plot(run.states[:, 0], run.states[:, 1], lw=1.3, label=label)
    for obstacle in obstacles:
        centre = obstacle.centre_at([first.t[0]])[0]
        angle = float(np.degrees(obstacle.angle))
        a, b = obstacle.axes
        axes.add_patch(Ellipse(centre, 2 * a, 2 * b, angle=angle, color="tab:gray", alpha=0.6))
        if obstacle.margin > 0:
            margin = 2 * obstacle.margin
            axes.add_patch(
                Ellipse(
                    centre, 2 * a + margin, 2 * b + margin, angle=angle, fill=False, ls=":", color="tab:gray"
                )
            )
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(title or "paths among obstacles")
    axes.axis("equal")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize="small")
    figure.tight_layout()
    return figure
