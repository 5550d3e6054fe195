"""Record the fault detector's inputs on the benchmark's closed loops, and replay detectors on them.

``record``: fly the ``ft`` row of :mod:`benchmarks.bench_faults` (the same trials, faults,
currents and seeds) with detection *disabled*: a :class:`Recorder` stands in for the detector
and keeps each step's inputs (the command ``f_{k−1}`` and the estimator's thruster-force bias
``b̂_k``) without ever declaring.  Until a detector declares, it does not act on the loop, so
replaying any detector on these inputs is exact up to its first detection: the first
detection's time and thruster, and any false alarm before a fault, are what the replay
measures (a second detection needs the closed loop, after the controller reallocated).

``replay``: feed the recorded inputs to :class:`uuv_ocp.estimation.faults.ThrusterFaultDetector`
with the options given (``--set name=value``, repeated) and print, per fault count, the first
detections: false alarms (fault-free trials; or a detection before the fault or naming a
healthy thruster), right ones, the delay's median, 90th percentile and maximum, and the count
within 2 s.  Fifty 50-s trials replay in seconds.

``bound``: what an *ideal* detector could do on the same recorded inputs (issue 27's 2-s goal):
for each single-fault recording, the matched filter that knows the faulty thruster ``i``, the
fault time and the estimator's response to a step (``RESPONSE``; only the loss is unknown),
evaluated at every step up to 2 s after the fault on windows of ``--windows`` steps (the bias's
intercept and ramp per axis removed, as the detector's null model).  Its threshold is the
statistic's distribution on the fault-free recordings *with the same template*: every window
after the arming time of every fault-free trial.  Two levels: ``1%`` (the 99th percentile:
a genie that tests once, at the known fault time) and ``0/N`` (the largest value over the ``N``
fault-free trials: a detector that knows the thruster but must test at every step, as a real
one does).  Three weightings: ``ols`` (equal weights on the bias, the detector's), ``gls`` (the
fault-free windows' covariance, estimated on the other half of the fault-free trials) and
``inc`` (the bias *increments*, each weighted by its phase's noise: the estimator's bias moves
20–45 times less on the control steps without a DVL sample, the 5 Hz DVL at dt = 0.1 s).  Printed
per trial: the command's RMS over the 2 s after the fault, the force the loss removes, the
earliest declaration of each weighting and level (``-`` if none within 2 s), and the noise of
the ``ols`` force estimate at 2 s.

Run: ``python -m benchmarks.replay_faults record --count 50 --faults 1,0 --out DIR [--first 0]
[--step 1] [--kinds failed,loss]`` then ``python -m benchmarks.replay_faults replay --out DIR
[--set step_window=20 ...]`` or ``python -m benchmarks.replay_faults bound --out DIR [--trials
3,12] [--windows 10,20,30,40]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path
from unittest import mock

import numpy as np

import uuv_ocp as uo
from benchmarks import bench_faults
from uuv_ocp.estimation.faults import Detection, ThrusterFaultDetector


class Recorder(ThrusterFaultDetector):
    """A detector that keeps its inputs and never declares (the loop as without detection)."""

    def reset(self) -> None:
        """Forget the recorded inputs too."""
        super().reset()
        self.inputs: list[tuple[int, float, np.ndarray, np.ndarray]] = []

    def update(self, step: int, time: float, forces: object, bias: object) -> Detection | None:
        """Record the step's command and bias (N); never a detection."""
        f = np.array(forces, dtype=float).reshape(self.count)
        b = np.array(bias, dtype=float).reshape(self.count)
        self.inputs.append((int(step), float(time), f, b))
        return None


def record(trials: tuple[int, ...], counts: tuple[int, ...], kinds: tuple[str, ...], out: Path) -> None:
    """Fly each trial with a :class:`Recorder` and save its inputs in ``out`` (one ``.npz`` each)."""
    bench = bench_faults.Bench()
    out.mkdir(parents=True, exist_ok=True)
    made: list[Recorder] = []

    def recorder(*args: object, **kwargs: object) -> Recorder:
        made.append(Recorder(*args, **kwargs))  # type: ignore[arg-type]
        return made[-1]

    tag = "" if kinds == bench_faults.FAULTS.kinds else "-" + "-".join(kinds)
    for count in counts:
        for trial in trials:
            path = out / f"rec{tag}-{count}-{trial}.npz"
            if path.exists():
                continue
            faults, direction = bench_faults.drawn(trial, count, bench.bounds, kinds)
            # simulate builds its detector from the options: this process's runs get the recorder
            with mock.patch("uuv_ocp.control.simulation.ThrusterFaultDetector", recorder):
                run = bench.run("ft", faults, direction, trial, DURATION)
            inputs = made[-1].inputs
            np.savez(
                path,
                steps=np.array([row[0] for row in inputs]),
                times=np.array([row[1] for row in inputs]),
                forces=np.array([row[2] for row in inputs]),
                bias=np.array([row[3] for row in inputs]),
                faults=json.dumps([vars(item) for item in faults]),
                direction=direction,
                ended=str(run.fault or ""),
            )
            load = os.getloadavg()[0]
            print(f"{path.name}: {len(inputs)} steps, end {run.t[-1]:.1f} s, load {load:.2f}", flush=True)


