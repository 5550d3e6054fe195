"""Per-step time of every backend on two source trees, in one run (is any backend slower?).

Each round runs, for each tree in turn (alternating which goes first), one worker process per
tree that times ``NMPC.step`` over a short closed loop on s2 (RexROV, N = 20, dt = 0.1 s) for
every backend; the table gives the median over rounds of each tree's per-round median step and
their ratio.  Alternating trees within a round lets the machine's drift hit both alike.

Run: ``python -m benchmarks.bench_before_after --baseline /path/to/old/src [--rounds 5] [--clock cpu]``
(``--clock cpu``: the worker's CPU time per step, for a machine that other work loads)
(the baseline is another checkout's ``src`` folder, e.g. a ``git worktree`` of an older commit).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

#: backend -> options: every registered exact backend and swarm at the settings a closed loop
#: uses by default, plus one hybrid
BACKENDS = {
    "ipopt": None,
    "fatrop": None,
    "sqp": None,
    "sqp-rti": None,
    "igwo": None,
    "gwo": None,
    "pso": None,
    "ssa": None,
    "igwo+fatrop": None,
}
STEPS = 25

_WORKER = """
import json, sys, time
import numpy as np
import uuv_ocp as uo

steps, names = int(sys.argv[1]), json.loads(sys.argv[2])
clock = time.process_time if sys.argv[3] == "cpu" else time.perf_counter
problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)
plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
medians = {}
for name, options in names.items():
    controller = uo.NMPC(problem, name, options=options, seed=1)
    state = problem.reference.initial_state(0.0)
    control = np.zeros(3)
    controller.step(state, 0.0, control)  # builds and compiles outside the timing
    times = []
    for k in range(1, steps + 1):
        start = clock()
        record = controller.step(state, k * problem.dt, control)
        times.append(clock() - start)
        control = record.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    medians[name] = float(np.median(times))
print(json.dumps(medians))
"""


def _run(source: Path, steps: int, clock: str = "wall") -> dict[str, float]:
    environment = {**os.environ, "PYTHONPATH": str(source)}
    completed = subprocess.run(
        [sys.executable, "-c", _WORKER, str(steps), json.dumps(BACKENDS), clock],
        env=environment,
        capture_output=True,
        text=True,
        check=True,
    )
    result: dict[str, float] = json.loads(completed.stdout.strip().splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> int:
    """Print the before/after table (ms) of every backend."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, type=Path, help="the older tree's src folder")
    parser.add_argument("--current", type=Path, default=Path(__file__).resolve().parents[1] / "src")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        default="wall",
        help="cpu: the worker's CPU time per step, which other processes on a loaded machine do not inflate",
    )
    args = parser.parse_args(argv)
    trees = {"before": args.baseline.resolve(), "after": args.current.resolve()}
    rounds: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    for index in range(args.rounds):
        order = ("before", "after") if index % 2 == 0 else ("after", "before")
        for label in order:
            rounds[label].append(_run(trees[label], args.steps, args.clock))
        print(f"round {index + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    print(
        f"per-step median of NMPC.step on s2 (N = 20), {args.clock} clock, "
        f"median of {args.rounds} interleaved rounds"
    )
    print(f"before: {trees['before']}\nafter:  {trees['after']}")
    print(f"{'backend':>14} {'before ms':>10} {'after ms':>10} {'after/before':>13}")
    for name in BACKENDS:
        before = float(np.median([r[name] for r in rounds["before"]])) * 1e3
        after = float(np.median([r[name] for r in rounds["after"]])) * 1e3
        print(f"{name:>14} {before:10.3f} {after:10.3f} {after / before:13.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
