"""Figures of the paper reproduction that :mod:`uuv_ocp.plotting` does not have.

* :func:`convergence_factor_figure` — the paper's Figure 5: ``a(t)`` of GWO (linear), IGWO
  (cosine) and the two other shapes, with the decay rate ``−da/dt`` underneath;
* :func:`xy_time_figure` — the paper's Figures 7a/8a: ``x(t)`` and ``y(t)`` with the reference;
* :func:`error_distribution_figure` — Figure 9: histograms of ``e_x`` and ``e_y`` over trials;
* :func:`reference_grid_figure` — Figure 10: one XOY panel per reference;
* :func:`solve_time_figure` — solve time per step of every solver (box plot, log axis).

Like :mod:`uuv_ocp.plotting` they use matplotlib's object-oriented API (no pyplot, no backend
change) and import matplotlib only when called.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.optimize.schedules import PAPER_CONVERGENCE_LABELS, convergence_factor

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "convergence_factor_figure",
    "error_distribution_figure",
    "reference_grid_figure",
    "solve_time_figure",
    "xy_time_figure",
]


def _figure(
    rows: int, cols: int, *, figsize: tuple[float, float] = (6.4, 4.8), sharex: bool = False
) -> tuple[Figure, np.ndarray]:
    from matplotlib.figure import Figure

    figure = Figure(figsize=figsize)
    axes = figure.subplots(rows, cols, squeeze=False, sharex=sharex)
    return figure, axes


def convergence_factor_figure(iterations: int = 500) -> Figure:
    """Figure 5: the convergence factors ``a(t)`` and their decay rates over ``T`` iterations.

    Parameters
    ----------
    iterations : int
        Iteration budget ``T`` (the paper's Figure 5 uses 500).

    Returns
    -------
    matplotlib.figure.Figure
        Top: ``a(t)`` for the shapes of :data:`~uuv_ocp.optimize.schedules.CONVERGENCE_FACTORS`,
        labelled with the paper's names; bottom: ``−da/dt`` (per iteration, central differences).
    """
    figure, axes = _figure(2, 1, sharex=True, figsize=(6.4, 5.6))
    t = np.linspace(0.0, iterations, 2001)
    names = {"linear": "GWO", "cosine": "IGWO"}
    for kind, label in PAPER_CONVERGENCE_LABELS.items():
        a = np.asarray(convergence_factor(t, iterations, kind))
        text = f"{label} ({names[kind]})" if kind in names else label
        width = 2.2 if kind in names else 1.0
        axes[0, 0].plot(t, a, lw=width, label=text)
        axes[1, 0].plot(t, -np.gradient(a, t), lw=width, label=text)
    axes[0, 0].set_ylabel("convergence factor a")
    axes[0, 0].set_title(f"Convergence factors (paper Figure 5), T = {iterations}")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].set_ylabel("decay rate −da/dt (1/iteration)")
    axes[1, 0].set_xlabel("iteration t")
    for axis in axes[:, 0]:
        axis.grid(True, alpha=0.3)
    figure.tight_layout()
    return figure


def xy_time_figure(run: ClosedLoopResult, title: str = "") -> Figure:
    """Figures 7a/8a: ``x(t)`` and ``y(t)`` of a run against the reference.

    Parameters
    ----------
    run : ClosedLoopResult
        A tracking run.
    title : str
        Title of the top panel.
    """
    figure, axes = _figure(2, 1, sharex=True, figsize=(6.4, 4.8))
    for axis, column, name in ((axes[0, 0], 0, "x"), (axes[1, 0], 1, "y")):
        axis.plot(run.t, run.reference[:, column], "k--", lw=1.2, label="reference")
        axis.plot(run.t, run.states[:, column], lw=1.3, label=run.solver)
        axis.set_ylabel(f"{name} (m)")
        axis.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[0, 0].set_title(title or "x/y state tracking")
    axes[1, 0].set_xlabel("t (s)")
    figure.tight_layout()
    return figure


def error_distribution_figure(runs: Mapping[str, Sequence[ClosedLoopResult]], bins: int = 40) -> Figure:
    """Figure 9: the distribution of ``e_x`` and ``e_y`` over every sample of every trial.

    Parameters
    ----------
    runs : mapping of str to sequence of ClosedLoopResult
        Panel row label (e.g. ``"s1 (case I)"``) to the trials pooled in that row.
    bins : int
        Histogram bins.
    """
    figure, axes = _figure(len(runs), 2, figsize=(6.4, 2.4 * len(runs) + 0.6))
    for row, (label, trials) in enumerate(runs.items()):
        errors = np.concatenate([trial.errors for trial in trials])
        for column, name in enumerate("xy"):
            axis = axes[row, column]
            axis.hist(errors[:, column], bins=bins, color=f"C{column}", alpha=0.8)
            axis.set_title(f"{label}: e_{name}, {len(trials)} trials", fontsize=9)
            axis.set_xlabel(f"e_{name} (m)")
            axis.grid(True, alpha=0.3)
        axes[row, 0].set_ylabel("samples")
    figure.tight_layout()
    return figure


def reference_grid_figure(
    runs: Mapping[str, ClosedLoopResult], unreachable_from: Mapping[str, float | None] | None = None
) -> Figure:
    """Figure 10: one XOY panel per reference with the run and the reference.

    Parameters
    ----------
    runs : mapping of str to ClosedLoopResult
        Reference name to a run on it.
    unreachable_from : mapping of str to float or None, optional
        Time (s) from which a reference is beyond the vehicle's top speed; that part of the
        reference is drawn in red.
    """
    count = len(runs)
    cols = min(count, 4)
    rows = -(-count // cols)
    figure, axes = _figure(rows, cols, figsize=(3.0 * cols + 0.4, 2.7 * rows + 0.4))
    for axis in axes.flat[count:]:
        axis.set_visible(False)
    for axis, (name, run) in zip(axes.flat, runs.items(), strict=False):
        axis.plot(run.reference[:, 0], run.reference[:, 1], "k--", lw=1.0, label="reference")
        late = (unreachable_from or {}).get(name)
        if late is not None and np.any(run.t >= late):
            mask = run.t >= late
            axis.plot(run.reference[mask, 0], run.reference[mask, 1], "-", color="tab:red", lw=2.5, alpha=0.4)
        axis.plot(run.states[:, 0], run.states[:, 1], lw=1.2, label=run.solver)
        axis.set_title(name, fontsize=9)
        axis.set_xlabel("x (m)", fontsize=8)
        axis.set_ylabel("y (m)", fontsize=8)
        axis.tick_params(labelsize=7)
        axis.grid(True, alpha=0.3)
    axes.flat[0].legend(fontsize=7)
    figure.tight_layout()
    return figure


def solve_time_figure(times: Mapping[str, np.ndarray]) -> Figure:
    """Solve time per step of every solver: a box plot (whiskers 5–95 %) on a log axis.

    Parameters
    ----------
    times : mapping of str to numpy.ndarray
        Solver name to its solve times per step (s), pooled over trials.
    """
    figure, axes = _figure(1, 1, figsize=(6.4, 3.6))
    axis = axes[0, 0]
    names = list(times)
    data = [1e3 * np.asarray(times[name], dtype=float) for name in names]
    axis.boxplot(data, whis=(5, 95), showfliers=False)
    axis.set_xticks(range(1, len(names) + 1), names, rotation=20, fontsize=8)
    axis.set_yscale("log")
    axis.set_ylabel("solve time per step (ms)")
    axis.set_title("Solve time per step (box 25–75 %, whiskers 5–95 %)")
    axis.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    return figure
