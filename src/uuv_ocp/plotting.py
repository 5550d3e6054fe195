"""Matplotlib figures of closed-loop runs and solver comparisons, ready for a report.

Tracking figures take one :class:`~uuv_ocp.control.simulation.ClosedLoopResult` or a sequence
of them, labelled by ``labels=`` (default: the solver names, numbered when they repeat):

* :func:`xoy_figure` (and :func:`obstacle_figure`): the path with the reference, keep-out zones
  and, optionally, predicted horizons;
* :func:`error_figure`: ``|e|`` per direction on a logarithmic axis (the sub-millimetre settled
  error is visible next to the start-up transient), or the signed errors with ``log=False``;
* :func:`thrust_figure`: the applied controls against their bounds;
* :func:`state_figure`: heading and velocities (and depth for a 6-DOF vehicle) with the
  reference;
* :func:`estimation_figure`: a run with an estimator: estimated against true current and
  state with ±2σ bands, the normalised innovation of every sensor output, sensor dropouts;
* :func:`comparison_figure`: cost, violation and time per solve of :func:`uuv_ocp.compare`
  rows;
* :func:`closed_loop_animation` and :func:`save_animation`: a closed loop as a GIF or MP4.

Steps solved with the soft terminal constraint, steps where the solver failed (the fallback
control was applied) and steps that missed the backend's deadline are marked in every tracking
figure.  :func:`save_figure` writes PNG, SVG, PDF or EPS chosen by the file suffix;
:func:`save_tracking_figures` writes the four tracking figures at once.

Figures are built with matplotlib's object-oriented API, without pyplot: no backend is chosen
or changed (figures render on machines without a screen, and a notebook's backend is left
alone), no global figure list keeps them alive, and matplotlib is imported only when the
first figure is made, so ``import uuv_ocp`` does not load it.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uuv_ocp.control.simulation import ClosedLoopResult

if TYPE_CHECKING:
    from matplotlib.animation import FuncAnimation
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "AnimationWriterUnavailable",
    "closed_loop_animation",
    "comparison_figure",
    "error_figure",
    "estimation_figure",
    "obstacle_figure",
    "save_animation",
    "save_figure",
    "save_tracking_figures",
    "state_figure",
    "thrust_figure",
    "xoy_figure",
]

#: File suffixes :func:`save_figure` writes, and the format each one selects.
FIGURE_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf", ".eps": "eps", ".ps": "ps"}
#: Smallest ``|e|`` (m, rad) drawn on a logarithmic error axis; exact zeros are drawn there.
ERROR_FLOOR = 1e-10
#: Smallest violation drawn on the comparison figure's logarithmic axis (0 is drawn there).
VIOLATION_FLOOR = 1e-16

# How each kind of marked step is drawn: (attribute of the run, legend text, marker style).
_STEP_MARKS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("relaxed_steps", "soft terminal (relaxed)", {"marker": "s", "fillstyle": "none", "ms": 5}),
    ("fallback_steps", "failed (fallback applied)", {"marker": "X", "ms": 7}),
    ("deadline_steps", "deadline missed", {"marker": "v", "ms": 6}),
)
_UNREACHABLE_TEXT = "path beyond the vehicle's reach"


# ---------------------------------------------------------------------------------- helpers
def _subplots(*grid: int, **options: Any) -> tuple[Figure, Any]:
    """Make a figure (not registered with pyplot) and its axes, as ``pyplot.subplots`` does."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=options.pop("figsize", None))
    return figure, figure.subplots(*grid, **options)


def _as_runs(runs: Sequence[ClosedLoopResult] | ClosedLoopResult) -> list[ClosedLoopResult]:
    """One run or a sequence of them, as a non-empty list (``ValueError`` otherwise)."""
    runs = [runs] if isinstance(runs, ClosedLoopResult) else list(runs)
    if not runs:
        raise ValueError("runs must hold at least one ClosedLoopResult")
    for run in runs:
        if not isinstance(run, ClosedLoopResult):
            raise ValueError(f"runs must be uuv_ocp.ClosedLoopResult objects, got {type(run).__name__}")
    return runs


def run_labels(runs: Sequence[ClosedLoopResult], labels: Sequence[str] | None = None) -> list[str]:
    """Legend labels of ``runs``: ``labels`` if given, else the solver names, numbered if repeated.

    Parameters
    ----------
    runs : sequence of ClosedLoopResult
        The runs, in drawing order.
    labels : sequence of str, optional
        One label per run.

    Returns
    -------
    list of str
        ``labels`` as given, or e.g. ``["fatrop #1", "fatrop #2", "ipopt"]``.

    Raises
    ------
    ValueError
        ``labels`` does not hold one string per run.
    """
    if labels is not None:
        if isinstance(labels, str):
            raise ValueError(f"labels must be a sequence of strings (one per run), got the string {labels!r}")
        labels = list(labels)
        if len(labels) != len(runs) or not all(isinstance(label, str) for label in labels):
            raise ValueError(f"labels must hold one string per run ({len(runs)}), got {labels!r}")
        return labels
    names = [run.solver for run in runs]
    seen: dict[str, int] = {}
    result = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        result.append(f"{name} #{seen[name]}" if names.count(name) > 1 else name)
    return result


def _colours(count: int) -> list[str]:
    """``count`` distinct colours of matplotlib's default cycle (repeating after ten)."""
    return [f"C{index % 10}" for index in range(count)]


def _steps(run: ClosedLoopResult, attribute: str) -> np.ndarray:
    """Return the indices of the steps whose flag ``attribute`` is set (none if absent)."""
    flags = getattr(run, attribute, None)
    if flags is None:
        return np.zeros(0, dtype=int)
    flags = np.asarray(flags, dtype=bool).ravel()[: len(run.t)]
    return np.flatnonzero(flags)


