"""Thruster faults on a BlueROV2 Heavy survey under an unknown current: fault-tolerant NMPC vs baselines.

Issue 27: a lawnmower survey at 2 m depth (3 lanes of 6 m, 2 m apart, 0.5 m/s) under a
0.3 m/s current of a direction drawn per seed, *unknown*: every controller gets the state and
the current from an EKF on its own model (``uo.Sensors.auv``: 1 Hz position fix, DVL, attitude,
gyro, depth), ``sqp-rti``, N = 10, dt = 0.1 s.  Per seed a random thruster fails completely or
loses 50 % (drawn) at a random time in 5..8 s; the same runs without a fault give the false
alarms.  Four controllers fly each run:

* ``naive``: the NMPC planning the eight thruster forces, its model kept healthy;
* ``ft``: the same NMPC with the fault detector (``fault_detector=uo.FaultDetectorOptions()``,
  :mod:`uuv_ocp.estimation.faults`): told the *estimated* health from a detection on;
* ``oracle``: the same NMPC told the true health from the fault on (``health_known=True``);
* ``pinv``: an NMPC planning the generalised force τ on the force model, τ mapped to the
  thrusters by the pseudo-inverse of the healthy allocation matrix, clipped (``allocation=``).

The thruster controllers' EKF estimates a thruster-force bias (``bias=True``, 5 N/√s: what the
detector reads; the controller is not told it); the pinv EKF on the force model too.

Printed per controller: successes (stays within 0.5 m, 3-D, of the reference from 10 s after the
fault on), median RMS 3-D error after the fault, median time to recover (from the fault to the
last exit from the 0.5 m tube; runs that never leave it count 0), and for ``ft``: isolated
right / detected at all, median and worst time to detect, false alarms on the fault-free runs;
median / p90 controller step time (ms).

Every run is a checked record (``uuv_ocp.studies.records``) in ``--out`` (default
``out/bench_faults``): an interrupted benchmark resumes, a damaged record is recomputed.

Run: ``python -m benchmarks.bench_faults [--seeds 0 1 ... | --count 20] [--duration 25]
[--rows naive,ft,oracle,pinv] [--out DIR]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.studies.records import read_record, write_record

RECOVERY = 10.0  # s after the fault from which the 0.5 m tube must hold
TUBE = 0.5  # m
SPEED = 0.3  # m/s
BIAS_STD = 5.0  # N/√s
ROWS = ("naive", "ft", "oracle", "pinv")


def survey() -> uo.Reference:
    """Return the lawnmower survey at 2 m depth."""
    return uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.5, depth=2.0)


def drawn(seed: int) -> dict[str, float]:
    """Return seed ``seed``'s fault (thruster, time s, remaining effectiveness) and current direction."""
    rng = np.random.default_rng(10_000 + seed)
    return {
        "thruster": int(rng.integers(8)),
        "time": int(rng.integers(50, 81)) / 10,
        "health": float(rng.choice([0.0, 0.5])),
        "direction": float(rng.uniform(0.0, 2.0 * np.pi)),
    }


class Bench:
    """The problems, controllers and estimators of the benchmark (built once)."""

    def __init__(self) -> None:
        reference = survey()
        self.boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
        forces = Vehicle6DOF.bluerov2_heavy()
        self.in_thrusters = uo.TrackingProblem(self.boat, reference, horizon=10, dt=0.1, terminal="cost")
        self.in_forces = uo.TrackingProblem(forces, reference, horizon=10, dt=0.1, terminal="cost")
        self.x0 = self.in_thrusters.initial_state()
        options = uo.EstimatorOptions(bias=True, bias_std=BIAS_STD, compiled=False)
        sensors = uo.Sensors.auv(self.boat)
        self.thruster_ekf = uo.Estimator(self.in_thrusters, "ekf", sensors=sensors, options=options)
        self.force_ekf = uo.Estimator(self.in_forces, "ekf", sensors=sensors, options=options)
        self.thruster_mpc = uo.NMPC(self.in_thrusters, "sqp-rti")
        self.force_mpc = uo.NMPC(self.in_forces, "sqp-rti")

    def run(self, row: str, seed: int, faulty: bool, duration: float) -> uo.ClosedLoopResult:
        """Fly ``row`` on seed ``seed`` (with its fault if ``faulty``)."""
        draw = drawn(seed)
        fault = uo.ThrusterFault(int(draw["thruster"]), draw["time"], "loss", effectiveness=draw["health"])
        options: dict = {"faults": (fault,) if faulty else ()}
        controller, estimator = self.thruster_mpc, self.thruster_ekf
        if row == "ft":
            options["fault_detector"] = uo.FaultDetectorOptions()
        elif row == "oracle":
            options["health_known"] = True
        elif row == "pinv":
            controller, estimator = self.force_mpc, self.force_ekf
            options["allocation"] = self.boat.thrusters
        return uo.simulate(
            controller,
            self.x0,
            duration,
            current=uo.Current(speed=SPEED, direction=draw["direction"]),
            seed=seed,
            estimator=estimator,
            **options,
        )


