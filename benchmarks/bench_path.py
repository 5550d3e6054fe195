"""REMUS 100 lawnmower survey under a current: line-of-sight guidance (the marine baseline).

The survey: ``uo.Reference.lawnmower`` of 4 lanes 150 m long, 60 m apart (turn radius 30 m,
above the REMUS 100's smallest turning radius, about 26 m at 1.5 m/s with the rudder at its
15°), at 10 m depth; commanded speed 1.5 m/s through the water; the vehicle starts at rest on
the first waypoint, heading along the first lane.  The current: mean 0.3 m/s in a direction
drawn from the seed, Gauss–Markov speed and direction noise 0.01 /√s, decay 0.01 /s; unknown to
every row (the guidance takes none; the NMPC rows will say whether theirs is known or estimated).
Every run lasts the survey's length at 1.5 m/s plus 60 s; seeds 0..9 by default.

==================  ====================================================================
row                 controller
==================  ====================================================================
``ilos``            ``uo.LosGuidance`` at its default options (integral LOS, Δ = 10 m, κ = 0.3)
``los``             the same with κ = 0 (plain LOS: a steady offset against a cross current)
``sqp-rti-known``   NMPC path following (``uo.PathFollowingProblem``, N = 20, dt = 0.5 s, RK4 in
                    2 substeps: ``substeps=None``, stable on the REMUS roll mode), ``sqp-rti``, the
                    current known
``ipopt-known``     the same, IPOPT converged at each step
``fatrop-c-known``  the same, compiled fatrop
``sqp-rti-est``     ``sqp-rti``, the current unknown: estimated with the vehicle's states by an
                    EKF (``uo.Estimator(problem, "ekf", sensors=uo.Sensors.auv(vehicle),
                    options=SURVEY_ESTIMATOR)``; the path parameter is the controller's own)
``sqp-rti-ekf0-est`` the same with the EKF at ``uo.EstimatorOptions()`` (a 3-D current of
                    0.01 m/s/√s on every axis, the estimate told as it is: the fins chase it)
``sqp-rti-vert-est`` the same with ``SURVEY_ESTIMATOR``'s per-axis noise but no low-pass (the
                    vertical noise's share of the fix)
``fatrop-est``      the same with fatrop (``fatrop-c-est``: compiled)
``sqp-rti-hpipm-est`` ``sqp-rti-est`` on CasADi's ``hpipm`` QP path (no C step to compile)
``sqp-rti-rateR-est`` ``sqp-rti-est`` with ``PathWeights(rate=R)`` instead of the default 500 (the
                    increments' weight: how the default was chosen)
``sqp-rti-reverse-est`` ``sqp-rti-est`` with ``control_lower = −u_max`` (reverse thrust allowed: no
                    propeller floor)
==================  ====================================================================

:data:`SURVEY_ESTIMATOR`, the ``-est`` rows' EKF: the current's horizontal intensity 0.01 m/s/√s
(the plant's speed noise), the vertical 1e-4 (the plant's current, as the ocean's at survey depth,
is horizontal: with 0.01 the filter makes a vertical current of sensor noise that the stern planes
chase) and the controller told the current low-passed with T = 20 s (its wander step to step,
0.006 m/s per 0.5 s, and its start, 1.27 m/s at t = 0.5 s against 0.3, moved the rudder).  Chosen
on seeds 10 and 11, outside the benchmark's (docs/benchmarks.md).

The NMPC rows use ``PathFollowingProblem``'s defaults (``PathWeights()``: rate 500; the
propeller floored at 0.9 × its cruise speed; ``substeps=None``) unless the row says otherwise.
Each record's configuration holds the controller's settings (weights, substeps, control
bounds, solver and options; the guidance's options), so a record of other settings is recomputed,
never misread.

``--rti`` adds the ``sqp-rti`` step of three vehicles, N = 20 (:func:`rti_step_times`): the
median wall time and the median thread CPU time of a step, and the load before and after.  Read
the CPU column on a loaded machine: the wall median counts the time slices of other processes
once the load passes about twice the cores (the REMUS at 8.5-9.6 ms wall at load 15-17 was
this, docs/benchmarks.md).

Metrics, per run (:func:`uuv_ocp.path_metrics`), then the median over seeds (and the largest
cross-track error over seeds): cross-track RMS and max (m, to the survey path's segments, until
the vehicle passes its end), depth RMS (m), fin activity (deg, ``Σ |Δδ_r| + Σ |Δδ_s|``), energy
(kJ, ``∫ P dt`` of ``uo.Remus100.propeller_power``) and the controller's median step time (µs).

Every run is a checked record (``uuv_ocp.studies.records``: checksummed, written atomically)
in ``--out`` (default ``out/bench_path``): an interrupted benchmark resumes where it stopped,
and a damaged record is recomputed.

Run: ``python -m benchmarks.bench_path [--seeds 10] [--rows ilos,los] [--out DIR] [--rti]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.estimation import SURVEY_CURRENT_FILTER, SURVEY_CURRENT_STD
from uuv_ocp.studies.records import read_record, write_record

DEPTH = 10.0  # m
SPEED = 1.5  # m/s
CURRENT = 0.3  # m/s
LANES, WIDTH, SPACING = 4, 150.0, 60.0  # m
DT = 0.1  # s, the guidance rows' step
NMPC_DT, NMPC_HORIZON = 0.5, 20  # s, intervals: the NMPC rows' step and horizon
EXTRA = 60.0  # s after the survey's length at SPEED (a head current slows it)
PATH_SAMPLE = 0.02  # m between the samples of the path the cross-track error is measured to


def survey() -> tuple[uo.TrackingProblem, np.ndarray]:
    """Return the lawnmower problem (REMUS 100, N = 1: guidance needs no horizon) and the start state."""
    reference = uo.Reference.lawnmower(
        (0.0, 0.0), width=WIDTH, spacing=SPACING, lanes=LANES, speed=SPEED, depth=DEPTH, hold=120.0
    )
    problem = uo.TrackingProblem(uo.Remus100(), reference, horizon=1, dt=DT)
    return problem, reference.initial_state(reference.t_start)


def path_length(problem: uo.TrackingProblem) -> float:
    """Horizontal length (m) of the survey path, summed over its samples."""
    samples = path_samples(problem)
    return float(np.sum(np.linalg.norm(np.diff(samples, axis=0), axis=1)))


def path_samples(problem: uo.TrackingProblem) -> np.ndarray:
    """Return the survey's horizontal path sampled every :data:`PATH_SAMPLE` m or finer, shape (n, 2)."""
    reference = problem.reference
    count = int(math.ceil((reference.t_end - reference.t_start) * SPEED / PATH_SAMPLE)) + 1
    xy = reference.evaluate(np.linspace(reference.t_start, reference.t_end, count))[:, :2]
    moved = np.ones(len(xy), dtype=bool)
    moved[1:] = np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-9
    return xy[moved]