def first_detection(data: dict, options: uo.FaultDetectorOptions, allocation: np.ndarray) -> Detection | None:
    """Return the first detection of a detector with ``options`` on one recording, or None."""
    detector = ThrusterFaultDetector(allocation, options, bounds=BOUNDS)
    for step, time, f, b in zip(data["steps"], data["times"], data["forces"], data["bias"], strict=True):
        found = detector.update(int(step), float(time), f, b)
        if found is not None:
            return found
    return None


DURATION = 50.0  # s: the benchmark's default run
BOUNDS = np.full(8, 40.0)  # N: the BlueROV2 Heavy's thruster bound (stuck forces are told within it)


def replay(
    out: Path, options: uo.FaultDetectorOptions, pattern: str = "rec-*.npz", verbose: bool = False
) -> dict:
    """Replay ``options`` on every recording of ``out``; print and return the first-detection figures."""
    allocation = np.array(uo.model.Vehicle6DOF.bluerov2_heavy(thrusters=True).thrusters.allocation)
    figures: dict[int, dict] = {}
    for path in sorted(
        out.glob(pattern), key=lambda p: (p.name.rsplit("-", 2)[-2], int(p.stem.rsplit("-", 1)[1]))
    ):
        count, trial = int(path.stem.rsplit("-", 2)[-2]), int(path.stem.rsplit("-", 1)[1])
        with np.load(path) as saved:
            data = {key: saved[key] for key in ("steps", "times", "forces", "bias")}
            faults = json.loads(str(saved["faults"]))
        found = first_detection(data, options, allocation)
        item = figures.setdefault(count, {"n": 0, "alarms": [], "delays": [], "missed": []})
        item["n"] += 1
        failed = {fault["thruster"]: fault["time"] for fault in faults}
        if found is None:
            if faults:
                item["missed"].append(trial)
            continue
        if found.thruster in failed and found.time >= failed[found.thruster] - 1e-9:
            item["delays"].append((trial, found.time - failed[found.thruster], found.kind))
        else:
            item["alarms"].append((trial, round(found.time, 1), found.thruster))
    for count, item in sorted(figures.items()):
        delays = np.array([d for _, d, _ in item["delays"]])
        line = f"faults {count}: {item['n']} trials, false alarms {len(item['alarms'])} {item['alarms']}"
        if count and delays.size:
            late = [(t, round(d, 1)) for t, d, _ in item["delays"] if d > 2.0 + 1e-9]
            line += (
                f"; right {delays.size}, median {np.median(delays):.1f} p90 {np.percentile(delays, 90):.1f}"
                f" max {delays.max():.1f} s, <= 2 s {int(np.sum(delays <= 2.0 + 1e-9))}; late {late};"
                f" missed {item['missed']}"
            )
        print(line)
        if verbose:
            print("   ", [(t, round(d, 1), k) for t, d, k in item["delays"]])
    return figures


RESPONSE = np.array([0.6, 0.72, 0.8, 0.87, 0.9, 0.93, 0.95, 0.97])
"""The estimator's bias along a thruster after a step loss, per step from the first it shows in
(a fraction of the step, read off the responses of the benchmark's faults of >= 8 N on trials 0–39)."""
ARM = 5.0  # s: the detector's arming time (FaultDetectorOptions.arm_time), the null windows' start


def _recorded(path: Path) -> tuple[dict, list]:
    """Return one recording's inputs and faults."""
    with np.load(path) as saved:
        return {key: saved[key] for key in ("times", "forces", "bias")}, json.loads(str(saved["faults"]))