def _mark_steps(axis: Axes, run: ClosedLoopResult, x: np.ndarray, y: np.ndarray, colour: str) -> set[str]:
    """Mark the relaxed, failed and deadline-missed steps of ``run`` at ``(x[k], y[k])``.

    Returns the legend texts of the kinds that were drawn.
    """
    drawn = set()
    for attribute, text, style in _STEP_MARKS:
        steps = _steps(run, attribute)
        steps = steps[steps < len(x)]
        if steps.size:
            axis.plot(x[steps], y[steps], ls="none", color=colour, **style)
            drawn.add(text)
    return drawn


def _mark_legend(axis: Axes, drawn: set[str]) -> None:
    """Legend of the run lines plus one black proxy entry per drawn kind of marked step."""
    from matplotlib.lines import Line2D

    handles, texts = axis.get_legend_handles_labels()
    for _, text, style in _STEP_MARKS:
        if text in drawn:
            handles.append(Line2D([], [], ls="none", color="k", **style))
            texts.append(text)
    axis.legend(handles, texts, loc="best", fontsize="small")


def _shade_unreachable(axes: Sequence[Axes], unreachable_from: float | None, end: float) -> None:
    """Shade ``t >= unreachable_from`` on time axes (the first span carries the legend label)."""
    if unreachable_from is None or not math.isfinite(unreachable_from) or unreachable_from >= end:
        return
    for index, axis in enumerate(axes):
        axis.axvspan(
            unreachable_from,
            end,
            color="tab:red",
            alpha=0.08,
            lw=0,
            label=_UNREACHABLE_TEXT if index == 0 else None,
        )


def _layout(runs: Sequence[ClosedLoopResult]) -> dict[str, int]:
    """Return the indices of the positions (x, y, z), heading (psi) and velocities the runs have.

    By the runs' ``state_roles`` (the vehicle's layout, recorded by ``simulate``; velocities
    keyed by their state names), else by the names x, y, z, psi, u, v, w, r; a run built by
    hand without either is read as a 3-DOF (6 states) or 6-DOF (12) vehicle's.
    """
    nx = runs[0].states.shape[1]
    if any(run.states.shape[1] != nx for run in runs):
        raise ValueError("runs must all have the same state dimension")
    roles = tuple(getattr(runs[0], "state_roles", ()))
    if {"x", "y"} <= set(roles):
        if any(tuple(getattr(run, "state_roles", ())) != roles for run in runs):
            raise ValueError("runs must all have the same state roles (the same vehicle layout)")
        names = tuple(runs[0].state_names)
        by_role = {role: index for index, role in enumerate(roles) if role in ("x", "y", "z", "psi")}
        velocities = {names[index]: index for index, role in enumerate(roles) if role == "velocity"}
        return {**by_role, **velocities}
    names = tuple(getattr(runs[0], "state_names", ()))
    if names:
        if any(tuple(getattr(run, "state_names", ())) not in ((), names) for run in runs):
            raise ValueError("runs must all have the same state names")
        known = ("x", "y", "z", "psi", "u", "v", "w", "r")
        layout = {name: names.index(name) for name in known if name in names}
        if {"x", "y"} <= set(layout):
            return layout
        raise ValueError(f"this figure needs states named x and y, got {names}; plot run.states yourself")
    if nx == 6:
        return {"x": 0, "y": 1, "psi": 2, "u": 3, "v": 4, "r": 5}
    if nx == 12:
        return {"x": 0, "y": 1, "z": 2, "psi": 5, "u": 6, "v": 7, "w": 8, "r": 11}
    raise ValueError(
        f"this figure needs a vehicle state (6 states: 3-DOF, 12: 6-DOF), got {nx} states; "
        "plot an Ocp's own states from run.states"
    )


def _draw_obstacles(axis: Axes, obstacles: Sequence[Any], t: float) -> list[Any]:
    """Draw keep-out zones (and their margins, dotted) where they are at time ``t``."""
    from matplotlib.patches import Ellipse

    patches = []
    for index, obstacle in enumerate(obstacles):
        centre = obstacle.centre_at([t])[0]
        angle = float(np.degrees(obstacle.angle))
        a, b = obstacle.axes
        body = Ellipse(
            centre,
            2 * a,
            2 * b,
            angle=angle,
            color="tab:gray",
            alpha=0.6,
            label="keep-out zone" if index == 0 else None,
        )
        axis.add_patch(body)
        patches.append(body)
        if obstacle.margin > 0:
            margin = 2 * obstacle.margin
            ring = Ellipse(
                centre,
                2 * a + margin,
                2 * b + margin,
                angle=angle,
                fill=False,
                ls=":",
                color="tab:gray",
                label="safety margin" if index == 0 else None,
            )
            axis.add_patch(ring)
            patches.append(ring)
    return patches


def _plan_states(plan: Any) -> np.ndarray:
    """Return the predicted states of a plan: a ``SolveResult`` (its ``states``) or an array."""
    states = np.asarray(getattr(plan, "states", plan), dtype=float)
    if states.ndim != 2 or states.shape[1] < 2:
        raise ValueError(f"a plan must be a SolveResult or an (N+1, nx) array, got shape {states.shape}")
    return states