def seeded_current(seed: int) -> uo.Current:
    """Return the current of ``seed``: mean 0.3 m/s, direction drawn from the seed (module doc)."""
    direction = float(np.random.default_rng(2000 + seed).uniform(-math.pi, math.pi))
    return uo.Current(CURRENT, direction, speed_noise=0.01, direction_noise=0.01, decay=0.01)


def metrics(run: uo.ClosedLoopResult, problem: uo.TrackingProblem | uo.PathFollowingProblem) -> dict:
    """Return the run's cross-track, depth, fin and energy figures (:func:`uuv_ocp.path_metrics`)."""
    found = uo.path_metrics(run, problem)
    return {
        "cross_rms": found["cross_track_rms"],
        "cross_max": found["cross_track_max"],
        "depth_rms": found["depth_rms"],
        "fin_deg": math.degrees(found["fin_activity"]),
        "energy_kj": found["energy"] / 1e3,
        "step_us": float(1e6 * np.median(run.solve_times)),
        "completed": found["completed"],
    }


Start = tuple[uo.Controller, np.ndarray]


def _guidance(kappa: float | None) -> Callable[[uo.TrackingProblem, np.ndarray], Start]:
    def make(problem: uo.TrackingProblem, start: np.ndarray) -> Start:
        options = uo.LosOptions(speed=SPEED) if kappa is None else uo.LosOptions(speed=SPEED, kappa=kappa)
        return uo.LosGuidance(problem, options), start

    return make


