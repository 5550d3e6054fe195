"""Closed loop under currents and model mismatch: what the controller knows, and what it does not.

Four runs of NMPC on the s2 reference against a RexROV plant integrated at 10 substeps per
interval:

* ``nominal``: still water, the controller's model is the plant;
* ``current, known``: a 0.3 m/s current (with Gauss–Markov fluctuations) that the controller's
  model is told at every step;
* ``current, unknown``: the same current, the model assumes still water;
* ``mismatch``: the controller uses ``Vehicle.rexrov_controller_model()`` (uuv_simulator's
  rounded hydrodynamic coefficients) against the exact ``Vehicle.rexrov()`` plant, with the
  known current and measurement noise.

Run: ``python docs/tutorials/closed_loop.py`` (writes ``out/tutorials/closed_loop_errors.png``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import uuv_ocp as uo

CURRENT = uo.Current(speed=0.3, direction=0.5, speed_noise=0.02, direction_noise=0.05)
NOISE = uo.MeasurementNoise(std=(0.005, 0.005, 0.002, 0.002, 0.002, 0.002))  # m, m, rad, m/s, m/s, rad/s


def main(
    duration: float = 30.0,
    horizon: int = 20,
    solver: str = "sqp",
    settle: float = 10.0,
    out: str | Path | None = "out/tutorials/closed_loop_errors.png",
) -> dict:
    """Run the four cases; return label -> ClosedLoopResult."""
    reference = uo.Reference.paper("s2")
    plant = uo.Vehicle.rexrov()
    exact = uo.TrackingProblem(plant, reference, horizon=horizon, dt=0.1)
    rounded = exact.replace(vehicle=uo.Vehicle.rexrov_controller_model())
    x0 = reference.initial_state(0.0)
    cases = {
        "nominal": dict(problem=exact),
        "current, known": dict(problem=exact, current=CURRENT),
        "current, unknown": dict(problem=exact, current=CURRENT, current_known=False),
        "mismatch": dict(problem=rounded, current=CURRENT, noise=NOISE, plant=plant),
    }
    runs = {}
    print(f"{'case':<18}{'max|e| t>' + format(settle, 'g') + ' s (m)':>20}{'rms |e| (m)':>13}{'fail':>6}")
    for label, case in cases.items():
        problem = case.pop("problem")
        run = uo.simulate(uo.NMPC(problem, solver), x0, duration, seed=7, **case)
        runs[label] = run
        distance = np.linalg.norm(run.errors, axis=1)
        settled = distance[run.t >= settle]
        print(f"{label:<18}{settled.max():>20.2e}{np.sqrt(np.mean(distance**2)):>13.3f}{run.failures:>6d}")
    if out is not None:
        from uuv_ocp.plotting import error_figure, save_figure

        figure = error_figure(list(runs.values()), f"s2, NMPC + {solver}", labels=list(runs))
        print(f"figure: {save_figure(figure, out)}")
    return runs


if __name__ == "__main__":
    main()
    sys.exit(0)