# ------------------------------------------------------------------------ tracking figures
def xoy_figure(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    title: str = "",
    *,
    labels: Sequence[str] | None = None,
    obstacles: Sequence[Any] = (),
    plans: Sequence[Any] = (),
    unreachable_from: float | None = None,
    obstacle_time: float | None = None,
) -> Figure:
    """Path in the XOY plane: the reference, the runs, keep-out zones and marked steps.

    Parameters
    ----------
    runs : ClosedLoopResult or sequence of ClosedLoopResult
        Closed-loop runs.  The first run's reference is drawn in black; a run on another
        reference gets its own, dashed in the run's colour.
    title : str
        Axes title (default ``"XOY tracking"``).
    labels : sequence of str, optional
        Legend label per run (default: solver names, numbered when they repeat).
    obstacles : sequence of Obstacle
        Keep-out zones, drawn where they are at ``obstacle_time`` (the dotted ring is the zone
        enlarged by its margin); a moving one's track over the first run is drawn dash-dotted.
    plans : sequence of SolveResult or array_like
        Predicted horizons to draw (thin grey lines), e.g. ``StepOutput.result`` of some steps
        of a loop run by hand; a ``ClosedLoopResult`` does not store its plans.
    unreachable_from : float, optional
        Time (s) from which the reference asks for more than the vehicle can give; that part of
        the reference is drawn in red.
    obstacle_time : float, optional
        Time (s) at which the obstacles are drawn (default: the first run's start).

    Returns
    -------
    matplotlib.figure.Figure
        One axes, ``x (m)`` against ``y (m)``, equal scales.
    """
    runs = _as_runs(runs)
    names = run_labels(runs, labels)
    figure, axes = _subplots(figsize=(6.4, 4.8))
    first = runs[0]
    reference = first.reference
    if np.any(np.isfinite(reference[:, :2])):
        axes.plot(reference[:, 0], reference[:, 1], "k--", lw=1.2, label="reference")
        if unreachable_from is not None:
            late = first.t >= unreachable_from
            if np.any(late):
                axes.plot(reference[late, 0], reference[late, 1], "-", color="tab:red", lw=2.5, alpha=0.4)
                axes.plot([], [], "-", color="tab:red", lw=2.5, alpha=0.4, label=_UNREACHABLE_TEXT)
    for index, plan in enumerate(plans):
        states = _plan_states(plan)
        axes.plot(
            states[:, 0],
            states[:, 1],
            "-",
            color="0.55",
            lw=0.7,
            label="predicted horizon" if index == 0 else None,
        )
    _draw_obstacles(axes, obstacles, float(first.t[0] if obstacle_time is None else obstacle_time))
    tracks = [o for o in obstacles if o.is_moving]
    for index, obstacle in enumerate(tracks):
        track = obstacle.centre_at(first.t)
        axes.plot(
            track[:, 0],
            track[:, 1],
            "-.",
            color="tab:gray",
            lw=0.9,
            label="moving obstacle's track" if index == 0 else None,
        )
    drawn: set[str] = set()
    for run, name, colour in zip(runs, names, _colours(len(runs)), strict=True):
        if run is not first and not _same_path(run.reference, reference):
            axes.plot(run.reference[:, 0], run.reference[:, 1], "--", color=colour, lw=0.9, alpha=0.7)
        axes.plot(run.states[:, 0], run.states[:, 1], lw=1.3, color=colour, label=name)
        drawn |= _mark_steps(axes, run, run.states[:, 0], run.states[:, 1], colour)
    axes.plot(*first.states[0, :2], "o", color="tab:green", label="start")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(title or "XOY tracking")
    axes.axis("equal")
    axes.grid(True, alpha=0.3)
    _mark_legend(axes, drawn)
    figure.tight_layout()
    return figure


def _same_path(reference: np.ndarray, other: np.ndarray) -> bool:
    """Whether two sampled references have the same horizontal path (NaN counts as equal)."""
    if reference.shape != other.shape:
        return False
    return bool(np.allclose(reference[:, :2], other[:, :2], equal_nan=True))


def obstacle_figure(
    runs: Sequence[ClosedLoopResult],
    obstacles: Sequence[Any],
    labels: Sequence[str] | None = None,
    title: str = "",
    obstacle_time: float | None = None,
) -> Figure:
    """Paths of closed-loop runs among keep-out zones (enlarged by their margin, dotted).

    :func:`xoy_figure` with ``obstacles``; they are drawn where they are at ``obstacle_time``
    (s; default the first run's start time), moving ones with their track.
    """
    return xoy_figure(
        runs,
        title or "paths among obstacles",
        labels=labels,
        obstacles=obstacles,
        obstacle_time=obstacle_time,
    )


