"""Reproduction jobs: track the paper's references and tabulate the results.

Every finished run is written as a checked record (:mod:`uuv_ocp.studies.records`) to
``<out>/runs/<reference>_<solver>_<key>.npz`` before the next one starts, ``key`` a hash of the
run's whole configuration (vehicle, reference, solver and options, horizon, dt, duration, start
time, package version).  An interrupted job loses at most the run in progress; a rerun reuses
the records of the same configuration only, and recomputes one that fails its checks (a
:class:`~uuv_ocp.studies.records.RecordWarning` names it); ``fresh=True`` recomputes all.
"""

from __future__ import annotations

import hashlib
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._version import __version__
from uuv_ocp.build import Transcribed
from uuv_ocp.control.disturbances import Current
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.control.simulation import SimulationInterrupted, simulate
from uuv_ocp.estimation.base import Estimator, available_estimators
from uuv_ocp.estimation.sensors import Sensors
from uuv_ocp.interrupts import check_interrupt, remember_interrupts
from uuv_ocp.judge import FEASIBILITY_TOLERANCE, instance_parameters, score_terms
from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.plotting import estimation_figure, save_figure, save_tracking_figures
from uuv_ocp.reference.path import PAPER_REFERENCES, Reference
from uuv_ocp.solvers import REGISTRY, get_solver
from uuv_ocp.studies.records import config_key, read_record, write_record
from uuv_ocp.tracking import ReferenceSpeedWarning, TrackingProblem

AnyVehicle = Vehicle | Vehicle6DOF


@dataclass(frozen=True)
class TrackingRow:
    """One line of the tracking table."""

    reference: str
    solver: str
    metrics: dict
    duration: float
    reference_speed_max: float
    note: str
    #: what the controller was given: ``"oracle"`` (the true state, and the true current when
    #: there is one) or the name of the estimator of state and current (``"ekf"``, ...)
    loop: str = "oracle"


def unreachable_from(reference: Reference, vehicle: AnyVehicle, t0: float, duration: float) -> float | None:
    """First time (s) on ``[t0, t0 + duration]`` at which the path is faster than the vehicle.

    The top speed is over ground with crabbing allowed (:meth:`Vehicle.max_horizontal_speed`:
    surge and sway thrust together, the Munk moment held by the yaw thrust; for a 6-DOF
    vehicle :meth:`Vehicle6DOF.max_horizontal_speed`, level at constant depth), the physical
    limit of position tracking; the surge-only figure (``max_speed()[0]``) is lower.  ``None``
    when the path stays within reach, or for a vehicle and reference that do not pair (a
    planar reference for a 6-DOF vehicle or the other way round).
    """
    return _reach(reference, vehicle, t0, duration)[1]


def _reach(
    reference: Reference, vehicle: AnyVehicle, t0: float, duration: float
) -> tuple[float, float | None, str]:
    """Largest path speed (m/s), :func:`unreachable_from` and the note, from one sampling of the path."""
    times = np.linspace(t0, t0 + duration, 3001)
    states = reference.evaluate(times)
    columns = (6, 7) if reference.spatial else (3, 4)  # body-frame horizontal velocity (u_R, v_R)
    speed = np.hypot(states[:, columns[0]], states[:, columns[1]])
    kind = "spatial" if reference.spatial else "planar"
    if kind != vehicle.layout.reference or not hasattr(vehicle, "max_horizontal_speed"):  # no top speed
        return float(speed.max()), None, ""
    top, crab = vehicle.max_horizontal_speed()
    over = times[speed > top]
    if not over.size:
        return float(speed.max()), None, ""
    start = float(over[0])
    note = (
        f"path speed > {top:.2f} m/s (top speed, crabbing at {np.degrees(crab):.0f}°) from t = {start:.1f} s"
    )
    return float(speed.max()), start, note


def run_settings(
    problem: TrackingProblem,
    solver: str,
    options: dict | None,
    t0: float,
    duration: float,
    current: Current | None = None,
    estimator: str | None = None,
) -> dict:
    """Return the whole configuration of one :func:`track_references` run (its record's key).

    A ``current`` and an ``estimator`` (with its sensors) enter only when given, so that the
    keys of oracle runs stay those that earlier versions wrote.
    """
    reference = problem.reference
    times = np.linspace(t0, t0 + duration + problem.horizon * problem.dt, 257)
    samples = np.ascontiguousarray(reference.evaluate(np.minimum(times, reference.t_end)), dtype=float)
    return {
        "vehicle": problem.vehicle,
        "reference": reference.name,
        "reference_content": hashlib.sha256(samples.tobytes()).hexdigest(),
        "solver": solver,
        "solver_options": options or {},
        "horizon": problem.horizon,
        "dt": problem.dt,
        "terminal": problem.terminal,
        "t0": t0,
        "duration": duration,
        "version": __version__,
        **({"current": current} if current is not None else {}),
        **({"estimator": estimator, "sensors": "auv"} if estimator is not None else {}),
    }


