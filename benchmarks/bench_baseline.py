"""Old-vs-new: the tracking problem on this tree against a baseline commit, in one run.

The redesign rebuilt ``TrackingProblem`` on the general ``Ocp``.  This benchmark checks it did
not cost speed or change answers: it checks the baseline commit out into a temporary git
worktree and runs the same closed loop (s2, RexROV, N = 20, 300 steps from rest, warm-started)
on the baseline and on this tree in turn (old, new, old, new: the VM's drift hits both), in
separate processes, and prints the median ms per step and the new/old ratio.  With
``--optima`` it also solves s1..s10 from perturbed states with ipopt, fatrop and sqp on both
trees and prints the largest relative cost difference.

Run: ``python -m benchmarks.bench_baseline [--rev d6ebbd6] [--optima]`` (part of ``make bench``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

BASELINE = "d6ebbd6"  # the last commit before the symbolic core (stop 8)
ROOT = Path(__file__).resolve().parents[1]

_LOOP = r"""
import json, sys, time
import numpy as np
import uuv_ocp as uo
solver = sys.argv[1]
ref = uo.Reference.paper("s2")
problem = uo.TrackingProblem(uo.Vehicle.rexrov(), ref, horizon=20, dt=0.1)
controller = uo.NMPC(problem, solver)
plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
controller.step(ref.initial_state(0.0), 0.0); controller.step(ref.evaluate([3.0])[0], 3.0)
controller.reset()
state, control, times = ref.initial_state(0.0), np.zeros(3), []
for k in range(300):
    start = time.perf_counter()
    out = controller.step(state, k * 0.1, control, np.zeros(2))
    times.append(time.perf_counter() - start)
    control = out.control
    state = np.array(plant(state, control, np.zeros(2))).ravel()
print(json.dumps({"median_ms": 1e3 * float(np.median(times)), "final": state.tolist()}))
"""

_OPTIMA = r"""
import json, numpy as np, uuv_ocp as uo
rows = {}
for name in [f"s{i}" for i in range(1, 11)]:
    ref = uo.Reference.paper(name)
    for terminal in ("equality", "cost"):
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), ref, horizon=20, dt=0.1, terminal=terminal)
        t0 = ref.t_start + 1.0
        x0 = ref.evaluate([t0])[0] + np.array([0.05, -0.05, 0.02, 0.05, 0.0, 0.0])
        for solver in ("ipopt", "fatrop", "sqp"):
            for current in (None, [0.2, -0.1]):
                res = uo.solve(problem, solver, x0=x0, t0=t0, u_prev=[300.0, -200.0, 50.0], current=current)
                rows[f"{name}/{terminal}/{solver}/{current is not None}"] = res.cost
print(json.dumps(rows))
"""


def _run(source: Path, script: str, *args: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(source))
    out = subprocess.run(
        [sys.executable, "-c", script, *args], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    """Print the old-vs-new table (and optionally the optimum comparison)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", default=BASELINE, help="baseline git revision")
    parser.add_argument("--optima", action="store_true", help="also compare optima on s1..s10")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        tree = Path(folder) / "baseline"
        try:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), args.rev],
                check=True,
                capture_output=True,
            )
        except (OSError, subprocess.CalledProcessError) as error:
            print(f"baseline comparison skipped: cannot check out {args.rev} ({error})")
            return
        try:
            trees = {"old": tree / "src", "new": ROOT / "src"}
            print(f"\nTracking problem, this tree vs {args.rev} (s2, N = 20, 300 steps, median ms per step)")
            print(f"{'solver':8s} {'old ms':>8s} {'new ms':>8s} {'new/old':>8s}")
            for solver in ("fatrop", "sqp", "ipopt"):
                medians: dict[str, list[float]] = {"old": [], "new": []}
                for _ in range(args.rounds):
                    for label, source in trees.items():
                        medians[label].append(_run(source, _LOOP, solver)["median_ms"])
                old, new = float(np.median(medians["old"])), float(np.median(medians["new"]))
                print(f"{solver:8s} {old:8.2f} {new:8.2f} {new / old:8.3f}")
            if args.optima:
                old_costs, new_costs = (_run(source, _OPTIMA) for source in trees.values())
                gaps = {
                    key: abs(new_costs[key] - cost) / max(1.0, abs(cost)) for key, cost in old_costs.items()
                }
                worst = max(gaps, key=gaps.__getitem__)
                within = sum(gap <= 1e-9 for gap in gaps.values())
                print(
                    f"optima: {within}/{len(gaps)} instances within 1e-9 relative cost; "
                    f"largest difference {gaps[worst]:.1e} ({worst})"
                )
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)


if __name__ == "__main__":
    main()
