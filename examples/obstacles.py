"""Obstacle course: a RexROV (3-DOF) and a BlueROV2 Heavy (6-DOF) track a line through keep-out zones.

Each vehicle follows a straight reference that runs through two obstacles (each enlarged by a
safety margin, the vehicle's size), in closed loop with each solver.  The plant is recorded at
every one of its integration steps (10 per control interval), not only at the controller's
nodes, and the table reports over all of them the smallest distance to any obstacle itself
(negative = collision) and to any enlarged obstacle (negative = the margin was entered), the
failures and the median step time; one figure shows the RexROV's paths.

Run: ``python examples/obstacles.py [SOLVER ...]`` (writes ``out/obstacles.png``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.obstacles import closest_approach

# fatrop and its hybrids are left out of the default set: on the BlueROV2 course fatrop stalls at
# its iteration limit twice per step before IPOPT rescues it (4.7-8.5 s per step, docs/benchmarks.md)
SOLVERS = ("ipopt", "sqp", "igwo", "igwo+sqp", "pso+sqp")


@dataclass(frozen=True)
class Course:
    """One vehicle's obstacle course."""

    name: str
    problem: uo.TrackingProblem
    x0: np.ndarray


def courses(horizon: int = 20, obstacle_tolerance: float | str = "auto") -> list[Course]:
    """Build the RexROV and BlueROV2 Heavy courses (obstacles a little off the line: two unequal sides).

    ``obstacle_tolerance`` (``TrackingProblem``'s): ``"auto"`` keeps every plant step, not only
    the controller's nodes, out of the enlarged obstacles; 0 constrains the nodes only.
    """
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    rexrov_obstacles = [
        uo.Obstacle.circle((5.0, 0.2), 1.0, margin=1.0, name="rock"),
        uo.Obstacle.ellipse((11.0, -0.3), (1.5, 0.8), angle=0.4, margin=1.0, name="wreck"),
    ]
    rexrov = uo.TrackingProblem(
        uo.Vehicle.rexrov(),
        line,
        horizon=horizon,
        dt=0.1,
        terminal="cost",
        obstacles=rexrov_obstacles,
        obstacle_tolerance=obstacle_tolerance,
    )
    dive = uo.Reference.from_xyz(lambda t: 0.3 * t, lambda t: 0 * t, lambda t: 1.0 + 0 * t, name="dive")
    blue_obstacles = [
        uo.Obstacle.circle((1.5, 0.1), 0.3, margin=0.3, name="pile"),
        uo.Obstacle.moving(lambda t: (3.5, -1.0 + 0.1 * t), 0.3, margin=0.3, name="diver"),
    ]
    blue = uo.TrackingProblem(
        Vehicle6DOF.bluerov2_heavy(),
        dive,
        horizon=horizon,
        dt=0.1,
        terminal="cost",
        obstacles=blue_obstacles,
        obstacle_tolerance=obstacle_tolerance,
    )
    return [
        Course("RexROV", rexrov, line.initial_state(0.0)),
        Course("BlueROV2 Heavy", blue, dive.initial_state(0.0)),
    ]


@dataclass(frozen=True)
class Outcome:
    """One closed loop of the course: the run and its distances over every plant step."""

    run: uo.ClosedLoopResult
    clearance: float  # smallest signed distance (m) to any enlarged obstacle; < 0: margin entered
    distance: float  # smallest signed distance (m) to any obstacle itself; < 0: collision


def main(
    solvers: tuple[str, ...] = SOLVERS,
    duration: float = 30.0,
    horizon: int = 20,
    out: str | Path | None = "out/obstacles.png",
    options: dict[str, dict] | None = None,
    only: tuple[str, ...] | None = None,
) -> dict[str, dict[str, Outcome]]:
    """Run every course with every solver; print the table; write the figure if ``out``.

    ``options`` maps a solver name to its options (default: each solver's own); ``only``: the
    names of the courses to run (default: all; the figure needs the RexROV's).
    """
    results: dict[str, dict[str, Outcome]] = {}
    print(f"{'vehicle':<16}{'solver':<13}{'obstacle m':>11}{'margin m':>10}{'fail':>6}{'median ms':>11}")
    for course in courses(horizon):
        if only is not None and course.name not in only:
            continue
        results[course.name] = {}
        for solver in solvers:
            controller = uo.NMPC(course.problem, solver, options=(options or {}).get(solver), seed=1)
            run = uo.simulate(controller, course.x0, duration=duration, record_substeps=True)
            outcome = Outcome(
                run,
                closest_approach(course.problem.obstacles, run),
                closest_approach(course.problem.obstacles, run, margin=False),
            )
            results[course.name][solver] = outcome
            print(
                f"{course.name:<16}{solver:<13}{outcome.distance:>11.3g}{outcome.clearance:>10.2g}"
                f"{run.failures:>6d}{1e3 * np.median(run.solve_times):>11.2f}"
            )
    if out is not None:
        from uuv_ocp.plotting import obstacle_figure, save_figure

        course = courses(horizon)[0]
        runs = [results[course.name][solver].run for solver in solvers]
        save_figure(obstacle_figure(runs, course.problem.obstacles, title="RexROV obstacle course"), out)
    return results


if __name__ == "__main__":
    main(*(() if len(sys.argv) < 2 else (tuple(sys.argv[1:]),)))