def path_problem(
    reference: uo.Reference,
    horizon: int = NMPC_HORIZON,
    weights: uo.PathWeights | None = None,
    control_lower: tuple[float, ...] | None = None,
) -> uo.PathFollowingProblem:
    """Return the NMPC rows' problem: REMUS 100 following the survey, N = 20, dt = 0.5 s."""
    return uo.PathFollowingProblem(
        uo.Remus100(),
        reference,
        speed=SPEED,
        horizon=horizon,
        dt=NMPC_DT,
        weights=weights,
        control_lower=control_lower,
    )


#: ``control_lower`` of the ``-reverse`` rows: the vehicle's own bounds (no propeller floor)
REVERSE = tuple(-bound for bound in uo.Remus100().control_bound)


@dataclasses.dataclass(frozen=True)
class _Nmpc:
    """An NMPC row: the solver, its options and the problem's non-default settings."""

    solver: str
    options: dict | None = None
    weights: uo.PathWeights | None = None
    control_lower: tuple[float, ...] | None = None
    estimator: uo.EstimatorOptions | None = None

    def __call__(self, problem: uo.TrackingProblem, start: np.ndarray) -> Start:
        following = path_problem(problem.reference, weights=self.weights, control_lower=self.control_lower)
        return uo.NMPC(following, solver=self.solver, options=self.options), following.initial_state(start)


def _nmpc(
    solver: str,
    options: dict | None = None,
    weights: uo.PathWeights | None = None,
    control_lower: tuple[float, ...] | None = None,
    estimator: uo.EstimatorOptions | None = None,
) -> Callable[[uo.TrackingProblem, np.ndarray], Start]:
    return _Nmpc(solver, options, weights, control_lower, estimator)


#: the ``-est`` rows' EKF options (module doc): horizontal current noise of the plant's intensity,
#: a vertical one 100× smaller, the controller told the current low-passed with T = 20 s
SURVEY_ESTIMATOR = uo.EstimatorOptions(current_std=SURVEY_CURRENT_STD, current_filter=SURVEY_CURRENT_FILTER)


def settings(row: str, controller: uo.Controller) -> dict:
    """Return the controller's settings a record is written for (module doc): weights, bounds, options."""
    problem = controller.problem
    if isinstance(controller, uo.LosGuidance):
        return {"guidance": repr(controller.options)}
    made = ROWS[row]
    assert isinstance(made, _Nmpc) and isinstance(problem, uo.PathFollowingProblem)
    estimated = {"estimator": repr(estimator_options(row))} if row.endswith(ESTIMATED) else {}
    return {
        **estimated,
        "solver": made.solver,
        "options": repr(made.options),
        "weights": repr(problem.weights),
        "substeps": problem.substeps,
        "horizon": problem.horizon,
        "control_lower": repr(problem.control_lower),
    }