def bound(out: Path, windows: tuple[int, ...], trials: tuple[int, ...] | None = None) -> list[dict]:
    """Print and return the ideal detector's figures on the single-fault recordings (module doc)."""
    allocation = np.array(uo.model.Vehicle6DOF.bluerov2_heavy(thrusters=True).thrusters.allocation)
    weights = 1.0 / np.linalg.norm(allocation, axis=1)  # the detector's normalised axes
    free = [_recorded(path)[0] for path in sorted(out.glob("rec-0-*.npz"))]
    if not free:
        raise ValueError(f"--out: no fault-free recording rec-0-*.npz in {out}")
    axes = [(data["bias"] @ allocation.T) * weights for data in free]
    half = np.arange(len(free)) >= len(free) // 2
    # the increments' noise per phase (step parity) and axis, on every fault-free step after arming
    increments = [(np.diff(y, axis=0), np.arange(1, len(y))) for y in axes]
    keep = [data["times"][1:] >= ARM - 1e-9 for data in free]
    noise = np.array(
        [
            [
                np.std(
                    np.concatenate(
                        [d[m & (k % 2 == p), a] for (d, k), m in zip(increments, keep, strict=True)]
                    )
                )
                for a in range(6)
            ]
            for p in range(2)
        ]
    )
    null = {}
    for W in windows:
        N = np.hstack(
            [np.kron(np.ones((W, 1)), np.eye(6)), np.kron(np.linspace(-1.0, 1.0, W)[:, None], np.eye(6))]
        )
        M = np.eye(6 * W) - N @ np.linalg.pinv(N)  # removes the intercept and ramp per axis
        rows, owner, ends = [], [], []
        for o, (y, data) in enumerate(zip(axes, free, strict=True)):
            for k in range(W - 1, len(y)):
                if data["times"][k] >= ARM - 1e-9:
                    rows.append(y[k - W + 1 : k + 1].ravel())
                    owner.append(o)
                    ends.append(k)
        Z = np.array(rows) @ M
        owner_, ends_ = np.array(owner), np.array(ends)
        inverse = {}
        for h in (False, True):  # the covariance of one half whitens the other half's windows
            C = np.cov(Z[half[owner_] == h].T)
            C = 0.9 * C + 0.1 * np.trace(C) / (6 * W - 12) * M  # shrunk: 6 W numbers from ~10⁴ windows
            inverse[h] = np.linalg.pinv(M @ C @ M, rcond=1e-10, hermitian=True)
        # the increment windows: W − 1 increments, the ramp a constant per axis
        D = np.array(rows)[:, 6:] - np.array(rows)[:, :-6]
        P = np.kron(np.ones((W - 1, 1)), np.eye(6))
        null[W] = (M, Z, owner_, ends_, inverse, D, P)
    results = []
    paths = sorted(out.glob("rec-1-*.npz"), key=lambda p: int(p.stem.rsplit("-", 1)[1]))
    for path in paths:
        trial = int(path.stem.rsplit("-", 1)[1])
        if trials is not None and trial not in trials:
            continue
        data, faults = _recorded(path)
        fault = faults[0]
        if fault["kind"] not in ("failed", "loss"):
            continue
        i, t0 = int(fault["thruster"]), float(fault["time"])
        loss = 1.0 if fault["kind"] == "failed" else 1.0 - float(fault["effectiveness"])
        t, F = data["times"], data["forces"]
        y = (data["bias"] @ allocation.T) * weights
        first = int(np.searchsorted(t, t0)) + 1  # the first bias sample the fault shows in
        last = int(np.searchsorted(t, t0 + 2.0 + 1e-9)) - 1
        column = allocation[:, i] * weights
        rms = float(np.sqrt(np.mean(F[first : first + 20, i] ** 2)))
        found: dict[str, float] = {}
        noise_force = np.inf
        for W in windows:
            M, Z, owner, ends, inverse, D, P = null[W]
            for k in range(max(first, W - 1), last + 1):
                lag = np.arange(k - W + 1, k + 1) - first
                gain = np.where(lag >= 0, RESPONSE[np.clip(lag, 0, RESPONSE.size - 1)], 0.0)
                gain = np.where(lag >= RESPONSE.size, 1.0, gain)
                x = (-(F[k - W + 1 : k + 1, i] * gain)[:, None] * column[None, :]).ravel()
                window = y[k - W + 1 : k + 1].ravel()
                xt = M @ x
                filters = {"ols": {h: xt / (xt @ xt) for h in (False, True)}}
                filters["gls"] = {h: inverse[h] @ xt / (xt @ inverse[h] @ xt) for h in (False, True)}
                for name, chosen in filters.items():
                    # each half's filter on the other half's windows (the same filter for ols)
                    nulls = np.concatenate([Z[half[owner] != h] @ chosen[h] for h in (False, True)])
                    owners = np.concatenate([owner[half[owner] != h] for h in (False, True)])
                    value = float(np.mean([chosen[h] @ (M @ window) for h in (False, True)]))
                    worst = max(float(nulls[owners == o].max()) for o in np.unique(owners))
                    for level, threshold in (("1%", float(np.quantile(nulls, 0.99))), ("0/N", worst)):
                        key = f"{name} {level}"
                        if value > threshold:  # the earliest over the windows
                            found[key] = min(found.get(key, np.inf), float(t[k] - t0))
                    if name == "ols" and k == last:
                        # the force estimate's noise: the loss estimate's times the command
                        noise_force = min(noise_force, float(np.std(nulls)) * rms)
                # increments, each over its phase's noise; the null windows of the same phase
                scale = 1.0 / noise[np.arange(k - W + 2, k + 1) % 2].ravel()
                dx = (x[6:] - x[:-6]) * scale
                Pw = P * scale[:, None]
                Mi = np.eye(dx.size) - Pw @ np.linalg.pinv(Pw)
                a = Mi @ dx / (dx @ Mi @ dx)
                same = ends % 2 == k % 2
                nulls = (D[same] * scale) @ a
                value = float(a @ ((window[6:] - window[:-6]) * scale))
                worst = max(float(nulls[owner[same] == o].max()) for o in np.unique(owner[same]))
                for level, threshold in (("1%", float(np.quantile(nulls, 0.99))), ("0/N", worst)):
                    key = f"inc {level}"
                    if value > threshold:
                        found[key] = min(found.get(key, np.inf), float(t[k] - t0))
        row = {
            "trial": trial,
            "thruster": i,
            "loss": loss,
            "rms": rms,
            "force": loss * rms,
            "noise": noise_force,
        }
        for name in ("ols", "gls", "inc"):
            for level in ("1%", "0/N"):
                row[f"{name} {level}"] = found.get(f"{name} {level}", np.inf)
        results.append(row)
        shown = "  ".join(
            f"{key} {row[key]:.1f}" if np.isfinite(row[key]) else f"{key} -" for key in row if " " in key
        )
        print(
            f"trial {trial:3d} thruster {i} loss {loss:.1f}: command {rms:5.1f} N RMS,"
            f" removes {loss * rms:4.1f} N;"
            f" ideal first declaration (s after the fault) {shown}; ols noise at 2 s {noise_force:.2f} N",
            flush=True,
        )
    return results


