"""Old-vs-new: the tracking problem on this tree against a baseline commit, in one run.

The redesign rebuilt ``TrackingProblem`` on the general ``Ocp``.  This benchmark checks it did
not cost speed or change answers: it checks the baseline commit out into a temporary git
worktree and runs the same closed loop (s2, RexROV, N = 20, 300 steps from rest, warm-started)
on the baseline and on this tree in turn (old, new, old, new: the VM's drift hits both), in
separate processes, and prints the median ms per step and the new/old ratio, in wall time
(the criterion) and in the process's CPU time (``time.process_time``: what the step itself
costs, without the time the process waits for a core on a loaded machine), and the ratio of
each round.  With ``--optima`` it also solves s1..s10 from perturbed states with ipopt, fatrop
and sqp on both trees and prints the largest relative cost difference.

``--instructions`` also counts the instructions of each step under valgrind's callgrind (the
same loop; needs ``valgrind``): a measure the machine's load does not move, for a loaded VM.

Run: ``python -m benchmarks.bench_baseline [--rev d6ebbd6] [--rounds 3] [--instructions]
[--optima]`` (part of ``make bench``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
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
state, control, times, cpu = ref.initial_state(0.0), np.zeros(3), [], []
for k in range(300):
    start, start_cpu = time.perf_counter(), time.process_time()
    out = controller.step(state, k * 0.1, control, np.zeros(2))
    times.append(time.perf_counter() - start)
    cpu.append(time.process_time() - start_cpu)
    control = out.control
    state = np.array(plant(state, control, np.zeros(2))).ravel()
print(json.dumps({"median_ms": 1e3 * float(np.median(times)), "cpu_ms": 1e3 * float(np.median(cpu)),
                  "final": state.tolist()}))
"""

# The same loop for --instructions, run under valgrind's callgrind: instrumentation starts after
# the build and the warm-up, and each step runs inside itertools.starmap so that callgrind can
# count the instructions of that call alone (--toggle-collect) and dump them per call.
_COUNTED = _LOOP.replace(
    "state, control, times, cpu =",
    "import itertools, os, subprocess\n"
    "subprocess.run(['callgrind_control', '-i', 'on', str(os.getpid())], capture_output=True)\n"
    "time.sleep(1.0)\n"
    "state, control, times, cpu =",
).replace(
    "out = controller.step(state, k * 0.1, control, np.zeros(2))",
    "(out,) = itertools.starmap(controller.step, [(state, k * 0.1, control, np.zeros(2))])",
)

# ipopt to 1e-10 with bound_relax_factor = 0 (ipopt otherwise relaxes every bound by 1e-8
# relative, so a saturated control may leave the box by ~2e-5 N): the reference optimum.
_OPTIMA = r"""
import json, sys, numpy as np, uuv_ocp as uo
tight = sys.argv[1] == "tight"
solvers = ("ipopt",) if tight else ("ipopt", "fatrop", "sqp")
options = {"plugin_options": {"ipopt.tol": 1e-10, "ipopt.bound_relax_factor": 0.0}, "max_iter": 500}
rows = {}
for name in [f"s{i}" for i in range(1, 11)]:
    ref = uo.Reference.paper(name)
    for terminal in ("equality", "cost"):
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), ref, horizon=20, dt=0.1, terminal=terminal)
        t0 = ref.t_start + 1.0
        x0 = ref.evaluate([t0])[0] + np.array([0.05, -0.05, 0.02, 0.05, 0.0, 0.0])
        for solver in solvers:
            for current in (None, [0.2, -0.1]):
                res = uo.solve(problem, solver, x0=x0, t0=t0, u_prev=[300.0, -200.0, 50.0], current=current,
                               options=options if tight else None)
                key = f"{name}/{terminal}/{'tight-' if tight else ''}{solver}/{current is not None}"
                rows[key] = {"cost": res.cost, "success": bool(res.success),
                             "controls": np.asarray(res.controls).tolist()}
print(json.dumps(rows))
"""

# The new tree's judge on the old tree's controls, clipped into the box the new backends hold.
_JUDGE = r"""
import json, sys, numpy as np, uuv_ocp as uo
rows = json.loads(open(sys.argv[1]).read())
judged = {}
for key, row in rows.items():
    name, terminal, _, current = key.split("/")
    ref = uo.Reference.paper(name)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), ref, horizon=20, dt=0.1, terminal=terminal)
    t0 = ref.t_start + 1.0
    x0 = ref.evaluate([t0])[0] + np.array([0.05, -0.05, 0.02, 0.05, 0.0, 0.0])
    box = np.asarray(problem.vehicle.max_thrust)
    controls = np.asarray(row["controls"])
    cost, _ = uo.score(problem, np.clip(controls, -box, box), x0=x0, t0=t0, u_prev=[300.0, -200.0, 50.0],
                       current=[0.2, -0.1] if current == "True" else None)
    judged[key] = {"cost": float(cost), "outside": float(np.max(np.abs(controls) - box))}
print(json.dumps(judged))
"""


def _relative(a: float, b: float) -> float:
    return abs(a - b) / max(1.0, abs(b))


