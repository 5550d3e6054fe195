"""A REMUS 100 flies a lawnmower survey at 10 m depth under a cross current: NMPC vs ILOS.

The survey of ``benchmarks/bench_path.py`` (lanes 150 m long, 60 m apart, 10 m deep, 1.5 m/s;
``--lanes`` sets how many): the same REMUS 100 (one propeller, a rudder, stern planes; it
cannot move sideways) flies it twice under the same 0.3 m/s current, once steered by
integral line-of-sight guidance (``uo.LosGuidance``, the marine baseline; told nothing of the
current) and once by NMPC path following (``uo.PathFollowingProblem``, N = 20, dt = 0.5 s;
its prediction model is told the current, or with ``--estimate`` an EKF estimates it from the
AUV's sensors).  Both start on the first waypoint at the survey speed, headed along the first lane.

Printed: per controller, the cross-track RMS and max (m), depth RMS (m), fin activity
``Σ|Δδ|`` (deg), propeller energy (kJ) and the median controller step (ms), by
``uo.path_metrics``.  Figures (``--out``, default
``docs/images``): the horizontal path, the depth, the fin angles and the propeller speed.

Run: ``python examples/remus_survey.py`` (``--quick``: 30 s of the first lane, for the tests).
"""

from __future__ import annotations

import argparse
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import uuv_ocp as uo

