"""Closed loop under currents and model mismatch: what the controller knows, and what it does not.

Five runs of NMPC on the s2 reference against a RexROV plant integrated at 10 substeps per
interval, under a 0.3 m/s current (with Gauss–Markov fluctuations):

* ``current unknown, EKF`` (the realistic loop, the headline): the controller is told neither
  the state nor the current; an EKF on the controller's model infers both from the AUV sensor
  suite ``uo.Sensors.auv`` (position fix 1 Hz σ 0.5 m, DVL 5 Hz σ 0.02 m/s with 5 % dropouts,
  attitude 10 Hz σ 0.5°, gyro 10 Hz σ 0.1°/s), and the controller uses the estimates;
* ``current known (oracle)``: the controller gets the true state and is told the current;
* ``current unknown, ignored``: the true state, the current neither told nor estimated (the
  naive controller);
* ``still water (oracle)``: no current, the controller's model is the plant;
* ``mismatch, EKF``: the realistic loop again with the controller (and its EKF) on
  ``Vehicle.rexrov_controller_model()`` (uuv_simulator's rounded coefficients) against the exact
  ``Vehicle.rexrov()`` plant.

Run: ``python docs/tutorials/closed_loop.py`` (writes ``out/tutorials/closed_loop_errors.png``
and ``out/tutorials/closed_loop_estimation.png``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import uuv_ocp as uo

CURRENT = uo.Current(speed=0.3, direction=0.5, speed_noise=0.02, direction_noise=0.05)
HEADLINE = "current unknown, EKF"


def main(
    duration: float = 30.0,
    horizon: int = 20,
    solver: str = "sqp",
    settle: float = 10.0,
    out: str | Path | None = "out/tutorials/closed_loop_errors.png",
) -> dict:
    """Run the five cases; return label -> ClosedLoopResult."""
    reference = uo.Reference.paper("s2")
    plant = uo.Vehicle.rexrov()
    exact = uo.TrackingProblem(plant, reference, horizon=horizon, dt=0.1)
    rounded = exact.replace(vehicle=uo.Vehicle.rexrov_controller_model())
    x0 = reference.initial_state(0.0)

    def ekf(problem: uo.TrackingProblem) -> uo.Estimator:
        # the estimator runs on the controller's own model; the sensors are the vehicle's
        return uo.Estimator(problem, "ekf", sensors=uo.Sensors.auv(problem.vehicle))

    cases = {
        HEADLINE: dict(problem=exact, current=CURRENT, estimator=ekf(exact)),
        "current known (oracle)": dict(problem=exact, current=CURRENT),
        "current unknown, ignored": dict(problem=exact, current=CURRENT, current_known=False),
        "still water (oracle)": dict(problem=exact),
        "mismatch, EKF": dict(problem=rounded, current=CURRENT, estimator=ekf(rounded), plant=plant),
    }
    runs = {}
    print(
        f"{'case':<26}{'max|e| t>' + format(settle, 'g') + ' s (m)':>20}{'rms |e| (m)':>13}"
        f"{'|ĉ − c| end (m/s)':>19}{'fail':>6}"
    )
    for label, case in cases.items():
        problem = case.pop("problem")
        run = uo.simulate(uo.NMPC(problem, solver), x0, duration, seed=7, **case)
        runs[label] = run
        distance = np.linalg.norm(run.errors, axis=1)
        settled = distance[run.t >= settle]
        estimates = run.estimates
        current_error = (
            f"{np.linalg.norm(estimates.currents[-1] - run.currents[len(estimates.t) - 1]):.3f}"
            if estimates is not None
            else "-"
        )
        print(
            f"{label:<26}{settled.max():>20.2e}{np.sqrt(np.mean(distance**2)):>13.3f}"
            f"{current_error:>19}{run.failures:>6d}"
        )
    if out is not None:
        from uuv_ocp.plotting import error_figure, estimation_figure, save_figure

        figure = error_figure(list(runs.values()), f"s2, NMPC + {solver}", labels=list(runs))
        print(f"figure: {save_figure(figure, out)}")
        figure = estimation_figure(runs[HEADLINE], f"s2, {HEADLINE}: what the EKF made of the sensors")
        print(f"figure: {save_figure(figure, Path(out).with_name('closed_loop_estimation.png'))}")
    return runs


if __name__ == "__main__":
    main()
    sys.exit(0)