#: Row name -> ``(survey problem, start state) -> (controller, its start state)``.
ROWS: dict[str, Callable[[uo.TrackingProblem, np.ndarray], Start]] = {
    "ilos": _guidance(None),
    "los": _guidance(0.0),
    "sqp-rti-known": _nmpc("sqp-rti"),
    "ipopt-known": _nmpc("ipopt"),
    "fatrop-c-known": _nmpc("fatrop", {"compiled": True}),
    "sqp-rti-est": _nmpc("sqp-rti"),
    "sqp-rti-ekf0-est": _nmpc("sqp-rti", estimator=uo.EstimatorOptions()),
    "sqp-rti-vert-est": _nmpc("sqp-rti", estimator=uo.EstimatorOptions(current_std=SURVEY_CURRENT_STD)),
    "sqp-rti-hpipm-est": _nmpc("sqp-rti", {"qpsol": "hpipm"}),
    "sqp-rti-rate1-est": _nmpc("sqp-rti", weights=uo.PathWeights(rate=1.0)),
    "sqp-rti-rate100-est": _nmpc("sqp-rti", weights=uo.PathWeights(rate=100.0)),
    "sqp-rti-rate2000-est": _nmpc("sqp-rti", weights=uo.PathWeights(rate=2000.0)),
    "sqp-rti-reverse-est": _nmpc("sqp-rti", control_lower=REVERSE),
    "fatrop-est": _nmpc("fatrop"),
    "fatrop-c-est": _nmpc("fatrop", {"compiled": True}),
}
#: rows whose current is unknown to the NMPC and estimated (an EKF on ``uo.Sensors.auv``)
ESTIMATED = ("-est",)


def estimator_of(row: str, controller: uo.Controller) -> uo.Estimator | None:
    """Return the EKF of an ``-est`` row on the controller's problem (vehicle states, current)."""
    if not row.endswith(ESTIMATED):
        return None
    problem = controller.problem
    options = estimator_options(row)
    return uo.Estimator(problem, "ekf", sensors=uo.Sensors.auv(problem.vehicle), options=options)


def estimator_options(row: str) -> uo.EstimatorOptions:
    """Return the EKF options of an ``-est`` row: its own, else :data:`SURVEY_ESTIMATOR`."""
    made = ROWS[row]
    own = made.estimator if isinstance(made, _Nmpc) else None
    return SURVEY_ESTIMATOR if own is None else own


def run_row(row: str, seeds: int, out: Path) -> list[dict[str, float]]:
    """Run (or read back) ``row`` for seeds ``0..seeds-1``; the metrics of each seed."""
    problem, start = survey()
    duration = path_length(problem) / SPEED + EXTRA
    controller, x0 = ROWS[row](problem, start)
    estimator = estimator_of(row, controller)
    measured = controller.problem if isinstance(controller.problem, uo.PathFollowingProblem) else problem
    found = []
    for seed in range(seeds):
        config = {"bench": "path", "row": row, "seed": seed, "duration": duration, "dt": DT}
        config.update(settings(row, controller), estimated=estimator is not None)
        path = out / f"{row}-{seed:02d}.npz"
        saved = read_record(path, config)
        if saved is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # the window's end: hold=120 s covers it
                run = uo.simulate(
                    controller, x0, duration, current=seeded_current(seed), seed=seed, estimator=estimator
                )
            write_record(path, run, config)
        else:
            run = saved[0]
        found.append(metrics(run, measured))
    return found