DEPTH, SPEED = 10.0, 1.5  # m, m/s
WIDTH, SPACING = 150.0, 60.0  # m: lane length, lane spacing (turn radius 30 m)
CURRENT = uo.Current(0.3, math.pi / 2)  # m/s, toward east: across the north-going first lane


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns: the two closed loops and their figures (the tests check them)."""

    survey: uo.TrackingProblem
    following: uo.PathFollowingProblem
    runs: dict[str, uo.ClosedLoopResult]
    errors: dict[str, np.ndarray]  # signed cross-track error (m) of each run's states
    figures: tuple[Path, ...]


def main(
    duration: float | None = None,
    lanes: int = 2,
    solver: str = "ipopt",
    out: Path | str = "docs/images",
    estimate: bool = False,
) -> Outcome:
    """Fly the survey with ILOS and with NMPC for ``duration`` s (default: the whole survey)."""
    reference = uo.Reference.lawnmower(
        (0.0, 0.0), width=WIDTH, spacing=SPACING, lanes=lanes, speed=SPEED, depth=DEPTH, hold=120.0
    )
    survey = uo.TrackingProblem(uo.Remus100(), reference, horizon=1, dt=0.1)
    following = uo.PathFollowingProblem(uo.Remus100(), reference, speed=SPEED, horizon=20, dt=0.5)
    start = reference.initial_state(reference.t_start)
    start[6] = SPEED  # surge: already under way (the survey, not the launch)
    if duration is None:  # the path's length at the survey speed, and a minute to spare
        duration = (reference.t_end - reference.t_start - 120.0) + 60.0
    runs = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the survey window's end: the hold covers it
        runs["ILOS"] = uo.simulate(
            uo.LosGuidance(survey, uo.LosOptions(speed=SPEED)), start, duration, current=CURRENT
        )
        nmpc = uo.NMPC(following, solver=solver)
        # the current unknown to the NMPC too: an EKF estimates it with the vehicle's states
        # (the path parameter is the controller's own); a horizontal current (the vertical
        # noise 100x smaller) told to the NMPC low-passed over 20 s, or the fins chase its noise
        options = uo.EstimatorOptions(
            current_std=uo.estimation.SURVEY_CURRENT_STD,
            current_filter=uo.estimation.SURVEY_CURRENT_FILTER,
        )
        sensors = uo.Sensors.auv(following.vehicle)
        ekf = uo.Estimator(following, "ekf", sensors=sensors, options=options) if estimate else None
        name = f"NMPC {solver}" + (" + EKF" if estimate else "")
        runs[name] = uo.simulate(
            nmpc, following.initial_state(start), duration, current=CURRENT, estimator=ekf, seed=0
        )
    errors = {
        name: uo.path_errors(following, run.states[:, :12])["cross_track"] for name, run in runs.items()
    }
    for name, run in runs.items():
        found = uo.path_metrics(run, following)  # to the path until its end, over the whole run
        cross, worst, fins = found["cross_track_rms"], found["cross_track_max"], found["fin_activity"]
        print(
            f"{name:12s} cross-track RMS {cross:.3f} m, max {worst:.3f} m, depth RMS "
            f"{found['depth_rms']:.3f} m, fin activity {math.degrees(fins):.1f} deg, "
            f"energy {found['energy'] / 1e3:.2f} kJ, step {1e3 * np.median(run.solve_times):.2f} ms, "
            f"fallbacks {run.fallback_steps.sum()}"
        )
    return Outcome(survey, following, runs, errors, figures(runs, reference, Path(out)))


def figures(runs: dict[str, uo.ClosedLoopResult], reference: uo.Reference, out: Path) -> tuple[Path, ...]:
    """Write the path, depth, fin and propeller figures of ``runs`` to ``out``; their paths."""
    import matplotlib

    matplotlib.use("Agg")  # files only: no display (the package itself never picks a backend)
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    times = np.linspace(reference.t_start, reference.t_end, 4000)
    path = reference.evaluate(times)
    written = []
    figure, axis = plt.subplots(figsize=(6, 5))
    axis.plot(path[:, 1], path[:, 0], "k--", lw=1, label="survey path")
    for name, run in runs.items():
        axis.plot(run.states[:, 1], run.states[:, 0], label=name)
    axis.set(xlabel="east y (m)", ylabel="north x (m)", title="REMUS 100 survey, 0.3 m/s current toward east")
    axis.set_aspect("equal")
    axis.legend()
    written.append(out / "remus_survey_path.png")
    figure.savefig(written[-1], dpi=100, bbox_inches="tight")
    plt.close(figure)
    panels = (
        ("depth z (m)", lambda run: run.states[:, 2], "states", "remus_survey_depth.png"),
        (
            "rudder δr (deg)",
            lambda run: np.degrees(run.controls[:, 0]),
            "controls",
            "remus_survey_rudder.png",
        ),
        (
            "stern planes δs (deg)",
            lambda run: np.degrees(run.controls[:, 1]),
            "controls",
            "remus_survey_stern.png",
        ),
        ("propeller (rpm)", lambda run: run.controls[:, 2], "controls", "remus_survey_propeller.png"),
    )
    figure, axes = plt.subplots(len(panels), 1, figsize=(7, 8), sharex=True)
    for axis, (label, value, kind, _) in zip(axes, panels, strict=True):
        for name, run in runs.items():
            t = run.t if kind == "states" else run.t[:-1]
            axis.step(t, value(run), where="post", label=name) if kind == "controls" else axis.plot(
                t, value(run)
            )
        axis.set_ylabel(label)
    axes[0].invert_yaxis()  # NED: down is positive
    axes[0].legend(list(runs))
    axes[-1].set_xlabel("t (s)")
    written.append(out / "remus_survey_signals.png")
    figure.savefig(written[-1], dpi=100, bbox_inches="tight")
    plt.close(figure)
    return tuple(written)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="30 s of the first lane")
    parser.add_argument("--duration", type=float, default=None, help="s (default: the whole survey)")
    parser.add_argument("--lanes", type=int, default=2)
    parser.add_argument("--solver", default="ipopt")
    parser.add_argument("--out", default="docs/images")
    parser.add_argument("--estimate", action="store_true", help="the NMPC estimates the current (EKF)")
    arguments = parser.parse_args()
    duration = 30.0 if arguments.quick else arguments.duration
    main(duration, arguments.lanes, arguments.solver, arguments.out, arguments.estimate)