def scored(run: uo.ClosedLoopResult, draw: dict[str, float], faulty: bool) -> dict[str, float]:
    """Return one run's figures (module doc)."""
    error = np.linalg.norm(run.states[:, :3] - run.reference[:, :3], axis=1)
    t = run.t  # the faults' and the detections' clock
    start = draw["time"] if faulty else 5.0
    after, recovered = t >= start, t >= start + RECOVERY
    outside = np.flatnonzero(after & (error > TUBE))
    detections = run.detections
    first = detections[0] if detections.size else None
    return {
        "success": float(run.fault is None and recovered.any() and np.max(error[recovered]) <= TUBE),
        "rms": float(np.sqrt(np.mean(error[after] ** 2))),
        "recover": float(t[outside[-1]] - start) if outside.size else 0.0,
        "detected": float(first is not None and (not faulty or first[0] >= draw["time"] - 1e-9)),
        "right": float(first is not None and faulty and int(first[1]) == draw["thruster"]),
        "delay": float(first[0] - draw["time"]) if first is not None and faulty else np.nan,
        "alarm": float(detections.size > 0 and not faulty),
    }


def main(seeds: tuple[int, ...], duration: float, rows: tuple[str, ...], out: Path) -> None:
    """Print the table of the module doc."""
    bench = Bench()
    out.mkdir(parents=True, exist_ok=True)
    figures: dict[tuple[str, bool], list[dict[str, float]]] = {}
    times: dict[str, list[np.ndarray]] = {row: [] for row in rows}
    for faulty in (True, False):
        for row in rows:
            for seed in seeds:
                config = {"row": row, "seed": seed, "faulty": faulty, "duration": duration, "version": 1}
                path = out / f"{row}-{seed}-{int(faulty)}.npz"
                saved = read_record(path, config)
                if saved is None:
                    run = bench.run(row, seed, faulty, duration)
                    write_record(path, run, config)
                else:
                    run = saved[0]
                figures.setdefault((row, faulty), []).append(scored(run, drawn(seed), faulty))
                times[row].append(run.solve_times)
    print(
        f"\nBlueROV2 Heavy survey at 2 m, {SPEED} m/s current (unknown, EKF), one thruster failed or "
        f"at 50 % from 5..8 s, {duration:g} s, sqp-rti N = 10, seeds {seeds[0]}..{seeds[-1]} ({len(seeds)})"
    )
    print(
        f"{'row':7s} {'success':>8s} {'med RMS m':>9s} {'med recover s':>13s} {'isolated':>9s} "
        f"{'med/max detect s':>16s} {'false alarms':>12s} {'fault-free ok':>13s} "
        f"{'med ms':>7s} {'p90 ms':>7s}"
    )
    for row in rows:
        faulty, free = figures[(row, True)], figures[(row, False)]
        n = len(faulty)
        step = 1e3 * np.concatenate(times[row])
        delays = [item["delay"] for item in faulty if item["right"]]
        detect = f"{np.median(delays):.1f}/{max(delays):.1f}" if delays else "-"
        isolated = f"{int(sum(i['right'] for i in faulty))}/{int(sum(i['detected'] for i in faulty))}"
        alarms = f"{int(sum(i['alarm'] for i in free))}/{len(free)}"
        print(
            f"{row:7s} {int(sum(i['success'] for i in faulty)):>4d}/{n:<3d} "
            f"{np.median([i['rms'] for i in faulty]):9.3f} {np.median([i['recover'] for i in faulty]):13.1f} "
            f"{isolated if row == 'ft' else '-':>9s} {detect if row == 'ft' else '-':>16s} "
            f"{alarms if row == 'ft' else '-':>12s} "
            f"{int(sum(i['success'] for i in free)):>9d}/{len(free):<3d} "
            f"{np.median(step):7.2f} {np.percentile(step, 90):7.2f}"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=None)
    parser.add_argument("--count", type=int, default=10, help="seeds 0..count-1 (without --seeds)")
    parser.add_argument("--duration", type=float, default=25.0)
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--out", type=Path, default=Path("out/bench_faults"))
    arguments = parser.parse_args()
    chosen = tuple(arguments.seeds) if arguments.seeds else tuple(range(arguments.count))
    picked = tuple(row for row in arguments.rows.split(",") if row)
    unknown = sorted(set(picked) - set(ROWS))
    if unknown:
        parser.error(f"--rows: unknown {unknown}; choose from {list(ROWS)}")
    main(chosen, arguments.duration, picked, arguments.out)
