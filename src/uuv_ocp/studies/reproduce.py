"""Reproduce the paper's experiment end to end: campaigns, tables, figures, verdicts.

:func:`reproduce` runs one Monte Carlo campaign (:func:`~uuv_ocp.studies.campaign.run_campaign`)
per reference and solver with the paper's stated settings — ten references, 50 trials each,
a Gauss–Markov current, measurement noise, the controller on uuv_simulator's rounded RexROV
parameters against the exact plant — and writes ``report.md`` with the paper's Tables 1–4
beside ours, the equivalents of its Figures 5 and 7–12, the solve time per step of every
solver, a measured time-to-band and a verdict on every claim (:mod:`uuv_ocp.studies.report`).
The paper's numbers come from :mod:`uuv_ocp.studies.paper_data`; every other number in the
report is computed from the saved trials.  Beside the paper's setting (the current known to
the controller, the full state measured with noise), Tables 1–2 get a column "current unknown,
estimated": the IGWO campaigns again, the controller given the state and current an EKF
infers from the vehicle's sensors (:attr:`ReproductionSettings.estimator`); the verdicts stay
on the paper's setting.

Campaigns resume: a rerun of the same command loads the finished trials and runs only the
missing ones, so Ctrl-C loses at most the trials in progress.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from uuv_ocp.studies.campaign import CampaignResult, run_campaign
from uuv_ocp.studies.report import write_report
from uuv_ocp.studies.reproduction import (
    COMPARISON_REFERENCE,
    ESTIMATOR,
    FULL_BUDGETS,
    HYBRID,
    PRIMARY_BAND,
    QUICK_BUDGETS,
    QUICK_DURATION,
    QUICK_REFERENCES,
    QUICK_TRIALS,
    SOLVERS,
    TABLE_SOLVER,
    TIGHT_BAND,
    ReproductionResult,
    ReproductionSettings,
    SpeedLimit,
    load_trials,
    speed_limit,
    time_to_band,
)

__all__ = [
    "COMPARISON_REFERENCE",
    "ESTIMATOR",
    "FULL_BUDGETS",
    "HYBRID",
    "PRIMARY_BAND",
    "QUICK_BUDGETS",
    "QUICK_DURATION",
    "QUICK_REFERENCES",
    "QUICK_TRIALS",
    "SOLVERS",
    "TABLE_SOLVER",
    "TIGHT_BAND",
    "ReproductionResult",
    "ReproductionSettings",
    "SpeedLimit",
    "load_trials",
    "reproduce",
    "speed_limit",
    "time_to_band",
]


def reproduce(
    out_dir: str | Path,
    *,
    quick: bool = False,
    trials: int | None = None,
    references: Sequence[str] | None = None,
    solvers: Sequence[str] | None = None,
    every_pair: bool = False,
    executor: str = "local",
    workers: int = 2,
    progress: bool = True,
) -> ReproductionResult:
    """Run the paper's experiment and write ``out_dir/report.md`` with its figures.

    Parameters
    ----------
    out_dir : str or Path
        Output folder: ``report.md``, ``figures/``, and the campaigns in ``campaigns/``
        (resumed by a rerun with the same settings).
    quick : bool
        Reduced size for CI (:meth:`ReproductionSettings.quick_settings`).
    trials : int, optional
        Trials per reference and solver (default: 50, quick: 2).
    references, solvers : sequence of str, optional
        Subsets to run (default: all ten references, :data:`SOLVERS`; quick: s1, s2, s5).
    every_pair : bool
        Every solver on every reference, not only on s2 (:class:`ReproductionSettings`).
    executor, workers : str, int
        Passed to :func:`~uuv_ocp.studies.campaign.run_campaign`.
    progress : bool
        Progress bars, and one line per campaign on standard error.

    Returns
    -------
    ReproductionResult
    """
    changes: dict[str, Any] = {}
    if trials is not None:
        changes["trials"] = trials
    if references is not None:
        changes["references"] = tuple(references)
    if solvers is not None:
        changes["solvers"] = tuple(solvers)
    if every_pair:
        changes["every_pair"] = True
    settings = ReproductionSettings.quick_settings(**changes) if quick else ReproductionSettings(**changes)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    campaigns: dict[tuple[str, str], CampaignResult] = {}
    elapsed: dict[tuple[str, str], float] = {}
    estimated: dict[str, CampaignResult] = {}
    configs = settings.configs()
    extra = settings.estimated_configs()
    total = len(configs) + len(extra)
    for number, config in enumerate([*configs, *extra], start=1):
        column = config.estimator is not None
        if progress:
            loop = f" + {config.estimator} (current unknown)" if column else ""
            print(f"[{number}/{total}] {config.reference} {config.solver}{loop}", file=sys.stderr, flush=True)
        start = time.perf_counter()
        result = run_campaign(
            config, out / "campaigns", executor=executor, workers=workers, progress=progress
        )
        if column:  # its time counts in the total, under its own key
            estimated[config.reference] = result
            elapsed[config.reference, f"{config.solver}, {config.estimator}"] = time.perf_counter() - start
            continue
        elapsed[config.reference, config.solver] = time.perf_counter() - start
        campaigns[config.reference, config.solver] = result
    return write_report(settings, campaigns, elapsed, out, estimated)