def track_references(
    names: Sequence[str | Reference] = PAPER_REFERENCES,
    solver: str = "ipopt",
    *,
    duration: float = 30.0,
    horizon: int = 20,
    dt: float = 0.1,
    vehicle: AnyVehicle | None = None,
    out_dir: str | Path = "out",
    fresh: bool = False,
    progress: bool = True,
    figures: bool = True,
    solver_options: dict | None = None,
    current: Current | None = None,
    estimator: str | None = None,
    prefix: str = "",
) -> list[TrackingRow]:
    """Closed-loop NMPC on each reference (paper name or :class:`Reference`) from rest; resumable.

    ``current`` acts on the plant (``None``: still water).  Without ``estimator`` the loop is
    the oracle: the controller gets the true state and is told the current.  With
    ``estimator`` (a name of :func:`uuv_ocp.available_estimators`, e.g. ``"ekf"``) the current
    is unknown to the controller: it gets the state and the current that estimator infers
    from the vehicle's sensor suite :meth:`Sensors.auv <uuv_ocp.Sensors.auv>` (position fix,
    DVL with dropouts, attitude, gyro; depth on a 6-DOF vehicle), seeded with 0.

    Returns one :class:`TrackingRow` per reference and, when ``figures`` is true, writes
    ``<prefix><ref>_xoy.png``, ``_errors.png``, ``_thrust.png`` and ``_states.png`` into
    ``out_dir``, the part of the run where the path is faster than the vehicle shaded, and
    with an estimator ``<prefix><ref>_estimation.png``
    (:func:`~uuv_ocp.plotting.estimation_figure`).
    """
    if estimator is not None and estimator not in available_estimators():
        raise ValueError(f"estimator must be one of {available_estimators()} or None, got {estimator!r}")
    vehicle = vehicle or Vehicle.rexrov()
    out_dir = Path(out_dir)
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    with remember_interrupts():  # a Ctrl-C CasADi swallows while a problem is built (uuv_ocp.interrupts)
        for item in names:
            check_interrupt()
            reference = item if isinstance(item, Reference) else Reference.paper(item)
            name = reference.name
            problem = TrackingProblem(vehicle, reference, horizon=horizon, dt=dt)
            t0 = reference.t_start
            run_duration = min(duration, problem.latest_start() - t0)
            settings = run_settings(problem, solver, solver_options, t0, run_duration, current, estimator)
            label = re.sub(
                r"[^A-Za-z0-9_.-]+", "-", f"{name}_{solver}"
            )  # a file name whatever the path's name
            loop = estimator or "oracle"
            path = runs_dir / f"{label}_{config_key(settings)[:12]}.npz"
            saved = (
                None if fresh else read_record(path, settings, steps=int(np.floor(run_duration / dt + 1e-9)))
            )
            if saved is not None:
                run = saved[0]
            else:
                controller = NMPC(problem, solver, options=solver_options)
                estimation: dict[str, Any] = {}
                if estimator is not None:
                    estimation = {
                        "estimator": Estimator(problem, estimator, sensors=Sensors.auv(vehicle)),
                        "seed": 0,
                    }
                with warnings.catch_warnings():  # the row's note says it (_reach)
                    warnings.simplefilter("ignore", ReferenceSpeedWarning)
                    try:
                        run = simulate(
                            controller,
                            problem.initial_state(t0),
                            run_duration,
                            current=current,
                            progress=progress,
                            label=f"{name} {solver}" + (f" {estimator}" if estimator else ""),
                            **estimation,
                        )
                    except SimulationInterrupted as stop:  # the unfinished run is not saved
                        raise KeyboardInterrupt(
                            f"interrupted during {name}; finished runs are in {runs_dir}"
                        ) from stop
                write_record(path, run, settings)
            speed_max, unreachable, note = _reach(reference, vehicle, t0, run_duration)
            if figures:
                save_tracking_figures(
                    run,
                    out_dir,
                    prefix=f"{prefix}{name}_",
                    labels=[f"{name} {solver}" + (f", {estimator}" if estimator else "")],
                    vehicle=vehicle,
                    unreachable_from=unreachable,
                )
                if estimator is not None:
                    figure = estimation_figure(run, f"{name}: {estimator} estimates, current unknown")
                    save_figure(figure, out_dir / f"{prefix}{name}_estimation.png")
            rows.append(TrackingRow(name, solver, run.metrics(), run_duration, speed_max, note, loop))
    return rows


