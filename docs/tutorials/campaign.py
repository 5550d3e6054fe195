"""A Monte Carlo campaign: random currents, noise and mismatch; resume with more trials; query the index.

The campaign runs NMPC on the s2 reference: each trial draws a current (speed uniform in
[0, 0.5] m/s, any direction, Gauss–Markov fluctuations) and measurement noise from the seed and
its index, and the controller uses uuv_simulator's rounded RexROV coefficients against the
exact RexROV plant.  It then asks for more trials: the folder is keyed by everything but the
trial count, so the first trials are read back (checked) and only the new ones run.  It reads
the SQLite index of finished trials, and last runs the same campaign on a 2-worker Dask
``LocalCluster`` (the ``dask`` extra; ``--scheduler tcp://host:port`` on the command line joins a
real cluster), which gives the same records.

Run: ``python docs/tutorials/campaign.py`` (writes into ``out/tutorials/campaign``).
"""

from __future__ import annotations

import sys
from pathlib import Path

from uuv_ocp.studies.campaign import CampaignConfig, format_summary, query_trials, run_campaign


def main(
    trials: int = 6,
    more: int = 8,
    duration: float = 15.0,
    horizon: int = 10,
    solver: str = "sqp",
    workers: int = 2,
    out: str | Path = "out/tutorials/campaign",
    dask: bool = True,
) -> dict:
    """Run ``trials`` trials, then ``more``, then the same on Dask; return the results and index rows."""
    config = CampaignConfig(reference="s2", solver=solver, trials=trials, duration=duration, horizon=horizon)
    first = run_campaign(config, out, workers=workers, progress=False)
    print(format_summary(first))
    # the same campaign with more trials: the same folder, the first trials read back
    bigger = CampaignConfig(reference="s2", solver=solver, trials=more, duration=duration, horizon=horizon)
    second = run_campaign(bigger, out, workers=workers, progress=False)
    ran = more - second.resumed
    print(f"{more} trials: {second.resumed} read back from {second.directory.name}, {ran} run")
    print(format_summary(second))
    rows = query_trials(out, campaign=bigger.name)
    print(f"\n{'trial':>5}{'current m/s':>12}{'max|e_x| m':>12}{'max|e_y| m':>12}{'fallbacks':>10}")
    for row in rows:
        metrics, speed = row["metrics"], _mean_current_speed(Path(out) / row["path"])
        print(
            f"{row['trial']:>5}{speed:>12.2f}{metrics['max_abs_ex']:>12.3f}{metrics['max_abs_ey']:>12.3f}"
            f"{int(metrics['failures']):>10d}"
        )
    on_dask = None
    if dask:  # same trials, same task function, another engine: the same records
        from importlib.util import find_spec

        if find_spec("distributed") is None:
            print("\ndask is not installed (pip install 'uuv_ocp[dask]'): the Dask run is skipped")
        else:
            on_dask = run_campaign(bigger, Path(out) / "dask", executor="dask", workers=2, progress=False)
            same = [
                a["max_abs_ey"] == b["max_abs_ey"] for a, b in zip(second.trials, on_dask.trials, strict=True)
            ]
            print(f"\non a 2-worker Dask LocalCluster: {sum(same)} of {more} trials with the same errors")
    return {"first": first, "second": second, "rows": rows, "dask": on_dask}


def _mean_current_speed(record: Path) -> float:
    """Mean current speed (m/s) the plant felt in a trial, from its record."""
    import numpy as np

    from uuv_ocp import ClosedLoopResult

    run = ClosedLoopResult.load(str(record))
    return float(np.mean(np.hypot(run.currents[:, 0], run.currents[:, 1])))


if __name__ == "__main__":
    main()
    sys.exit(0)
