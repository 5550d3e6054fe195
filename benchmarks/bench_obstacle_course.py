"""Issue 30: the obstacle course in closed loop, every hybrid and MPPI alone, clearance at every plant step.

The courses of ``examples/obstacles.py`` (RexROV past a rock and a wreck, BlueROV2 Heavy past
a pile and a moving diver), N = 15, dt = 0.1 s, ``obstacle_tolerance="auto"`` (and 0 for a few
solvers, to compare), each solver at its default options, seed 1.  The plant (RK4, 10 steps
per control interval) is recorded at every step; *margin* is the smallest signed distance (m)
over all of them to any obstacle enlarged by its safety margin (< 0: the margin was entered),
*obstacle* the same to the obstacles themselves (< 0: a collision).

Run: ``python -m benchmarks.bench_obstacle_course [--out DIR] [--solvers a,b]``.  Each run is
appended to ``DIR/course.jsonl`` as it ends (a rerun skips what is there: resumable); the table
is printed from that file at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.obstacles import closest_approach
from uuv_ocp.solvers import REGISTRY

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import obstacles as example  # noqa: E402  (examples/ is not a package)

DURATION = {"RexROV": 25.0, "BlueROV2 Heavy": 15.0}  # both obstacles passed
HORIZON = 15


def plan(solvers: list[str] | None) -> list[tuple[str, str, float | str]]:
    """(course, solver, tolerance) in the order run: MPPI and its hybrids first, fatrop's last."""
    if solvers is None:
        hybrids = [name for name in REGISTRY.names() if REGISTRY.kind(name) == "hybrid"]
        hybrids.sort(key=lambda name: (not name.startswith("mppi"), "fatrop" in name, name))
        solvers = ["mppi", *hybrids]
    runs: list[tuple[str, str, float | str]] = []
    for solver in solvers:
        for course in DURATION:
            runs.append((course, solver, "auto"))
    for solver in ("sqp", "mppi+sqp"):  # without the tolerance: the nodes only
        for course in DURATION:
            runs.append((course, solver, 0.0))
    return runs


def run_one(course_name: str, solver: str, tolerance: float | str) -> dict:
    """One closed loop; its figures."""
    course = {c.name: c for c in example.courses(HORIZON, tolerance)}[course_name]
    start = time.perf_counter()
    load = os.getloadavg()
    run = uo.simulate(
        uo.NMPC(course.problem, solver, seed=1),
        course.x0,
        duration=DURATION[course_name],
        record_substeps=True,
        progress=True,  # a bar where bars are drawn (a terminal, UUV_OCP_PROGRESS=always): runs last minutes
    )
    return {
        "course": course_name,
        "solver": solver,
        "tolerance": tolerance,
        "tolerances_m": list(course.problem.obstacle_tolerances),
        "margin_m": closest_approach(course.problem.obstacles, run),
        "obstacle_m": closest_approach(course.problem.obstacles, run, margin=False),
        "failures": run.failures,
        "steps": int(run.controls.shape[0]),
        "median_ms": 1e3 * float(np.median(run.solve_times)),
        "wall_s": time.perf_counter() - start,
        "load": [load[0], os.getloadavg()[0]],
    }


def table(records: list[dict]) -> str:
    """Markdown table of the records."""
    lines = [
        "| course | solver | tolerance (mm) | margin (mm) | obstacle (m) | fallbacks / steps "
        "| median step (ms) | load |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        tolerance = (
            "0" if r["tolerance"] == 0.0 else "auto " + "/".join(f"{1e3 * t:.1f}" for t in r["tolerances_m"])
        )
        lines.append(
            f"| {r['course']} | {r['solver']} | {tolerance} | {1e3 * r['margin_m']:+.2f} | "
            f"{r['obstacle_m']:.3f} | "
            f"{r['failures']} / {r['steps']} | {r['median_ms']:.1f} | {r['load'][0]:.1f}–{r['load'][1]:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    """Run what is not in the output file yet; print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench_obstacle_course")
    parser.add_argument("--solvers", default=None, help="comma-separated (default: mppi and every hybrid)")
    args = parser.parse_args(argv)
    path = Path(args.out) / "course.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    records = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    done = {(r["course"], r["solver"], r["tolerance"]) for r in records}
    for key in plan(None if args.solvers is None else args.solvers.split(",")):
        if key in done:
            continue
        record = run_one(*key)
        records.append(record)
        with path.open("a") as handle:
            handle.write(json.dumps(record) + "\n")
        print(table([record]).splitlines()[-1], flush=True)
    print(table(records))
    return records


if __name__ == "__main__":
    main()
