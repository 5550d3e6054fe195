"""Thruster faults on a BlueROV2 Heavy survey under an unknown current: fault-tolerant NMPC vs baselines.

Issue 27: a lawnmower survey at 2 m depth (3 lanes of 10 m, 3 m apart, at ``SURVEY_SPEED``
= 0.5 m/s; at 0.8 m/s the vehicle lags the reference by 1.2 m along the lanes into the current
without any fault, so every row fails the tube: no setting to compare controllers)
under a 0.3 m/s current of a direction drawn per trial, *unknown*: every controller gets the
state and the current from an EKF on its own model (``uo.Sensors.auv``: 1 Hz position fix, DVL,
attitude, gyro, depth), ``sqp-rti``, N = 10, dt = 0.1 s.  Trial ``i`` with ``c`` faults draws
them with :class:`uuv_ocp.RandomFaults` (``c`` distinct thrusters, each a complete failure or a
50 % loss, at a time uniform in 5..10 s) from ``numpy.random.default_rng([i, c, 27])``; its
current direction from ``default_rng([i, 0])`` (the same for every count: the 0-fault trial is
the fault-free twin).  Four controllers fly each trial:

* ``naive``: the NMPC planning the eight thruster forces, its model kept healthy;
* ``ft``: the same NMPC with the fault detector (``fault_detector=uo.FaultDetectorOptions()``,
  :mod:`uuv_ocp.estimation.faults`): told the *estimated* health from a detection on;
* ``oracle``: the same NMPC told the true health from the fault on (``health_known=True``);
* ``pinv``: an NMPC planning the generalised force τ on the force model, τ mapped to the
  thrusters by the pseudo-inverse of the healthy allocation matrix, clipped (``allocation=``).

The thruster controllers' EKF estimates a thruster-force bias (``bias=True``, 5 N/√s: what the
detector reads; the controller is not told it); the pinv EKF on the force model too.

Printed per controller and fault count: mission successes (the 3-D position error stays within
``TUBE`` = 0.5 m of the reference from ``RECOVERY`` = 10 s after the last fault to the end; for
0 faults from 10 s), median tracking RMS after the first fault (0 faults: after 5 s), median
time to recover (from the last fault to the last exit from the tube; 0 if it never leaves it),
and for ``ft``: faults isolated to the right thruster / injected, median and worst time to
detect (from each fault to the detection naming its thruster), false alarms (a detection on a
0-fault trial, or naming a thruster that has not failed); median / p90 controller step (ms).
Below each ``ft`` row: the 90th percentile and the count within 2 s of the detection time; the
detection time counted from the first step after the fault at which the thruster is commanded
at least ``OBSERVABLE`` = 10 N (a 50 % loss then removes 5 N); whether each isolated fault was
told the right kind (stuck, or a loss; ``run.detections``' fourth column); and each detection
later than 2 s with its time from the end of the first 2-s window after the fault over which
the command's standard deviation reached ``VARIED`` = 5 N (the window's intercept absorbs a
constant command's loss: a thruster saturated after the fault is not observable until it varies).

Every run is a checked record (``uuv_ocp.studies.records``) in ``--out`` (default
``out/bench_faults``): an interrupted benchmark resumes, a damaged record is recomputed.

``--rti`` (before the trials) or ``--rti-only``: the per-step time of the sqp-rti NMPC (N = 20)
planning the eight thruster forces against the one planning the six generalised forces,
interleaved on the same states (a survey closed loop's), median ms, with the load average.

``--kinds failed,loss,stuck`` draws stuck thrusters too (:class:`uuv_ocp.RandomFaults`: a force
of a random sign, 25..75 % of the bound); another set of kinds draws other faults, so give it
its own ``--out``.

``--dither 5`` adds the null-space dither of that amplitude (N) to the ``ft`` row's thruster
commands (``uo.DitherOptions``, :mod:`uuv_ocp.control.dither`); its records carry it.

``--tau 0.1`` gives the thrusters a first-order response of that time constant (s) in the
plant and in the thruster rows' model and EKF (20 states: the delivered forces); not with
``pinv`` (it plans generalised forces); give it its own ``--out``.

Run: ``python -m benchmarks.bench_faults [--count 50] [--faults 0,1,2] [--duration 50]
[--rows naive,ft,oracle,pinv] [--kinds failed,loss] [--out DIR] [--rti | --rti-only]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.studies.records import read_record, write_record

RECOVERY = 10.0  # s after the last fault from which the tube must hold
TUBE = 0.5  # m
CURRENT = 0.3  # m/s
SURVEY_SPEED = 0.5  # m/s (0.8: the fault-free survey already lags 1.2 m along the lanes)
BIAS_STD = 5.0  # N/√s
DEADLINE = 0.1  # s: the controller's step, dt
ROWS = ("naive", "ft", "oracle", "pinv")
FAULTS = uo.RandomFaults(count=1, window=(5.0, 10.0), kinds=("failed", "loss"), effectiveness=0.5)
VERSION = 3  # 3: a new controller per run (a shared one stayed degraded after a run diverged)
DETECTOR_VERSION = 10  # 10: the increment test; 9: a steady-command change point told a loss
OBSERVABLE = 10.0  # N: a command from which a 50 % loss removes 5 N (the detection clock's "observable")
VARIED = 5.0  # N: command std over a 2-s window after the fault (what the per-window intercept leaves)


def survey() -> uo.Reference:
    """Return the lawnmower survey at 2 m depth."""
    return uo.Reference.lawnmower((0.0, 0.0), width=10.0, spacing=3.0, lanes=3, speed=SURVEY_SPEED, depth=2.0)


def drawn(
    trial: int, count: int, bounds: np.ndarray, kinds: tuple[str, ...] = FAULTS.kinds
) -> tuple[tuple[uo.ThrusterFault, ...], float]:
    """Return trial ``trial``'s faults (``count`` of them, of ``kinds``) and current direction (rad)."""
    faults = uo.RandomFaults(count, FAULTS.window, kinds, FAULTS.effectiveness)
    direction = float(np.random.default_rng([trial, 0]).uniform(0.0, 2.0 * np.pi))
    return faults.draw(np.random.default_rng([trial, count, 27]), bounds), direction


