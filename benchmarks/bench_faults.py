"""One failed thruster on a BlueROV2 Heavy survey: thruster NMPC (naive, oracle) vs pseudo-inverse.

A first slice of issue 27's campaign (no detection yet): a lawnmower survey at 2 m depth
(3 lanes of 6 m, 2 m apart, 0.5 m/s) under a constant 0.3 m/s current the controllers are
told, ``sqp-rti``, N = 10, dt = 0.1 s.  For each thruster in turn it fails completely at
t = 5 s; three controllers fly the same run:

* ``naive``: the NMPC planning the eight thruster forces, its model kept healthy;
* ``oracle``: the same NMPC told the true health from the fault on (``health_known=True``);
* ``pinv``: an NMPC planning the generalised force τ on the force model, τ mapped to the
  thrusters by the pseudo-inverse of the healthy allocation matrix, clipped (``allocation=``).

Printed per controller: trials that stay within 0.5 m (3-D) of the reference from 10 s after
the fault on, the median of the RMS 3-D error after the fault, the worst maximum error after
the fault, and the median / p90 step time (ms): the per-step cost of planning 8 thruster
forces against 6 generalised forces, measured in the same run.

Run: ``python -m benchmarks.bench_faults`` (``--duration``, ``--thrusters 0 4``).
"""

from __future__ import annotations

import argparse

import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF

FAULT_TIME = 5.0  # s
RECOVERY = 10.0  # s after the fault from which the 0.5 m tube must hold
TUBE = 0.5  # m
CURRENT = uo.Current(speed=0.3, direction=np.pi / 4)


def survey() -> uo.Reference:
    """Return the lawnmower survey at 2 m depth."""
    return uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.5, depth=2.0)


def trial(controller: uo.NMPC, x0: np.ndarray, duration: float, **options) -> dict[str, float]:
    """Run one loop; return its errors after the fault and its step times."""
    run = uo.simulate(controller, x0, duration, current=CURRENT, seed=1, **options)
    error = np.linalg.norm(run.states[:, :3] - run.reference[:, :3], axis=1)
    after = run.t >= FAULT_TIME
    recovered = run.t >= FAULT_TIME + RECOVERY
    return {
        "success": float(run.fault is None and np.max(error[recovered]) <= TUBE),
        "rms": float(np.sqrt(np.mean(error[after] ** 2))),
        "max": float(np.max(error[after])),
        "times": run.solve_times,
        "failures": run.failures,
    }


def main(duration: float = 30.0, thrusters: tuple[int, ...] = tuple(range(8))) -> None:
    """Print the table of the module doc."""
    reference = survey()
    boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
    forces = Vehicle6DOF.bluerov2_heavy()
    in_thrusters = uo.TrackingProblem(boat, reference, horizon=10, dt=0.1, terminal="cost")
    in_forces = uo.TrackingProblem(forces, reference, horizon=10, dt=0.1, terminal="cost")
    x0 = in_thrusters.initial_state()
    controllers = {
        "naive": (uo.NMPC(in_thrusters, "sqp-rti"), {}),
        "oracle": (uo.NMPC(in_thrusters, "sqp-rti"), {"health_known": True}),
        "pinv": (uo.NMPC(in_forces, "sqp-rti"), {"allocation": boat.thrusters}),
    }
    print(
        f"\nBlueROV2 Heavy survey at 2 m, {CURRENT.speed} m/s current (told), one thruster failed at "
        f"t = {FAULT_TIME:g} s, {duration:g} s, sqp-rti N = 10; thrusters {list(thrusters)}"
    )
    print(
        f"{'controller':10s} {'success':>8s} {'median RMS m':>13s} {'worst max m':>12s} "
        f"{'fallbacks':>9s} {'median ms':>10s} {'p90 ms':>7s}"
    )
    for name, (controller, options) in controllers.items():
        rows = [
            trial(controller, x0, duration, faults=(uo.ThrusterFault(i, FAULT_TIME),), **options)
            for i in thrusters
        ]
        times = 1e3 * np.concatenate([row["times"] for row in rows])
        fallbacks = sum(row["failures"] for row in rows)
        print(
            f"{name:10s} {int(sum(row['success'] for row in rows)):>4d}/{len(rows):<3d} "
            f"{np.median([row['rms'] for row in rows]):13.3f} {max(row['max'] for row in rows):12.3f} "
            f"{fallbacks:9d} {np.median(times):10.2f} {np.percentile(times, 90):7.2f}"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--thrusters", type=int, nargs="*", default=list(range(8)))
    arguments = parser.parse_args()
    main(arguments.duration, tuple(arguments.thrusters))
