"""``make bench``: run every benchmark of the project in one process and print their tables."""

from __future__ import annotations

import importlib
import platform
import sys
import time

BENCHMARKS = (
    "benchmarks.bench_exact",
    "benchmarks.bench_swarm",
    "benchmarks.bench_igwo_step",
    "benchmarks.bench_mppi",
    "benchmarks.bench_codegen",
    "benchmarks.bench_swarm_functions",
    "benchmarks.bench_6dof",
    "benchmarks.bench_baseline",
    "benchmarks.bench_nonconvex",
    "benchmarks.bench_campaign",
    "benchmarks.bench_rti",
    "benchmarks.bench_rti_scaling",
    "benchmarks.bench_deadline",
)


def main() -> int:
    """Run the benchmarks that exist; a missing optional one is reported, not fatal."""
    machine = platform.processor() or platform.machine()
    print(f"uuv_ocp benchmarks — {machine}, Python {sys.version.split()[0]}")
    for name in BENCHMARKS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            print(f"\n[{name}] skipped: {error}")
            continue
        start = time.perf_counter()
        module.main()
        print(f"[{name}] {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