def _wrapped(angle: np.ndarray) -> np.ndarray:
    """Angles in [−π, π)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def error_figure(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    title: str = "",
    *,
    labels: Sequence[str] | None = None,
    log: bool = True,
    heading: bool = True,
    unreachable_from: float | None = None,
) -> Figure:
    """Tracking errors against time: ``|e|`` on a logarithmic axis (default) or signed.

    Parameters
    ----------
    runs : ClosedLoopResult or sequence of ClosedLoopResult
        Runs of a tracking problem (their reference is not NaN).
    title : str
        Title of the top axes (default ``"Tracking error"``).
    labels : sequence of str, optional
        Legend label per run (default: solver names, numbered when they repeat).
    log : bool
        ``True``: ``|e_x|``, ``|e_y|`` (and ``|e_z|`` for a 6-DOF vehicle) in m on logarithmic
        axes, values below ``ERROR_FLOOR`` (1e-10) drawn at it and exact zeros left out
        (unless all are); ``False``: the signed errors on linear axes.
    heading : bool
        Add the wrapped heading error ``e_ψ`` (rad) as the last panel.
    unreachable_from : float, optional
        Shade the times (s) from which the reference is beyond the vehicle's reach.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per direction, sharing the time axis ``t (s)``.

    Raises
    ------
    ValueError
        A run has no reference (a run of an Ocp without one).
    """
    runs = _as_runs(runs)
    names = run_labels(runs, labels)
    layout = _layout(runs)
    for run, name in zip(runs, names, strict=True):
        if not np.any(np.isfinite(run.reference[:, [layout["x"], layout["y"]]])):
            raise ValueError(f"run {name!r} has no reference (an Ocp run): there is no tracking error")
    directions = [("x", "m"), ("y", "m")] + ([("z", "m")] if "z" in layout else [])
    if heading:
        if "psi" not in layout:
            raise ValueError(f"heading=True needs a heading state in the runs, got {sorted(layout)}")
        directions.append(("psi", "rad"))
    figure, axes = _subplots(len(directions), 1, sharex=True, figsize=(6.4, 1.8 + 1.5 * len(directions)))
    drawn: set[str] = set()
    for run, name, colour in zip(runs, names, _colours(len(runs)), strict=True):
        for axis, (state, _) in zip(axes, directions, strict=True):
            error = run.states[:, layout[state]] - run.reference[:, layout[state]]
            if state == "psi":
                error = _wrapped(error)
            if log:  # tiny values drawn at the floor; exact zeros (a start on the path) left out
                values = np.maximum(np.abs(error), ERROR_FLOOR)
                if np.any(error != 0.0):
                    values = np.where(error == 0.0, np.nan, values)
            else:
                values = error
            axis.plot(run.t, values, lw=1.1, color=colour, label=name)
            drawn |= _mark_steps(axis, run, run.t, values, colour)
    for axis, (state, unit) in zip(axes, directions, strict=True):
        symbol = "ψ" if state == "psi" else state
        axis.set_ylabel(f"|e_{symbol}| ({unit})" if log else f"e_{symbol} ({unit})")
        if log:
            axis.set_yscale("log")
        axis.grid(True, which="both" if log else "major", alpha=0.3)
    _shade_unreachable(axes, unreachable_from, max(float(run.t[-1]) for run in runs))
    axes[-1].set_xlabel("t (s)")
    axes[0].set_title(title or "Tracking error")
    _mark_legend(axes[0], drawn)
    figure.tight_layout()
    return figure


def _control_labels(
    nu: int, vehicle: Any, names: Sequence[str] | None, units: Sequence[str] | None
) -> tuple[list[str], list[str]]:
    """Names and units of ``nu`` controls: given, from the vehicle, or by dimension."""
    from uuv_ocp.model.fossen6dof import FORCE_NAMES, FORCE_UNITS
    from uuv_ocp.model.planar import CONTROL_NAMES, CONTROL_UNITS

    # the models own their labels (their layout); by dimension: the 3-DOF or 6-DOF generalised force
    by_dimension = {3: (CONTROL_NAMES, CONTROL_UNITS), 6: (FORCE_NAMES, FORCE_UNITS)}
    if vehicle is not None:
        default_names, default_units = vehicle.layout.control_names, vehicle.layout.control_units
    else:
        default_names, default_units = by_dimension.get(nu, (None, None))
    if names is None:
        names = default_names or tuple(f"u_{index + 1}" for index in range(nu))
    if units is None:
        if default_units is None:
            raise ValueError(f"give units= (one per control) for {nu} controls, or vehicle=")
        units = default_units
    names, units = list(names), list(units)
    if len(names) != nu or len(units) != nu:
        raise ValueError(f"names and units must have one entry per control ({nu}), got {names!r}, {units!r}")
    return names, units


def thrust_figure(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    title: str = "",
    *,
    labels: Sequence[str] | None = None,
    vehicle: Any = None,
    bounds: tuple[Any, Any] | None = None,
    names: Sequence[str] | None = None,
    units: Sequence[str] | None = None,
    unreachable_from: float | None = None,
) -> Figure:
    """Plot the applied controls against time (held over each interval), with their bounds.

    Parameters
    ----------
    runs : ClosedLoopResult or sequence of ClosedLoopResult
        Runs with the same control dimension.
    title : str
        Figure title (default ``"Applied thrust"``).
    labels : sequence of str, optional
        Legend label per run (default: solver names, numbered when they repeat).
    vehicle : VehicleModel, optional
        Gives the control names, units and symmetric bounds (``max_thrust`` or the thrusters'
        bounds).
    bounds : (array_like, array_like), optional
        ``(lower, upper)`` per control, e.g. ``(spec.lower, spec.upper)`` of a problem;
        overrides the vehicle's.
    names, units : sequence of str, optional
        Control names and units (default: the vehicle's; for 3 or 6 controls those of the
        3-DOF and 6-DOF models).
    unreachable_from : float, optional
        Shade the times (s) from which the reference is beyond the vehicle's reach.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per control, ``name (unit)`` against ``t (s)``.
    """
    runs = _as_runs(runs)
    run_names = run_labels(runs, labels)
    nu = runs[0].controls.shape[1]
    if any(run.controls.shape[1] != nu for run in runs):
        raise ValueError("runs must all have the same control dimension")
    names, units = _control_labels(nu, vehicle, names, units)
    if bounds is None and vehicle is not None:
        limit = np.asarray(vehicle.control_bound, dtype=float)
        bounds = (-limit, limit)
    lower = upper = None
    if bounds is not None:
        lower = np.broadcast_to(np.asarray(bounds[0], dtype=float), (nu,))
        upper = np.broadcast_to(np.asarray(bounds[1], dtype=float), (nu,))
    columns = 1 if nu <= 3 else 2
    rows = math.ceil(nu / columns)
    figure, grid = _subplots(
        rows, columns, sharex=True, squeeze=False, figsize=(6.4 * columns, 1.2 + 1.6 * rows)
    )
    axes = list(grid.ravel())
    for spare in axes[nu:]:
        spare.set_visible(False)
    axes = axes[:nu]
    drawn: set[str] = set()
    for run, name, colour in zip(runs, run_names, _colours(len(runs)), strict=True):
        if run.controls.shape[0] == 0:
            continue
        # hold the last control to the end of its interval
        times = run.t[: run.controls.shape[0] + 1]
        held = np.vstack([run.controls, run.controls[-1:]])
        for index, axis in enumerate(axes):
            axis.step(times, held[: len(times), index], where="post", lw=1.0, color=colour, label=name)
            drawn |= _mark_steps(axis, run, times[:-1], run.controls[:, index], colour)
    for index, axis in enumerate(axes):
        if lower is not None and upper is not None:
            for value, text in ((upper[index], "bound"), (lower[index], None)):
                if math.isfinite(value):
                    axis.axhline(value, color="k", ls=":", lw=1.0, label=text)
        axis.set_ylabel(f"{names[index]} ({units[index]})")
        axis.grid(True, alpha=0.3)
    _shade_unreachable(axes, unreachable_from, max(float(run.t[-1]) for run in runs))
    for axis in axes[-columns:]:
        axis.set_xlabel("t (s)")
        axis.xaxis.set_tick_params(labelbottom=True)
    figure.suptitle(title or "Applied thrust")
    _mark_legend(axes[0], drawn)
    figure.tight_layout()
    return figure


_STATE_PANELS = {
    "psi": ("ψ (rad)", "heading"),
    "z": ("z (m)", "depth"),
    "u": ("u (m/s)", "surge"),
    "v": ("v (m/s)", "sway"),
    "w": ("w (m/s)", "heave"),
    "r": ("r (rad/s)", "yaw rate"),
}


def state_figure(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    title: str = "",
    *,
    labels: Sequence[str] | None = None,
    unreachable_from: float | None = None,
) -> Figure:
    """Heading and body-frame velocities (and depth for a vehicle with one) with the reference.

    Parameters
    ----------
    runs : ClosedLoopResult or sequence of ClosedLoopResult
        Runs of one vehicle (its layout's roles find the heading, depth and velocities).
    title : str
        Figure title (default ``"Heading and velocities"``).
    labels : sequence of str, optional
        Legend label per run (default: solver names, numbered when they repeat).
    unreachable_from : float, optional
        Shade the times (s) from which the reference is beyond the vehicle's reach.

    Returns
    -------
    matplotlib.figure.Figure
        ψ (rad), the depth z (m) when the vehicle has one, then every body velocity (3-DOF:
        u, v (m/s), r (rad/s); 6-DOF: u, v, w, p, q, r); against ``t (s)``; the first run's
        reference dashed.
    """
    runs = _as_runs(runs)
    names = run_labels(runs, labels)
    layout = _layout(runs)
    panels: list[str] = [key for key in ("psi", "z") if key in layout]
    panels += [key for key in layout if key not in ("x", "y", "z", "psi")]
    units = dict(zip(getattr(runs[0], "state_names", ()), getattr(runs[0], "state_units", ()), strict=False))
    columns = 2
    rows = math.ceil(len(panels) / columns)
    figure, grid = _subplots(rows, columns, sharex=True, squeeze=False, figsize=(10.0, 1.2 + 1.8 * rows))
    axes = list(grid.ravel())
    first = runs[0]
    drawn: set[str] = set()
    for axis, key in zip(axes, panels, strict=False):
        index = layout[key]
        if np.any(np.isfinite(first.reference[:, index])):
            axis.plot(first.t, first.reference[:, index], "k--", lw=1.0, label="reference")
        for run, name, colour in zip(runs, names, _colours(len(runs)), strict=True):
            axis.plot(run.t, run.states[:, index], lw=1.1, color=colour, label=name)
            drawn |= _mark_steps(axis, run, run.t, run.states[:, index], colour)
        label, panel_title = _STATE_PANELS.get(key, (f"{key} ({units.get(key) or '-'})", key))
        axis.set_ylabel(label)
        axis.set_title(panel_title, fontsize="medium")
        axis.grid(True, alpha=0.3)
    _shade_unreachable(axes[: len(panels)], unreachable_from, max(float(run.t[-1]) for run in runs))
    for spare in axes[len(panels) :]:
        spare.set_visible(False)
    for axis in axes[len(panels) - columns : len(panels)]:
        axis.set_xlabel("t (s)")
        axis.xaxis.set_tick_params(labelbottom=True)
    figure.suptitle(title or "Heading and velocities")
    _mark_legend(axes[0], drawn)
    figure.tight_layout()
    return figure


# ------------------------------------------------------------------------- estimation
#: gid of the lines :func:`estimation_figure` draws, so that a test or a user can find them
ESTIMATE_GIDS = {
    "true": "true",
    "estimate": "estimate",
    "lower": "band_lower",
    "upper": "band_upper",
    "innovation": "innovation",
    "dropout": "dropout",
}


def _estimate_panels(run: ClosedLoopResult, nx: int) -> list[tuple[int, str, str]]:
    """Return (state index, y label, title) of the position, heading and velocity states of ``run``."""
    layout = _layout([run])
    units = dict(zip(run.state_names, run.state_units, strict=False))
    keys: list[str] = [key for key in ("x", "y", "z", "psi") if key in layout]
    keys += [key for key in layout if key not in ("x", "y", "z", "psi")]
    panels = []
    for key in keys:
        if layout[key] >= nx:
            continue
        default = {"x": ("x (m)", "position x"), "y": ("y (m)", "position y")}.get(key)
        label, title = _STATE_PANELS.get(key, default or (f"{key} ({units.get(key) or '-'})", key))
        panels.append((layout[key], label, title))
    return panels


def estimation_figure(run: ClosedLoopResult, title: str = "", *, sigmas: float = 2.0) -> Figure:
    """Draw what the estimator of a closed loop made of its sensors: estimates, bands, innovations.

    Parameters
    ----------
    run : ClosedLoopResult
        A run of :func:`uuv_ocp.simulate` with ``estimator=`` (``run.estimates`` is not ``None``).
    title : str
        Figure title (default ``"State and current estimation"``).
    sigmas : float
        Half-width of the bands in standard deviations, > 0 (default 2: ≈ 95 % for a Gaussian).

    Returns
    -------
    matplotlib.figure.Figure
        Panels against ``t (s)``, three per row:

        * each current component ``c_x, c_y (, c_z)`` (m/s, inertial): the true current
          (black, dashed) and the estimate with the band ``ĉ ± sigmas·√P_cc``;
        * each position, the heading and each velocity (by the run's ``state_roles``; their
          units): the true state and the estimate with ``x̂ ± sigmas·√P_xx``;
        * each sensor: its outputs' innovations normalised by ``√S`` (dimensionless, N(0, 1)
          for a consistent filter; dotted lines at ±``sigmas``), drawn at the steps it
          reported, and its dropouts (a due sample that did not arrive) as red crosses on the
          zero line.  A run saved before ``S`` was recorded gets the raw innovations (the
          outputs' units).

        Every line carries a ``gid`` from :data:`ESTIMATE_GIDS` (``"estimate"``,
        ``"band_lower"``, ``"band_upper"``, ``"true"``, ``"innovation"``, ``"dropout"``).

    Raises
    ------
    ValueError
        ``run`` is not a ClosedLoopResult, has no estimates, or ``sigmas`` is not > 0.
    """
    (run,) = _as_runs(run)
    estimates, measurements = run.estimates, run.measurements
    if estimates is None or measurements is None:
        raise ValueError(
            "run must come from uo.simulate(..., estimator=uo.Estimator(...)): it has no run.estimates"
        )
    if not (isinstance(sigmas, int | float) and not isinstance(sigmas, bool) and math.isfinite(sigmas)):
        raise ValueError(f"sigmas must be a finite number > 0, got {sigmas!r}")
    if sigmas <= 0:
        raise ValueError(f"sigmas must be a finite number > 0, got {sigmas!r}")
    t = estimates.t
    n, nx, nc = t.size, estimates.states.shape[1], estimates.currents.shape[1]
    spread = sigmas * np.sqrt(np.maximum(estimates.variances, 0.0))
    # (true values, estimate, its spread, y label, title) of every estimate panel
    panels: list[tuple[np.ndarray, np.ndarray, np.ndarray, str, str]] = []
    for index in range(nc):
        axis_name = "xyz"[index] if nc <= 3 else str(index + 1)
        truth = run.currents[:n, index] if index < run.currents.shape[1] else np.full(n, np.nan)
        panels.append(
            (
                truth,
                estimates.currents[:, index],
                spread[:, nx + index],
                f"c_{axis_name} (m/s)",
                f"current {axis_name} (inertial)",
            )
        )
    for index, label, panel_title in _estimate_panels(run, nx):
        panels.append(
            (run.states[:n, index], estimates.states[:, index], spread[:, index], label, panel_title)
        )
    sensors = list(zip(measurements.sensors, measurements.sizes, strict=True))
    count = len(panels) + len(sensors)
    columns = 3
    rows = math.ceil(count / columns)
    figure, grid = _subplots(rows, columns, sharex=True, squeeze=False, figsize=(12.0, 1.0 + 2.0 * rows))
    axes = list(grid.ravel())
    band_label = f"±{sigmas:g}σ"
    for axis, (truth, estimate, width, label, panel_title) in zip(axes, panels, strict=False):
        axis.fill_between(
            t, estimate - width, estimate + width, color="C0", alpha=0.2, lw=0, label=band_label
        )
        axis.plot(t, estimate - width, color="C0", lw=0.5, gid=ESTIMATE_GIDS["lower"])
        axis.plot(t, estimate + width, color="C0", lw=0.5, gid=ESTIMATE_GIDS["upper"])
        axis.plot(t, truth, "k--", lw=1.0, label="true", gid=ESTIMATE_GIDS["true"])
        axis.plot(t, estimate, color="C0", lw=1.2, label="estimate", gid=ESTIMATE_GIDS["estimate"])
        axis.set_ylabel(label)
        axis.set_title(panel_title, fontsize="medium")
    variances = estimates.innovation_variances
    normalised = bool(np.any(np.isfinite(variances)))
    offsets = np.concatenate([[0], np.cumsum(measurements.sizes)]).astype(int)
    for number, (axis, (name, size)) in enumerate(zip(axes[len(panels) :], sensors, strict=False)):
        for output in range(size):
            column = offsets[number] + output
            values = estimates.innovations[:, column]
            if normalised:
                values = values / np.sqrt(variances[:, column])
            reported = np.isfinite(values)
            axis.plot(
                t[reported],
                values[reported],
                ".-",
                ms=3,
                lw=0.6,
                color=f"C{output}",
                label=f"output {output + 1}",
                gid=ESTIMATE_GIDS["innovation"],
            )
        dropped = np.flatnonzero(measurements.dropped[:, number])
        if dropped.size:
            axis.plot(
                t[dropped],
                np.zeros(dropped.size),
                "x",
                color="tab:red",
                ms=8,
                mew=2.0,
                zorder=5,  # above the innovations, which pass through the zero line
                label="dropout",
                gid=ESTIMATE_GIDS["dropout"],
            )
        if normalised:
            for level in (-sigmas, sigmas):
                axis.axhline(level, color="k", ls=":", lw=0.8)
        axis.set_ylabel("ν/√S (-)" if normalised else "ν (output units)")
        axis.set_title(f"{name}: {'normalised ' if normalised else ''}innovation", fontsize="medium")
        axis.legend(loc="best", fontsize="x-small")
    for axis in axes[:count]:
        axis.grid(True, alpha=0.3)
    for spare in axes[count:]:
        spare.set_visible(False)
    for axis in axes[max(0, count - columns) : count]:
        axis.set_xlabel("t (s)")
        axis.xaxis.set_tick_params(labelbottom=True)
    if panels:
        axes[0].legend(loc="best", fontsize="small")
    figure.suptitle(title or "State and current estimation")
    figure.tight_layout()
    return figure


# ------------------------------------------------------------------------- comparison
def comparison_figure(rows: Sequence[Any], title: str = "") -> Figure:
    """Cost, largest violation and time per solve of :func:`uuv_ocp.compare` rows, best first.

    Parameters
    ----------
    rows : sequence of ComparisonRow
        Rows of one comparison (each with ``solver``, ``cost``, ``max_violation``,
        ``solve_time``, ``feasible``, ``ratio`` and ``rank``).
    title : str
        Figure title (default ``"Solver comparison"``).

    Returns
    -------
    matplotlib.figure.Figure
        Three panels of horizontal bars sharing the solver axis, in rank order: the judged
        cost (logarithmic when all costs are positive; ``cost/best`` written beside each bar),
        the largest violation (logarithmic, with the feasibility tolerance; 0 drawn at
        ``VIOLATION_FLOOR``) and the wall time of one solve (ms, logarithmic).  Feasible rows
        are blue, infeasible ones red and hatched.
    """
    from matplotlib.patches import Patch

    from uuv_ocp.judge import FEASIBILITY_TOLERANCE

    rows = sorted(rows, key=lambda row: getattr(row, "rank", 0) or 0)
    if not rows:
        raise ValueError("rows must hold at least one ComparisonRow")
    solvers = [row.solver for row in rows]
    position = np.arange(len(rows))[::-1]  # best at the top
    feasible = [bool(getattr(row, "feasible", True)) for row in rows]
    colours = ["tab:blue" if ok else "tab:red" for ok in feasible]
    hatches = ["" if ok else "//" for ok in feasible]
    costs = np.array([row.cost for row in rows], dtype=float)
    violations = np.array([row.max_violation for row in rows], dtype=float)
    times = 1e3 * np.array([row.solve_time for row in rows], dtype=float)
    figure, axes = _subplots(1, 3, sharey=True, figsize=(12.0, 1.6 + 0.45 * len(rows)))
    finite_costs = costs[np.isfinite(costs)]
    log_cost = bool(finite_costs.size) and bool(np.all(finite_costs > 0))
    panels = (
        (axes[0], np.where(np.isfinite(costs), costs, np.nan), "judged cost (objective units)", log_cost),
        (axes[1], np.maximum(violations, VIOLATION_FLOOR), "largest violation (units of its kind)", True),
        (axes[2], np.maximum(times, 1e-6), "time per solve (ms)", True),
    )
    for axis, values, label, log in panels:
        left = np.nanmin(values) / 10.0 if log and np.any(np.isfinite(values)) else 0.0
        bars = axis.barh(position, values - left, left=left, color=colours, alpha=0.8)
        for bar, hatch in zip(bars, hatches, strict=True):
            bar.set_hatch(hatch)
        axis.set_xlabel(label)
        if log:
            axis.set_xscale("log")
        axis.grid(True, axis="x", which="both", alpha=0.3)
    for y, row, cost in zip(position, rows, costs, strict=True):
        ratio = getattr(row, "ratio", math.nan)
        if np.isfinite(cost) and np.isfinite(ratio):
            axes[0].annotate(
                f" ×{ratio:.3g}", (cost, y), va="center", fontsize="small", annotation_clip=False
            )
    axes[1].axvline(
        FEASIBILITY_TOLERANCE, color="k", ls=":", lw=1.0, label=f"tolerance {FEASIBILITY_TOLERANCE:g}"
    )
    axes[0].set_yticks(position, solvers)
    axes[0].set_ylabel("solver (best first)")
    handles = [Patch(color="tab:blue", alpha=0.8, label="feasible")]
    if not all(feasible):
        handles.append(Patch(facecolor="tab:red", alpha=0.8, hatch="//", label="infeasible (ranked after)"))
    tolerance_handles, tolerance_labels = axes[1].get_legend_handles_labels()
    axes[1].legend(
        handles + tolerance_handles,
        [handle.get_label() for handle in handles] + tolerance_labels,
        loc="best",
        fontsize="small",
    )
    figure.suptitle(title or "Solver comparison")
    figure.tight_layout()
    return figure


# -------------------------------------------------------------------------- animation
class AnimationWriterUnavailable(RuntimeError):
    """The writer an animation's file suffix needs is not installed (pillow for GIF, ffmpeg for MP4)."""


def closed_loop_animation(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    *,
    labels: Sequence[str] | None = None,
    obstacles: Sequence[Any] = (),
    stride: int = 1,
    interval: float = 50.0,
    title: str = "",
) -> FuncAnimation:
    """Animate closed-loop paths in the XOY plane (moving obstacles move).

    Parameters
    ----------
    runs : ClosedLoopResult or sequence of ClosedLoopResult
        Runs on the same time grid (frames follow the first run's samples).
    labels : sequence of str, optional
        Legend label per run (default: solver names, numbered when they repeat).
    obstacles : sequence of Obstacle
        Keep-out zones, drawn where they are at each frame's time.
    stride : int
        Samples per frame, >= 1 (``stride=5`` at dt = 0.1 s: one frame per 0.5 s).
    interval : float
        Delay between frames when shown (ms), > 0.
    title : str
        Axes title (default ``"closed loop"``).

    Returns
    -------
    matplotlib.animation.FuncAnimation
        Show it in a notebook with ``IPython.display.HTML(animation.to_jshtml())`` or write it
        with :func:`save_animation`.
    """
    from matplotlib.animation import FuncAnimation

    runs = _as_runs(runs)
    names = run_labels(runs, labels)
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    if not (isinstance(interval, int | float) and math.isfinite(interval) and interval > 0):
        raise ValueError(f"interval must be a finite number > 0 (ms), got {interval!r}")
    figure, axes = _subplots(figsize=(6.4, 4.8))
    first = runs[0]
    if np.any(np.isfinite(first.reference[:, :2])):
        axes.plot(first.reference[:, 0], first.reference[:, 1], "k--", lw=1.0, label="reference")
    patches = _draw_obstacles(axes, obstacles, float(first.t[0]))
    # each obstacle has its body patch and, with a margin, a ring patch: move both
    owners = [o for o in obstacles for _ in range(2 if o.margin > 0 else 1)]
    lines, heads = [], []
    for name, colour in zip(names, _colours(len(runs)), strict=True):
        (line,) = axes.plot([], [], lw=1.3, color=colour, label=name)
        (head,) = axes.plot([], [], "o", color=colour, ms=6)
        lines.append(line)
        heads.append(head)
    every = np.vstack([run.states[:, :2] for run in runs])
    if np.any(np.isfinite(first.reference[:, :2])):
        every = np.vstack([every, first.reference[:, :2]])
    low, high = np.nanmin(every, axis=0), np.nanmax(every, axis=0)
    pad = 0.05 * max(float(np.max(high - low)), 1e-3)
    axes.set_xlim(low[0] - pad, high[0] + pad)
    axes.set_ylim(low[1] - pad, high[1] + pad)
    axes.set_aspect("equal", adjustable="box")
    clock = axes.text(0.02, 0.95, "", transform=axes.transAxes, va="top")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(title or "closed loop")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize="small")
    frames = list(range(0, len(first.t), stride))
    if frames[-1] != len(first.t) - 1:
        frames.append(len(first.t) - 1)

    def update(k: int) -> list[Any]:
        for run, line, head in zip(runs, lines, heads, strict=True):
            end = min(k, len(run.t) - 1)
            line.set_data(run.states[: end + 1, 0], run.states[: end + 1, 1])
            head.set_data(run.states[end : end + 1, 0], run.states[end : end + 1, 1])
        for patch, obstacle in zip(patches, owners, strict=True):
            if obstacle.is_moving:
                patch.set_center(obstacle.centre_at([first.t[k]])[0])
        clock.set_text(f"t = {first.t[k]:.1f} s")
        return [*lines, *heads, *patches, clock]

    update(0)
    return FuncAnimation(figure, update, frames=frames, interval=interval, blit=False)