class Bench:
    """The problems, controllers and estimators of the benchmark (built once)."""

    def __init__(self, horizon: int = 10, tau: float = 0.0, dither: float = 0.0) -> None:
        reference = survey()
        self.dither = uo.DitherOptions(amplitude=dither)
        self.boat = Vehicle6DOF.bluerov2_heavy(thrusters=True)
        if tau:  # thrusters with a first-order response, in the plant and every thruster row's model
            assert self.boat.thrusters is not None  # the preset with thrusters=True has them
            lagging = dataclasses.replace(self.boat.thrusters, time_constant=tau)
            self.boat = dataclasses.replace(self.boat, thrusters=lagging)
        forces = Vehicle6DOF.bluerov2_heavy()
        self.in_thrusters = uo.TrackingProblem(self.boat, reference, horizon=horizon, dt=0.1, terminal="cost")
        self.in_forces = uo.TrackingProblem(forces, reference, horizon=horizon, dt=0.1, terminal="cost")
        self.x0 = self.in_thrusters.initial_state()
        thrusters = self.boat.thrusters
        assert thrusters is not None  # the preset with thrusters=True has them
        self.bounds = np.array(thrusters.max_thrust)
        options = uo.EstimatorOptions(bias=True, bias_std=BIAS_STD, compiled=False)
        sensors = uo.Sensors.auv(self.boat)
        self.thruster_ekf = uo.Estimator(self.in_thrusters, "ekf", sensors=sensors, options=options)
        self.force_ekf = uo.Estimator(self.in_forces, "ekf", sensors=uo.Sensors.auv(forces), options=options)
        # a real-time step: the fallback chain (soft NLP, cold retry, IPOPT) stops at dt, as it
        # would on the vehicle (without it a diverging naive loop spends seconds per step)
        self.thruster_mpc = self.controller(self.in_thrusters)
        self.force_mpc = self.controller(self.in_forces)

    @staticmethod
    def controller(problem: uo.TrackingProblem) -> uo.NMPC:
        """Return a new sqp-rti NMPC of ``problem`` with the real-time deadline."""
        return uo.NMPC(problem, "sqp-rti", options={"deadline": DEADLINE})

    def run(
        self, row: str, faults: tuple[uo.ThrusterFault, ...], direction: float, seed: int, duration: float
    ) -> uo.ClosedLoopResult:
        """Fly ``row`` with ``faults`` under the current of ``direction``."""
        options: dict = {"faults": faults}
        # a new controller per run, so that a record does not depend on the runs before it in
        # the process (a resumed benchmark runs them in another order); it also hid a leak since
        # fixed: a diverged QP left NaN in the C step's HPIPM memory (OcpQpStep.reset)
        controller, estimator = self.controller(self.in_thrusters), self.thruster_ekf
        if row == "ft":
            options["fault_detector"] = uo.FaultDetectorOptions(dither=self.dither)
        elif row == "oracle":
            options["health_known"] = True
        elif row == "pinv":
            controller, estimator = self.controller(self.in_forces), self.force_ekf
            options["allocation"] = self.boat.thrusters
        return uo.simulate(
            controller,
            self.x0,
            duration,
            current=uo.Current(speed=CURRENT, direction=direction),
            seed=seed,
            estimator=estimator,
            **options,
        )