def table(results: dict[str, list[dict[str, float]]]) -> str:
    """Markdown table: medians over seeds (cross-track max: also the largest over seeds)."""
    head = [
        "row",
        "cross-track RMS m",
        "cross-track max m (worst seed)",
        "depth RMS m",
        "fin activity deg",
        "energy kJ",
        "step µs",
        "seeds done",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row, runs in results.items():

        def median(key: str, runs: list[dict[str, float]] = runs) -> float:
            return float(np.median([r[key] for r in runs]))

        worst = max(r["cross_max"] for r in runs)
        done = sum(int(r["completed"]) for r in runs)
        lines.append(
            f"| {row} | {median('cross_rms'):.3f} | {median('cross_max'):.2f} ({worst:.2f}) | "
            f"{median('depth_rms'):.3f} | {median('fin_deg'):.1f} | {median('energy_kj'):.2f} | "
            f"{median('step_us'):.0f} | {done}/{len(runs)} |"
        )
    return "\n".join(lines)


class _CpuTimedNmpc(uo.NMPC):
    """``uo.NMPC`` that also records each step's thread CPU time (s) in :attr:`cpu_times`.

    The closed loop's ``solve_times`` are wall clock: on a shared machine a step the scheduler
    preempts counts the other processes' time slice too (measured: REMUS steps of 1.0 ms CPU
    took 4-9 ms wall, quantised in slices, at load 8-10), so past a load of about twice the
    cores the median wall step measures the load, not the step.
    """

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.cpu_times: list[float] = []

    def step(self, *args: object, **kwargs: object) -> uo.StepRecord:
        start = time.thread_time()
        record = super().step(*args, **kwargs)  # type: ignore[arg-type]
        self.cpu_times.append(time.thread_time() - start)
        return record


def rti_step_times(duration: float = 30.0) -> list[tuple[str, int, float, float, int]]:
    """Median ``sqp-rti`` step (ms, wall and thread CPU), N = 20, of three vehicles' closed loops.

    Rows ``(vehicle, states, median wall ms, median CPU ms, fallback steps)``: the RexROV (6
    states) on s2, dt = 0.1 s, from the reference's start; the BlueROV2 Heavy (12) on the
    survey of ``examples/bluerov2_depth.py`` (dt = 0.1 s, from rest 0.5 m above it); the REMUS
    100 (12, and the path parameter) following this benchmark's survey (dt = 0.5 s, seed 0's
    current, known).  The first steps, which build the step, are excluded (the median of the
    rest).  The CPU time is the calling thread's (the step runs there): unlike the wall time it
    does not count the time slices of other processes when the machine is loaded
    (:class:`_CpuTimedNmpc`).
    """
    from uuv_ocp.model import Vehicle6DOF

    rows = []
    rexrov = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=NMPC_HORIZON, dt=0.1)
    survey_6dof = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.3, depth=2.0)
    bluerov = uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), survey_6dof, horizon=NMPC_HORIZON, dt=0.1)
    dive = survey_6dof.initial_state(survey_6dof.t_start)
    dive[2] -= 0.5
    problem, start = survey()
    remus = path_problem(problem.reference)
    cases: tuple[tuple[str, int, uo.TrackingProblem | uo.PathFollowingProblem, np.ndarray, dict], ...] = (
        ("RexROV (s2)", 6, rexrov, rexrov.reference.initial_state(0.0), {}),
        ("BlueROV2 Heavy (survey)", 12, bluerov, dive, {}),
        ("REMUS 100 (path following)", 12, remus, remus.initial_state(start), {"current": seeded_current(0)}),
    )
    for name, size, case, x0, extra in cases:
        controller = _CpuTimedNmpc(case, solver="sqp-rti")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            run = uo.simulate(controller, x0, duration, seed=0, **extra)
        settled = slice(5, len(run.solve_times))  # the first steps build and compile the step
        wall = float(1e3 * np.median(run.solve_times[settled]))
        cpu = float(1e3 * np.median(controller.cpu_times[settled]))
        rows.append((name, size, wall, cpu, int(run.fallback_steps.sum())))
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (resuming from ``--out``) and print its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--out", type=Path, default=Path("out/bench_path"))
    parser.add_argument("--rti", action="store_true", help="also the sqp-rti step of three vehicles")
    arguments = parser.parse_args(argv)
    rows = tuple(arguments.rows.split(","))
    unknown = sorted(set(rows) - set(ROWS))
    if unknown:
        parser.error(f"--rows must be among {list(ROWS)}, got {unknown}")
    if arguments.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {arguments.seeds}")
    arguments.out.mkdir(parents=True, exist_ok=True)
    results = {row: run_row(row, arguments.seeds, arguments.out) for row in rows}
    print(table(results))
    if arguments.rti:
        print(f"\nload before: {os.getloadavg()[0]:.2f}")
        print(
            "| vehicle | states | sqp-rti step ms, wall (median, N = 20) | CPU ms (median) "
            "| fallback steps |\n"
            "|---|---|---|---|---|"
        )
        for name, size, wall, cpu, fallbacks in rti_step_times():
            print(f"| {name} | {size} | {wall:.2f} | {cpu:.2f} | {fallbacks} |")
        print(f"load after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