def format_tracking_table(rows: Sequence[TrackingRow]) -> str:
    """Plain-text table of :func:`track_references` rows (errors in m, times in ms).

    When a row is a 6-DOF run (its metrics have the depth error ``max_abs_ez``), the table
    also has the depth columns ``max|ez|``, ``|ez|t>5``, ``rms_ez`` and the 3-D position error
    ``max|e|``, ``rms|e|`` (blank on 3-DOF rows).
    """
    columns = [
        ("ref", 4, lambda r: r.reference),
        ("solver", 7, lambda r: r.solver),
    ]
    if any(row.loop != "oracle" for row in rows):  # what each controller was given
        columns += [("loop", 6, lambda r: r.loop)]
    columns += [
        ("T(s)", 5, lambda r: f"{r.duration:.1f}"),
        ("max|ex|", 8, lambda r: f"{r.metrics['max_abs_ex']:.3f}"),
        ("max|ey|", 8, lambda r: f"{r.metrics['max_abs_ey']:.3f}"),
        ("|ex|t>5", 9, lambda r: _fmt(r.metrics["max_abs_ex_settled"])),
        ("|ey|t>5", 9, lambda r: _fmt(r.metrics["max_abs_ey_settled"])),
        ("rms_ex", 7, lambda r: f"{r.metrics['rms_ex']:.3f}"),
        ("rms_ey", 7, lambda r: f"{r.metrics['rms_ey']:.3f}"),
    ]
    if any("max_abs_ez" in row.metrics for row in rows):  # 6-DOF: depth and 3-D errors
        columns += [
            ("max|ez|", 8, lambda r: _spatial(r, "max_abs_ez", "{:.3f}")),
            ("|ez|t>5", 9, lambda r: _spatial(r, "max_abs_ez_settled")),
            ("rms_ez", 7, lambda r: _spatial(r, "rms_ez", "{:.3f}")),
            ("max|e|", 7, lambda r: _spatial(r, "max_e3d", "{:.3f}")),
            ("rms|e|", 7, lambda r: _spatial(r, "rms_e3d", "{:.3f}")),
        ]
    columns += [
        ("med ms", 7, lambda r: f"{1e3 * r.metrics['solve_time_median']:.2f}"),
        ("p90 ms", 7, lambda r: f"{1e3 * r.metrics['solve_time_p90']:.2f}"),
        ("fail", 4, lambda r: str(int(r.metrics["failures"]))),
        ("soft", 4, lambda r: str(int(r.metrics["relaxed_steps"]))),
    ]
    header = " ".join(f"{title:>{width}}" for title, width, _ in columns) + "  note"
    lines = [header, "-" * len(header)]
    for row in rows:
        cells = " ".join(f"{cell(row):>{width}}" for _, width, cell in columns)
        lines.append(f"{cells}  {row.note}")
    return "\n".join(lines)


def _spatial(row: TrackingRow, key: str, style: str | None = None) -> str:
    """Return a 6-DOF figure of ``row`` (``style``, or :func:`_fmt`); blank for a 3-DOF row."""
    if key not in row.metrics:
        return ""
    value = float(row.metrics[key])
    return style.format(value) if style is not None else _fmt(value)


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        return "nan"
    return f"{value:.2e}" if value < 1e-2 else f"{value:.3f}"


@dataclass(frozen=True)
class ComparisonRow:
    """One solver on one instance, judged by :func:`uuv_ocp.score`.

    Parameters
    ----------
    solver : str
    cost : float
        Objective from the common judge.
    max_violation : float
        Largest violation of any kind.
    solve_time : float
        Wall time of one solve (s).
    evaluations : int
    success : bool
        The backend's own verdict.
    ratio : float
        ``cost`` divided by the best feasible cost of the comparison (:func:`cost_ratio`: 1 for
        a cost equal to a best cost of 0, ``inf`` for a larger one).
    history : numpy.ndarray or None
        Best fitness per iteration (swarms).
    violations : dict
        Largest violation per kind: ``terminal`` (terminal-equality residual, the state's units:
        m, rad, m/s, rad/s), ``bound`` and ``rate`` (excess as a fraction of the control box
        half-width: 0.01 = 1 %), ``constraint`` (other hard constraints, their own units, e.g.
        m² for circular obstacles).
    feasible : bool
        Every violation within ``FEASIBILITY_TOLERANCE`` (1e-6).
    rank : int
        1 for the best: feasible rows by cost first, then infeasible rows by violation.
    """

    solver: str
    cost: float
    max_violation: float
    solve_time: float
    evaluations: int
    success: bool
    ratio: float
    history: np.ndarray | None
    violations: dict = field(default_factory=dict)
    feasible: bool = True
    rank: int = 0


