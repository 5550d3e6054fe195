"""Campaign throughput: the same trials on 2 local worker processes and on a 2-worker Dask LocalCluster.

Each executor runs the same fresh campaign (by default 8 trials of 30 s on s2 with sqp, N = 20:
the paper's trial length and horizon; the mismatch/current/noise defaults) into its own empty
folder; the time includes starting the workers, every trial and writing every record, i.e.
what a user waits for.  Runs per minute = trials / wall time; the overhead is Dask's time over
the local pool's, minus one.  Target: < 10 %.  The ``start``
column is the fixed part: starting the executor's workers and running one trivial task on each.

Run: ``python -m benchmarks.bench_campaign [--short]`` (part of ``make bench``; needs the dask
extra for the second row).  ``--short``: 8 trials of 10 s at N = 10, where the fixed start-up
and the scheduler's share of the two cores weigh more.
"""

from __future__ import annotations

import tempfile
import time

from uuv_ocp.studies.campaign import CampaignConfig, run_campaign
from uuv_ocp.studies.executors import TaskRunner


def startup(executor: str, workers: int = 2) -> float:
    """Wall time (s) to start ``executor``'s workers and run one trivial task on each."""
    start = time.perf_counter()
    with TaskRunner(executor, workers) as runner:
        list(runner.run(abs, [(i, (-i,)) for i in range(workers)]))
    return time.perf_counter() - start


def main(trials: int = 8, duration: float = 30.0, horizon: int = 20) -> dict[str, float]:
    """Print runs per minute per executor and Dask's overhead; return the wall times (s)."""
    config = CampaignConfig(reference="s2", solver="sqp", trials=trials, duration=duration, horizon=horizon)
    print(f"\ncampaign throughput: {trials} trials of {duration:g} s, s2, sqp, N = {horizon}, 2 workers")
    print(f"{'executor':<28}{'wall s':>8}{'runs/min':>10}{'vs local':>10}{'start s':>9}")
    times: dict[str, float] = {}
    for label, executor in (("local (2 processes)", "local"), ("dask (2-worker LocalCluster)", "dask")):
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            try:
                run_campaign(config, out, executor=executor, workers=2, progress=False)
            except ValueError as missing:  # the dask extra is not installed
                print(f"{label:<28}  skipped: {missing}")
                continue
            times[executor] = time.perf_counter() - start
        ratio = times[executor] / times["local"]
        print(
            f"{label:<28}{times[executor]:>8.1f}{60 * trials / times[executor]:>10.1f}{ratio:>10.2f}"
            f"{startup(executor):>9.1f}"
        )
    if "dask" in times:
        print(f"Dask overhead {100 * (times['dask'] / times['local'] - 1):+.1f} % (target < 10 %)")
    return times


if __name__ == "__main__":
    import sys

    main(duration=10.0, horizon=10) if "--short" in sys.argv[1:] else main()
