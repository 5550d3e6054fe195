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

Run: ``python -m benchmarks.replay_faults record --count 50 --faults 1,0 --out DIR [--first 0]
[--step 1] [--kinds failed,loss]`` then ``python -m benchmarks.replay_faults replay --out DIR
[--set step_window=20 ...]``.
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
    parser.add_argument("mode", choices=("record", "replay"))
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--step", type=int, default=1, help="record every step-th trial (split processes)")
    parser.add_argument("--faults", default="1,0")
    parser.add_argument("--kinds", default=",".join(bench_faults.FAULTS.kinds))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--set", action="append", default=[], help="replay: an option, name=value")
    parser.add_argument("--pattern", default="rec-*.npz")
    parser.add_argument("--verbose", action="store_true")
    arguments = parser.parse_args()
    if arguments.mode == "record":
        chosen = tuple(range(arguments.first, arguments.first + arguments.count, arguments.step))
        counts = tuple(int(item) for item in arguments.faults.split(","))
        kinds = tuple(item for item in arguments.kinds.split(",") if item)
        record(chosen, counts, kinds, arguments.out)
    else:
        replay(arguments.out, parsed(arguments.set), arguments.pattern, arguments.verbose)