def scored(run: uo.ClosedLoopResult, faults: tuple[uo.ThrusterFault, ...]) -> dict[str, float]:
    """Return one run's figures (module doc)."""
    error = np.linalg.norm(run.states[:, :3] - run.reference[:, :3], axis=1)
    t = run.t  # the faults' and the detections' clock
    first = faults[0].time if faults else 5.0
    last = faults[-1].time if faults else 0.0
    after, recovered = t >= first, t >= last + RECOVERY
    outside = np.flatnonzero((t >= last) & (error > TUBE))
    detections = run.detections
    failed = {item.thruster: item.time for item in faults}
    delays, observable, varied, alarms, stuck_right = [], [], [], 0, 0
    named: set[int] = set()
    kinds = {item.thruster: item.kind for item in faults}
    for row in detections:
        when, thruster = float(row[0]), int(row[1])
        if thruster in failed and when >= failed[thruster] - 1e-9 and thruster not in named:
            delays.append(when - failed[thruster])
            named.add(thruster)
            # from the first step after the fault the thruster is commanded >= OBSERVABLE
            commanded = np.abs(run.controls[:, thruster]) >= OBSERVABLE
            steps = np.flatnonzero((t[: commanded.size] >= failed[thruster] - 1e-9) & commanded)
            observable.append(when - max(t[steps[0]], failed[thruster]) if steps.size else np.nan)
            # a constant command's loss is a constant force, which the window's intercept absorbs:
            # the end of the first 2-s window after the fault whose command varied by >= VARIED
            first = int(np.searchsorted(t, failed[thruster] - 1e-9))
            ends = [
                k
                for k in range(first + 19, commanded.size)
                if np.std(run.controls[k - 19 : k + 1, thruster]) >= VARIED
            ]
            varied.append(when - t[ends[0]] if ends else np.nan)
            told_stuck = row.size > 3 and row[3] != 0.0  # older records: no kind column
            stuck_right += int(told_stuck == (kinds[thruster] == "stuck"))
        else:
            alarms += 1
    return {
        "success": float(run.fault is None and recovered.any() and np.max(error[recovered]) <= TUBE),
        "rms": float(np.sqrt(np.mean(error[after] ** 2))),
        "recover": float(t[outside[-1]] - last) if outside.size else 0.0,
        "isolated": float(len(named)),
        "injected": float(len(faults)),
        "delays": delays,  # type: ignore[dict-item]
        "observable": observable,  # type: ignore[dict-item]
        "varied": varied,  # type: ignore[dict-item]
        "kind_right": float(stuck_right),
        # momentum theory: a thruster's power grows as |f|^1.5 (N^1.5, a proxy; the applied commands)
        "power": float(np.mean(np.sum(np.abs(run.controls) ** 1.5, axis=1))),
        "alarm": float(alarms > 0),
    }