def compare(
    problem: Transcribed,
    solvers: Sequence[str],
    *,
    x0: object,
    t0: float = 0.0,
    seed: int = 0,
    options: dict[str, dict] | None = None,
    u_prev: object | None = None,
    current: object | None = None,
    parameters: dict[str, object] | None = None,
) -> list[ComparisonRow]:
    """Solve one instance of any problem with every named solver; ``ratio`` is cost / best cost.

    ``solvers`` names at least one solver; ``seed`` is an integer >= 0 (``ValueError``
    otherwise, before anything runs).  A best cost of 0 (the instance starts on a reference it
    can keep, e.g. a held pose) gives ratios 1 and ``inf`` (:func:`cost_ratio`).  Each solver
    is built (and, for NLPs, run once) before timing, so ``solve_time`` is the
    steady-state cost of one solve.  Swarms get ``seed``.  The instance is given as in
    :func:`uuv_ocp.solve` (``t0``, ``u_prev``, ``current`` for tracking problems,
    ``parameters`` for an :class:`~uuv_ocp.ocp.Ocp`).
    """
    if isinstance(solvers, str) or not isinstance(solvers, Sequence) or not solvers:
        raise ValueError(
            f"solvers must be a non-empty list of solver names, e.g. ['ipopt'], got {check.shown(solvers)}"
        )
    check.positive_int("seed", seed, minimum=0)  # numpy's own error would not name it
    for name in solvers:
        REGISTRY.factory(name)  # unknown names raise before anything runs
    p = instance_parameters(problem, x0, t0, u_prev=u_prev, current=current, parameters=parameters)
    results, kinds = [], []
    for name in solvers:
        solver_options = dict((options or {}).get(name, {}))
        backend = get_solver(problem, name, solver_options or None)
        backend.solve(p, None, np.random.default_rng(seed))  # build outside the timing
        result = backend.solve(p, None, np.random.default_rng(seed))
        results.append(result)
        kinds.append(score_terms(problem, problem.scaled_from_controls(result.controls), p)[1])
    feasible = [
        max(k.values()) <= FEASIBILITY_TOLERANCE and np.isfinite(r.cost)
        for r, k in zip(results, kinds, strict=True)
    ]
    finite = [r.cost for r, ok in zip(results, feasible, strict=True) if ok] or [
        r.cost for r in results if np.isfinite(r.cost)
    ]
    best = min(finite) if finite else math.nan
    order = sorted(
        range(len(results)),
        key=lambda i: (not feasible[i], results[i].cost if feasible[i] else results[i].max_violation),
    )
    rank = {index: position + 1 for position, index in enumerate(order)}
    return [
        ComparisonRow(
            r.solver,
            r.cost,
            r.max_violation,
            r.solve_time,
            r.evaluations,
            r.success,
            cost_ratio(r.cost, best),
            r.history,
            violations=k,
            feasible=ok,
            rank=rank[i],
        )
        for i, (r, k, ok) in enumerate(zip(results, kinds, feasible, strict=True))
    ]


def cost_ratio(cost: float, best: float) -> float:
    """``cost / best``; a best cost of 0 gives 1 for a cost of 0 and ``±inf`` for any other.

    A held pose started on the reference costs exactly 0 for every solver that holds it; the
    plain quotient raised ``ZeroDivisionError`` there (issue 31).  NaN stays NaN.
    """
    if best == 0.0:
        return 1.0 if cost == 0.0 else math.copysign(math.inf, cost) if cost == cost else math.nan
    return cost / best


def format_comparison(rows: Sequence[ComparisonRow]) -> str:
    """Plain-text table of :func:`compare` rows, best first (feasible rows by cost, then the rest).

    Violations per kind: ``term`` the terminal-equality residual (state units), ``box %`` and
    ``rate %`` the excess in percent of the control box half-width, ``constr`` other hard
    constraints (their own units); ``feas`` says whether all are within 1e-6.
    """
    header = (
        f"{'#':>2} {'solver':<14}{'cost':>13}{'cost/best':>10}{'feas':>5}{'term':>10}{'box %':>10}"
        f"{'rate %':>10}{'constr':>10}{'time ms':>9}{'evals':>8}{'ok':>4}"
    )
    lines = [header]
    for row in sorted(rows, key=lambda r: r.rank or 0):
        v = row.violations
        lines.append(
            f"{row.rank:>2} {row.solver:<14}{row.cost:>13.6g}{row.ratio:>10.3g}"
            f"{'y' if row.feasible else 'n':>5}"
            f"{v.get('terminal', math.nan):>10.2e}{100 * v.get('bound', math.nan):>10.2e}"
            f"{100 * v.get('rate', math.nan):>10.2e}{v.get('constraint', math.nan):>10.2e}"
            f"{1e3 * row.solve_time:>9.2f}{row.evaluations:>8d}{'y' if row.success else 'n':>4}"
        )
    return "\n".join(lines)