def _optima(trees: dict[str, Path]) -> None:
    """Compare the optima of both trees and explain every instance that differs by > 1e-9."""
    old, new = (_run(source, _OPTIMA, "default") for source in trees.values())
    gaps = {key: _relative(new[key]["cost"], row["cost"]) for key, row in old.items()}
    worst = max(gaps, key=gaps.__getitem__)
    print(
        f"optima: {sum(gap <= 1e-9 for gap in gaps.values())}/{len(gaps)} instances within 1e-9 "
        f"relative cost; largest difference {gaps[worst]:.1e} ({worst})"
    )
    tight_old, tight_new = (_run(source, _OPTIMA, "tight") for source in trees.values())
    tight_gaps = [_relative(tight_new[key]["cost"], row["cost"]) for key, row in tight_old.items()]
    print(
        f"ipopt to 1e-10 with bounds held exactly (bound_relax_factor 0): "
        f"{sum(gap <= 1e-9 for gap in tight_gaps)}/{len(tight_gaps)} within 1e-9, "
        f"largest {max(tight_gaps):.1e}"
    )
    differing = {key: old[key] for key, gap in gaps.items() if gap > 1e-9}
    if not differing:
        return
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as handle:
        json.dump(differing, handle)
    judged = _run(trees["new"], _JUDGE, handle.name)
    Path(handle.name).unlink()
    print(
        f"{'instance':30s} {'old-new':>8s} {'old out':>9s} {'clip-new':>9s} {'old-opt':>8s} {'new-opt':>8s}"
    )
    for key, row in differing.items():
        name, terminal, solver, current = key.split("/")
        optimum = tight_new[f"{name}/{terminal}/tight-ipopt/{current}"]
        clipped = _relative(judged[key]["cost"], new[key]["cost"])
        line = f"{key:30s} {gaps[key]:8.1e} {judged[key]['outside']:8.1e}N {clipped:9.1e}"
        if optimum["success"]:
            reference = optimum["cost"]
            line += f" {_relative(row['cost'], reference):8.1e} {_relative(new[key]['cost'], reference):8.1e}"
        print(line)
    print(
        "old out: largest |u| beyond the thrust box in the old solution (N); clip-new: the old "
        "controls clipped into the box and judged by this tree, against this tree's cost; "
        "old-opt / new-opt: distance to the reference optimum (tight ipopt)"
    )


def _instructions(source: Path, solver: str) -> np.ndarray:
    """Instructions of each closed-loop step (callgrind), independent of the machine's load."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "steps.out"
        command = [
            "valgrind",
            "--tool=callgrind",
            f"--callgrind-out-file={out}",
            "--instr-atstart=no",
            "--collect-atstart=no",
            "--toggle-collect=starmap_next",
            "--dump-after=starmap_next",
            sys.executable,
            "-c",
            _COUNTED,
            solver,
        ]
        env = dict(os.environ, PYTHONPATH=str(source))
        subprocess.run(command, env=env, capture_output=True, text=True, check=True, cwd=folder)
        counts = {}
        for dump in Path(folder).glob("steps.out.*"):
            total = re.search(r"^(?:summary|totals):\s*(\d+)", dump.read_text(), re.MULTILINE)
            counts[int(dump.suffix[1:])] = int(total.group(1)) if total else 0
    ordered = [counts[k] for k in sorted(counts)]
    # starmap_next runs twice per step (the step, then the end of the iterator): add the pairs
    return np.array([ordered[i] + ordered[i + 1] for i in range(0, len(ordered) - 1, 2)], dtype=float)


def _instruction_table(trees: dict[str, Path]) -> None:
    print("\nInstructions per step (callgrind, median over the 300 steps; load-independent)")
    print(f"{'solver':8s} {'old M':>8s} {'new M':>8s} {'new/old':>8s}   {'sum new/old':>11s}")
    for solver in ("fatrop", "sqp", "ipopt"):
        old, new = (_instructions(source, solver) for source in trees.values())
        print(
            f"{solver:8s} {np.median(old) / 1e6:8.2f} {np.median(new) / 1e6:8.2f} "
            f"{np.median(new) / np.median(old):8.3f}   {new.sum() / old.sum():11.3f}"
        )


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
    parser.add_argument(
        "--instructions",
        action="store_true",
        help="also count instructions per step under valgrind's callgrind (slow: ~10 min per solver)",
    )
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
            print(
                f"{'solver':8s} {'old ms':>8s} {'new ms':>8s} {'new/old':>8s}   "
                f"{'old cpu':>8s} {'new cpu':>8s} {'new/old':>8s}   per-round new/old (wall)"
            )
            for solver in ("fatrop", "sqp", "ipopt"):
                medians: dict[str, list[float]] = {"old": [], "new": []}
                cpu: dict[str, list[float]] = {"old": [], "new": []}
                for _ in range(args.rounds):
                    for label, source in trees.items():
                        row = _run(source, _LOOP, solver)
                        medians[label].append(row["median_ms"])
                        cpu[label].append(row["cpu_ms"])
                old, new = float(np.median(medians["old"])), float(np.median(medians["new"]))
                old_cpu, new_cpu = float(np.median(cpu["old"])), float(np.median(cpu["new"]))
                rounds = " ".join(f"{b / a:.3f}" for a, b in zip(medians["old"], medians["new"], strict=True))
                print(
                    f"{solver:8s} {old:8.2f} {new:8.2f} {new / old:8.3f}   "
                    f"{old_cpu:8.2f} {new_cpu:8.2f} {new_cpu / old_cpu:8.3f}   {rounds}"
                )
            if args.instructions:
                _instruction_table(trees)
            if args.optima:
                _optima(trees)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)


if __name__ == "__main__":
    main()