def parsed(settings: list[str]) -> uo.FaultDetectorOptions:
    """Return the options of ``name=value`` settings (Python literals)."""
    fields = {field.name: field.type for field in dataclasses.fields(uo.FaultDetectorOptions)}
    values: dict[str, object] = {}
    for setting in settings:
        name, _, text = setting.partition("=")
        if name not in fields:
            raise ValueError(f"--set: unknown option {name!r}; choose from {sorted(fields)}")
        values[name] = json.loads(text) if text not in ("True", "False") else text == "True"
    return uo.FaultDetectorOptions(**values)  # type: ignore[arg-type]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("record", "replay", "bound"))
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--step", type=int, default=1, help="record every step-th trial (split processes)")
    parser.add_argument("--faults", default="1,0")
    parser.add_argument("--kinds", default=",".join(bench_faults.FAULTS.kinds))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--set", action="append", default=[], help="replay: an option, name=value")
    parser.add_argument("--pattern", default="rec-*.npz")
    parser.add_argument("--verbose", action="store_true")
    parser.add_argument("--trials", default="", help="bound: these single-fault trials only")
    parser.add_argument("--windows", default="10,20,30,40", help="bound: window lengths (steps)")
    arguments = parser.parse_args()
    if arguments.mode == "record":
        chosen = tuple(range(arguments.first, arguments.first + arguments.count, arguments.step))
        counts = tuple(int(item) for item in arguments.faults.split(","))
        kinds = tuple(item for item in arguments.kinds.split(",") if item)
        record(chosen, counts, kinds, arguments.out)
    elif arguments.mode == "bound":
        chosen_trials = tuple(int(item) for item in arguments.trials.split(",") if item) or None
        bound(arguments.out, tuple(int(item) for item in arguments.windows.split(",")), chosen_trials)
    else:
        replay(arguments.out, parsed(arguments.set), arguments.pattern, arguments.verbose)
