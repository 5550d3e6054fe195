"""How far past its deadline an exact solve returns (ε of docs/solvers.md, "Deadlines"), under load.

Each exact backend solves hard instances with ``deadline = 50 ms``: s8 (a reference faster than
the RexROV; the hard NLP is infeasible, so the fallback chain runs) from rest and from states of
its first seconds, and the BlueROV2 Heavy holding station in a 1.5 m/s current (8 thrusters,
N = 10; fatrop's restoration phase hangs on some of these).  Every plugin is built first
(``backend.build()``), so what is measured is the solve.  While it runs, ``LOAD`` processes spin
on the CPU (``--load k``; default: one per core), the condition of issue 31's 1169 ms.

``overrun = wall time of solve - deadline`` (ms); ``hits`` = solves that reported
``deadline_hit``.  Run: ``python -m benchmarks.bench_deadline [--load k] [--repeats r]``
(also part of ``make bench``).
"""

from __future__ import annotations

import argparse
import os
import signal
import time

import numpy as np

import uuv_ocp as uo
from uuv_ocp.solvers import get_solver

DEADLINE = 0.05  # s
SOLVERS = ("ipopt", "sqp", "fatrop", "sqp-rti")


def _spin() -> None:  # a busy process: the load
    while True:
        pass


def _start_load(count: int) -> list[int]:
    pids = []
    for _ in range(count):
        pid = os.fork()
        if pid == 0:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            _spin()
        pids.append(pid)
    return pids


def _stop_load(pids: list[int]) -> None:
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


def instances() -> list[tuple[str, object, list[np.ndarray]]]:
    """``(label, problem, parameter vectors)`` of the measured instances."""
    s8 = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s8"))
    reference = s8.reference
    s8_ps = [s8.parameters(np.zeros(6), 0.0)] + [
        s8.parameters(reference.evaluate([t])[0] * 0.9, t) for t in (1.0, 2.0, 3.0)
    ]
    vehicle = uo.Vehicle6DOF.bluerov2_heavy(thrusters=True)
    hold = uo.TrackingProblem(vehicle, uo.Reference.hold((0.0, 0.0, 0.0, 0.0)), horizon=10)
    x0 = np.zeros(12)
    x0[:3] = (1.42, 0.0, -0.04)
    hold_ps = [hold.parameters(x0 * scale, 0.0, current=[1.5, 0.0, 0.0]) for scale in (0.0, 0.5, 1.0)]
    return [("s8 RexROV", s8, s8_ps), ("BlueROV2 1.5 m/s current", hold, hold_ps)]


def measure(repeats: int) -> list[dict]:
    """Overruns (s) per backend and instance family, with the hit counts."""
    rows = []
    for label, problem, ps in instances():
        for name in SOLVERS:
            backend = get_solver(problem, name, {"deadline": DEADLINE})
            build = getattr(backend, "build", None)
            if build is not None:
                build()
            for p in ps:  # builds anything left (sqp-rti's QP), untimed
                backend.solve(p)
            overruns, hits = [], 0
            for _ in range(repeats):
                for p in ps:
                    start = time.perf_counter()
                    result = backend.solve(p)
                    overruns.append(time.perf_counter() - start - DEADLINE)
                    hits += bool(result.details.get("deadline_hit", False))
            rows.append({"instances": label, "solver": name, "overruns": np.array(overruns), "hits": hits})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--load", type=int, default=os.cpu_count() or 1, help="busy processes (default: cores)"
    )
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv if argv is not None else [])
    pids = _start_load(args.load)
    try:
        rows = measure(args.repeats)
    finally:
        _stop_load(pids)
    print(f"\nDeadline {DEADLINE * 1e3:.0f} ms, {args.load} busy processes on {os.cpu_count()} cores:")
    header = ("instances", "solver", "solves", "hits", "median", "p95", "max")
    print("{:26s} {:8s} {:>6s} {:>5s} {:>8s} {:>8s} {:>8s}  overrun (ms)".format(*header))
    for row in rows:
        o = row["overruns"] * 1e3
        print(
            f"{row['instances']:26s} {row['solver']:8s} {o.size:6d} {row['hits']:5d} "
            f"{np.median(o):8.1f} {np.percentile(o, 95):8.1f} {o.max():8.1f}"
        )


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