def save_animation(animation: FuncAnimation, path: str | Path, *, fps: int = 20, dpi: int = 80) -> Path:
    """Write ``animation`` as GIF (pillow) or MP4 (ffmpeg), chosen by the suffix of ``path``.

    Parameters
    ----------
    animation : matplotlib.animation.FuncAnimation
        E.g. from :func:`closed_loop_animation`.
    path : str or Path
        ``*.gif`` or ``*.mp4`` (the folder is created).
    fps : int
        Frames per second, >= 1.
    dpi : int
        Resolution of the frames.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    AnimationWriterUnavailable
        GIF without pillow installed, MP4 without an ``ffmpeg`` on ``PATH``.
    ValueError
        Another suffix, or ``fps`` not an integer >= 1.
    """
    from matplotlib import animation as mpl_animation

    path = Path(path)
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps must be an integer >= 1, got {fps!r}")
    suffix = path.suffix.lower()
    writer: Any
    if suffix == ".gif":
        if importlib.util.find_spec("PIL") is None:
            raise AnimationWriterUnavailable(f"writing {path} needs pillow (pip install pillow)")
        writer = mpl_animation.PillowWriter(fps=fps)
    elif suffix == ".mp4":
        if not mpl_animation.writers.is_available("ffmpeg"):
            raise AnimationWriterUnavailable(
                f"writing {path} needs ffmpeg on PATH (e.g. apt-get install ffmpeg)"
            )
        writer = mpl_animation.FFMpegWriter(fps=fps)
    else:
        raise ValueError(f"an animation is written as .gif or .mp4, got {path.name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    animation.save(str(path), writer=writer, dpi=dpi)
    return path


# ------------------------------------------------------------------------------ output
def save_figure(figure: Figure, path: str | Path, *, dpi: int = 110) -> Path:
    """Write ``figure`` in the format its suffix names (creating the folder); return the path.

    Parameters
    ----------
    figure : matplotlib.figure.Figure
        The figure.
    path : str or Path
        ``*.png`` (raster, at ``dpi``), ``*.svg``, ``*.pdf``, ``*.eps`` or ``*.ps`` (vector).
    dpi : int
        Resolution of PNG output (and of any raster part of vector output).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        A suffix not in ``FIGURE_FORMATS``.
    """
    path = Path(path)
    fmt = FIGURE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"figure path must end in one of {', '.join(FIGURE_FORMATS)}, got {path.name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, format=fmt, dpi=dpi)
    return path


def save_tracking_figures(
    runs: Sequence[ClosedLoopResult] | ClosedLoopResult,
    directory: str | Path,
    *,
    prefix: str = "",
    suffix: str = ".png",
    labels: Sequence[str] | None = None,
    obstacles: Sequence[Any] = (),
    vehicle: Any = None,
    unreachable_from: float | None = None,
) -> dict[str, Path]:
    """Write the path, error, thrust and state figures of ``runs`` into ``directory``.

    Files are ``<prefix>xoy<suffix>``, ``<prefix>errors<suffix>``, ``<prefix>thrust<suffix>``
    and ``<prefix>states<suffix>``; ``suffix`` selects the format as in :func:`save_figure`
    (``".pdf"`` or ``".svg"`` for a report).  The other arguments are those of the figures.

    Returns
    -------
    dict of str to Path
        ``{"xoy": ..., "errors": ..., "thrust": ..., "states": ...}``.
    """
    if suffix.lower() not in FIGURE_FORMATS:
        raise ValueError(f"suffix must be one of {', '.join(FIGURE_FORMATS)}, got {suffix!r}")
    directory = Path(directory)
    figures = {
        "xoy": xoy_figure(runs, labels=labels, obstacles=obstacles, unreachable_from=unreachable_from),
        "errors": error_figure(runs, labels=labels, unreachable_from=unreachable_from),
        "thrust": thrust_figure(runs, labels=labels, vehicle=vehicle, unreachable_from=unreachable_from),
        "states": state_figure(runs, labels=labels, unreachable_from=unreachable_from),
    }
    return {
        name: save_figure(figure, directory / f"{prefix}{name}{suffix}") for name, figure in figures.items()
    }