def rti_timing(steps: int = 200) -> None:
    """Print the sqp-rti step (N = 20) in thruster forces vs generalised forces, interleaved."""
    bench = Bench(horizon=20)
    run = uo.simulate(bench.thruster_mpc, bench.x0, steps * 0.1, current=uo.Current(speed=CURRENT))
    x0 = bench.x0
    thrusters, forces = bench.thruster_mpc, bench.force_mpc
    thrusters.warm_up(x0, 0.0, np.zeros(8))
    forces.warm_up(x0, 0.0, np.zeros(6))
    times: dict[str, list[float]] = {"8 thruster forces": [], "6 generalised forces": []}
    u8, u6 = np.zeros(8), np.zeros(6)
    for k in range(run.controls.shape[0]):
        x, t = run.states[k], run.t[k]
        for name, controller in (("8 thruster forces", thrusters), ("6 generalised forces", forces)):
            start = time.perf_counter()
            output = controller.step(x, t, u8 if controller is thrusters else u6)
            times[name].append(time.perf_counter() - start)
            control = np.asarray(getattr(output, "control", output), dtype=float).ravel()
            if controller is thrusters:
                u8 = control
            else:
                u6 = control
    load = os.getloadavg()
    count = len(times["8 thruster forces"])
    print(f"\nsqp-rti step, N = 20, BlueROV2 Heavy survey states ({count} steps, interleaved)")
    for name, values in times.items():
        ms = 1e3 * np.array(values)
        print(f"  {name:22s} median {np.median(ms):6.2f} ms  p90 {np.percentile(ms, 90):6.2f} ms")
    print(f"  load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")


