"""Waypoint and lawnmower surveys: references built from points, flown by a RexROV with NMPC.

A survey is a :class:`uuv_ocp.Reference` like any other: ``Reference.waypoints`` joins straight
legs by tangent arcs, ``Reference.lawnmower`` lays out parallel lanes joined by semicircles.
Both are flown at constant speed, so their duration is their length divided by the speed.

Run: ``python docs/tutorials/surveys.py`` (writes ``out/tutorials/surveys.png``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import uuv_ocp as uo

SPEED = 0.5  # m/s along the path (the RexROV's surge top speed is about 1.6 m/s)


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (tests/system/test_docs.py checks it)."""

    lawnmower: uo.Reference
    square: uo.Reference
    runs: dict  # name -> ClosedLoopResult
    settled: dict  # name -> largest horizontal error (m) after the transient


def main(
    width: float = 20.0,
    spacing: float = 4.0,
    lanes: int = 3,
    duration: float | None = None,
    horizon: int = 20,
    settle: float = 10.0,
    solver: str = "sqp",
    out: str | Path | None = "out/tutorials/surveys.png",
) -> Outcome:
    """Fly a lawnmower survey and a square of waypoints; ``duration`` None flies them whole."""
    vehicle = uo.Vehicle.rexrov()
    # lanes along x, stacked towards +y, joined by semicircles of radius spacing / 2
    lawnmower = uo.Reference.lawnmower((0.0, 0.0), width=width, spacing=spacing, lanes=lanes, speed=SPEED)
    # a square flown anticlockwise, its corners rounded with a radius of a fifth of the side
    side = width / 2
    corners = [(0.0, 0.0), (side, 0.0), (side, side), (0.0, side), (0.0, 0.5)]
    square = uo.Reference.waypoints(corners, speed=SPEED, turn_radius=side / 5, name="square")
    runs, settled = {}, {}
    for reference in (lawnmower, square):
        problem = uo.TrackingProblem(vehicle, reference, horizon=horizon, dt=0.1)
        # the whole survey, less the horizon that must stay inside the reference window
        available = problem.latest_start() - reference.t_start
        length = available if duration is None else min(duration, available)
        run = uo.simulate(uo.NMPC(problem, solver), reference.initial_state(0.0), length)
        runs[reference.name] = run
        after = run.t >= settle
        settled[reference.name] = float(np.max(np.linalg.norm(run.errors[after], axis=1)))
        print(
            f"{reference.name:<10} {reference.description}: {reference.t_end - reference.t_start:.1f} s "
            f"at {SPEED} m/s; flew {run.t[-1]:.1f} s, max horizontal error after {settle:g} s "
            f"{settled[reference.name]:.2e} m, failures {run.failures}"
        )
    if out is not None:
        from uuv_ocp.plotting import save_figure, xoy_figure

        path = save_figure(xoy_figure(list(runs.values()), "surveys", labels=list(runs)), out)
        print(f"figure: {path}")
    return Outcome(lawnmower, square, runs, settled)


if __name__ == "__main__":
    main()
    sys.exit(0)
