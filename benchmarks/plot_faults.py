"""Figures of docs/faults.md from the records of ``benchmarks/bench_faults.py``.

Reads the runs of one trial (``--trial``, ``--faults`` failed thrusters) and every trial found
for the summary figure, from the benchmark's ``--out`` folder; writes three PNG files to
``--images`` (default ``docs/images``):

* ``faults_run.png``: the trial's 3-D position error over time for each row, the faults and the
  fault-tolerant NMPC's detections marked;
* ``faults_health.png``: the detector's window estimate of each failed thruster's health
  (``run.estimated_health``) against the plant's true health (``run.thruster_health``);
* ``faults_rms.png``: the tracking RMS after the first fault of every trial found, per row and
  fault count (box plot).

Run: ``python -m benchmarks.plot_faults --out out/bench_faults [--trial 0] [--faults 1]``.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from benchmarks.bench_faults import ROWS

COLOURS = {"naive": "tab:red", "ft": "tab:blue", "oracle": "tab:green", "pinv": "tab:orange"}


def _error(run: uo.ClosedLoopResult) -> np.ndarray:
    return np.linalg.norm(run.states[:, :3] - run.reference[:, :3], axis=1)


def _fault_times(run: uo.ClosedLoopResult) -> list[tuple[int, float]]:
    """(thruster, time) of each fault, from the recorded true health (first step below 1)."""
    faults = []
    for thruster in range(run.thruster_health.shape[1]):
        below = np.flatnonzero(run.thruster_health[:, thruster] < 1.0)
        if below.size:
            faults.append((thruster, float(run.t[below[0]])))
    return faults


def main(out: Path, images: Path, trial: int, count: int) -> None:
    """Write the three figures (module doc)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    images.mkdir(parents=True, exist_ok=True)
    # the rows the benchmark flew (``--rows``): those whose records are there
    paths = {row: out / f"{row}-{count}-{trial}.npz" for row in ROWS}
    runs = {row: uo.ClosedLoopResult.load(str(path)) for row, path in paths.items() if path.exists()}
    faults = _fault_times(runs["oracle"])

    figure, axis = plt.subplots(figsize=(8, 3.6))
    for row, run in runs.items():
        axis.plot(run.t, _error(run), color=COLOURS[row], label=row, lw=1.2)
    for thruster, when in faults:
        axis.axvline(when, color="k", ls="--", lw=0.8)
        axis.annotate(f"thruster {thruster} fails", (when, axis.get_ylim()[1] * 0.9), fontsize=8)
    for when in runs["ft"].detections[:, 0]:
        axis.axvline(when, color=COLOURS["ft"], ls=":", lw=0.8)
    axis.axhline(0.5, color="grey", lw=0.6)
    axis.set_xlabel("t (s)")
    axis.set_ylabel("position error (m)")
    axis.set_title(f"trial {trial}, {count} fault(s): dashed = fault, dotted = detection, grey = 0.5 m tube")
    axis.legend(ncol=4, fontsize=8)
    figure.tight_layout()
    figure.savefig(images / "faults_run.png", dpi=110)
    plt.close(figure)

    ft = runs["ft"]
    figure, axis = plt.subplots(figsize=(8, 3.2))
    steps = ft.controls.shape[0]
    for thruster, _ in faults:
        line = axis.plot(ft.t[:steps], ft.thruster_health[:, thruster], lw=2, label=f"true h{thruster}")
        axis.plot(
            ft.t[:steps],
            ft.estimated_health[:, thruster],
            color=line[0].get_color(),
            ls=":",
            label=f"window estimate h{thruster}",
        )
    for when, health in ft.detections[:, [0, 2]]:
        axis.plot([when], [health], "o", color="k")
    axis.set_ylim(-0.1, 1.2)
    axis.set_xlabel("t (s)")
    axis.set_ylabel("health")
    axis.set_title("fault-tolerant NMPC: detector's estimate vs the plant's health (dot: detection)")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(images / "faults_health.png", dpi=110)
    plt.close(figure)

    pattern = re.compile(r"(\w+)-(\d+)-(\d+)\.npz$")
    rms: dict[tuple[str, int], list[float]] = {}
    for path in sorted(out.glob("*.npz")):
        match = pattern.match(path.name)
        if match is None:
            continue
        row, faulted = match.group(1), int(match.group(2))
        run = uo.ClosedLoopResult.load(str(path))
        times = _fault_times(run) if faulted else []
        start = min(when for _, when in times) if times else 5.0
        error = _error(run)[run.t >= start]
        rms.setdefault((row, faulted), []).append(float(np.sqrt(np.mean(error**2))))
    counts = sorted({key[1] for key in rms})
    figure, axes = plt.subplots(1, len(counts), figsize=(3.2 * len(counts), 3.4), sharey=True)
    for axis, faulted in zip(np.atleast_1d(axes), counts, strict=True):
        flown = [row for row in ROWS if (row, faulted) in rms]
        data = [rms[(row, faulted)] for row in flown]
        axis.boxplot(data, tick_labels=flown)
        axis.set_title(f"{faulted} fault(s), {len(data[0])} trials")
        axis.set_yscale("log")
    np.atleast_1d(axes)[0].set_ylabel("tracking RMS after the fault (m)")
    figure.tight_layout()
    figure.savefig(images / "faults_rms.png", dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench_faults"))
    parser.add_argument("--images", type=Path, default=Path("docs/images"))
    parser.add_argument("--trial", type=int, default=0)
    parser.add_argument("--faults", type=int, default=1)
    arguments = parser.parse_args()
    main(arguments.out, arguments.images, arguments.trial, arguments.faults)