def main(
    trials: tuple[int, ...],
    counts: tuple[int, ...],
    duration: float,
    rows: tuple[str, ...],
    out: Path,
    kinds: tuple[str, ...] = FAULTS.kinds,
    tau: float = 0.0,
    dither: float = 0.0,
) -> None:
    """Print the table of the module doc (``tau``: the thrusters' time constant, s; ``dither``: N)."""
    if tau and "pinv" in rows:
        raise ValueError("--tau is for the thruster rows (naive, ft, oracle): pinv plans forces")
    bench = Bench(tau=tau, dither=dither)
    out.mkdir(parents=True, exist_ok=True)
    figures: dict[tuple[str, int], list[dict]] = {}
    times: dict[tuple[str, int], list[np.ndarray]] = {}
    for trial in trials:  # trial-major: an interrupted run leaves every row at the same count
        for count in counts:
            faults, direction = drawn(trial, count, bench.bounds, kinds)
            for row in rows:
                config = {
                    "row": row,
                    "trial": trial,
                    "count": count,
                    "faults": [vars(item) for item in faults],
                    "direction": direction,
                    "duration": duration,
                    "speed": SURVEY_SPEED,
                    "version": VERSION,
                }
                if row == "ft":  # the detector's revision: its records only are recomputed
                    config["detector"] = DETECTOR_VERSION
                if tau:
                    config["tau"] = tau
                if dither and row == "ft":
                    config["dither"] = [dither, *bench.dither.frequencies]
                path = out / f"{row}-{count}-{trial}.npz"
                saved = read_record(path, config)
                if saved is None:
                    run = bench.run(row, faults, direction, trial, duration)
                    write_record(path, run, config)
                else:
                    run = saved[0]
                figures.setdefault((row, count), []).append({**scored(run, faults), "trial": trial})
                times.setdefault((row, count), []).append(run.solve_times)
    print(
        f"\nBlueROV2 Heavy lawnmower at 2 m, {SURVEY_SPEED} m/s, {CURRENT} m/s current (unknown, EKF), "
        f"faults: {' or '.join(kinds)} (loss: 50 %) at 5..10 s, {duration:g} s, sqp-rti N = 10, "
        f"trials {len(trials)} per count"
    )
    print(
        f"{'row':7s} {'faults':>6s} {'success':>9s} {'med RMS m':>9s} {'med recover s':>13s} "
        f"{'isolated':>9s} {'med/max detect s':>16s} {'false alarms':>12s} {'med ms':>7s} {'p90 ms':>7s}"
    )
    for count in counts:
        for row in rows:
            items = figures[(row, count)]
            n = len(items)
            step = 1e3 * np.concatenate(times[(row, count)])
            delays = [d for item in items for d in item["delays"]]
            detect = f"{np.median(delays):.1f}/{max(delays):.1f}" if delays else "-"
            isolated = f"{int(sum(i['isolated'] for i in items))}/{int(sum(i['injected'] for i in items))}"
            alarms = f"{int(sum(i['alarm'] for i in items))}/{n}"
            ft = row == "ft"
            print(
                f"{row:7s} {count:6d} {int(sum(i['success'] for i in items)):>5d}/{n:<3d} "
                f"{np.median([i['rms'] for i in items]):9.3f} "
                f"{np.median([i['recover'] for i in items]):13.1f} "
                f"{isolated if ft and count else '-':>9s} {detect if ft and count else '-':>16s} "
                f"{alarms if ft else '-':>12s} {np.median(step):7.2f} {np.percentile(step, 90):7.2f}"
            )
            print(
                f"        mean RMS {np.mean([i['rms'] for i in items]):.3f} m, mean thruster power proxy "
                f"sum |f|^1.5 {np.mean([i['power'] for i in items]):.1f} N^1.5"
                + (f", dither {dither:g} N" if ft and dither else "")
            )
            if ft and count and delays:
                seen = np.array([d for item in items for d in item["observable"]], dtype=float)
                late = [
                    (item["trial"], round(float(d), 1), round(float(v), 1))
                    for item in items
                    for d, v in zip(item["delays"], item["varied"], strict=True)
                    if d > 2.0
                ]
                within = sum(d <= 2.0 + 1e-9 for d in delays)
                print(
                    f"        detect p90 {np.percentile(delays, 90):.1f} s, <= 2 s {within}/{len(delays)}; "
                    f"from |command| >= {OBSERVABLE:g} N after the fault: median "
                    f"{np.nanmedian(seen):.1f} max {np.nanmax(seen):.1f} s; kind (stuck or not) right "
                    f"{int(sum(i['kind_right'] for i in items))}/{len(delays)}; > 2 s (trial, s, s from "
                    f"the first 2-s window of command std >= {VARIED:g} N): {late}"
                )
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=10, help="trials 0..count-1 per fault count")
    parser.add_argument("--first", type=int, default=0, help="first trial index")
    parser.add_argument("--faults", default="0,1,2", help="fault counts")
    parser.add_argument("--duration", type=float, default=50.0)
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument(
        "--kinds",
        default=",".join(FAULTS.kinds),
        help="fault kinds drawn (failed, loss, stuck); another set draws other faults: use another --out",
    )
    parser.add_argument("--out", type=Path, default=Path("out/bench_faults"))
    parser.add_argument(
        "--tau", type=float, default=0.0, help="thrusters' time constant (s), plant and model; not pinv"
    )
    parser.add_argument(
        "--dither", type=float, default=0.0, help="ft row: null-space dither amplitude (N); 0: none"
    )
    parser.add_argument("--rti", action="store_true", help="the RTI step timing first")
    parser.add_argument("--rti-only", action="store_true", help="only the RTI step timing")
    arguments = parser.parse_args()
    if arguments.rti or arguments.rti_only:
        rti_timing()
    if not arguments.rti_only:
        picked = tuple(row for row in arguments.rows.split(",") if row)
        unknown = sorted(set(picked) - set(ROWS))
        if unknown:
            parser.error(f"--rows: unknown {unknown}; choose from {list(ROWS)}")
        counts = tuple(int(item) for item in arguments.faults.split(","))
        chosen = tuple(range(arguments.first, arguments.first + arguments.count))
        kinds = tuple(item for item in arguments.kinds.split(",") if item)
        main(
            chosen, counts, arguments.duration, picked, arguments.out, kinds, arguments.tau, arguments.dither
        )
