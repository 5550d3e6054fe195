"""Obstacles: keep-out zones on a RexROV's straight path, fixed and moving, in closed loop.

The reference runs straight through a rock and past a moving diver.  ``TrackingProblem``
adds each :class:`uuv_ocp.Obstacle` (enlarged by its safety margin, the vehicle's size) as a
hard constraint on the predicted positions of nodes 1..N; the same course without obstacles
shows that the path really does cross them.  ``examples/obstacles.py`` runs a longer course
with a 6-DOF vehicle as well.

Run: ``python docs/tutorials/obstacles.py`` (writes ``out/tutorials/obstacles.png``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import uuv_ocp as uo
from uuv_ocp.obstacles import closest_approach

ROCK = uo.Obstacle.circle((5.0, 0.2), 0.6, margin=0.5, name="rock")
# the diver swims across the path at 0.1 m/s (its centre is a function of the CasADi time)
DIVER = uo.Obstacle.moving(lambda t: (10.0, -2.0 + 0.1 * t), 0.3, margin=0.5, name="diver")
OBSTACLES = (ROCK, DIVER)


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (tests/system/test_docs.py checks it)."""

    problem: uo.TrackingProblem
    runs: dict  # label -> ClosedLoopResult
    clearance: dict  # label -> smallest signed distance (m) to any enlarged obstacle; < 0 inside


def main(
    duration: float = 30.0,
    horizon: int = 25,
    dt: float = 0.2,
    solver: str = "sqp",
    out: str | Path | None = None,
) -> Outcome:
    """Fly the course with and without the obstacles; print the clearances; draw the paths."""
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    # terminal="cost": a terminal equality on the reference could sit inside an obstacle
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=horizon, dt=dt, terminal="cost", obstacles=OBSTACLES
    )
    blind = problem.replace(obstacles=())  # the same problem without the keep-out zones
    x0 = line.initial_state(0.0)
    # record_substeps: the plant's every integration step (10 per control interval), so that the
    # distances below also cover what happens between the controller's nodes
    runs = {
        f"{solver}, obstacles": uo.simulate(uo.NMPC(problem, solver), x0, duration, record_substeps=True),
        f"{solver}, no obstacles": uo.simulate(uo.NMPC(blind, solver), x0, duration, record_substeps=True),
    }
    gaps = {label: closest_approach(OBSTACLES, run) for label, run in runs.items()}
    for label, run in runs.items():
        print(f"{label:<24} min clearance {gaps[label]:+.1e} m, failures {run.failures}")
    if out is not None:
        from uuv_ocp.plotting import obstacle_figure, save_figure

        # obstacles drawn where they are at t = 20 s, when the vehicle passes the diver
        figure = obstacle_figure(
            list(runs.values()), OBSTACLES, labels=list(runs), title="keep-out zones", obstacle_time=20.0
        )
        print(f"figure: {save_figure(figure, out)}")
    return Outcome(problem, runs, gaps)


if __name__ == "__main__":
    main(out="out/tutorials/obstacles.png")
    sys.exit(0)
