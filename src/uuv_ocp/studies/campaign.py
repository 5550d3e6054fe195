"""Monte Carlo campaigns: many closed-loop trials with random currents, noise and mismatch.

The paper (§4.2) ran every reference 50 times and averaged the maximum absolute error and the
error covariance per direction (its Tables 1–4).  :func:`run_campaign` does the same on our
model: trial ``i`` draws its current (speed, direction), its Gauss–Markov path and its
measurement noise from ``numpy.random.default_rng([seed, i])``, so any single trial can be
reproduced alone.  Every finished trial is written to ``<out>/<name>/trial_<i>.npz`` before
the next one starts; a rerun skips trials already on disk (resume), so an interrupted campaign
loses at most the trials in progress.

Executors: ``"local"`` (one process, in order) and ``"process"`` (a
``concurrent.futures.ProcessPoolExecutor`` with ``workers`` processes; each worker builds its
own solver).
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.control.disturbances import Current, MeasurementNoise
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.control.simulation import ClosedLoopResult, SimulationInterrupted, simulate
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.progress import ProgressBar
from uuv_ocp.reference.path import Reference
from uuv_ocp.tracking import TrackingProblem

EXECUTORS = ("local", "process")


@dataclass(frozen=True)
class CampaignConfig:
    """What a campaign runs.

    Parameters
    ----------
    reference : str
        Paper reference name (``"s1"`` … ``"s10"``).
    solver : str
        Solver name.
    trials : int
        Number of trials, >= 1.
    duration : float
        Simulated time per trial (s), > 0.
    max_current : float
        Trial current speeds are uniform in ``[0, max_current]`` (m/s), directions uniform.
    current_noise : float
        Gauss–Markov noise intensity of speed (m/s/√s) and direction (rad/√s).
    noise_std : tuple of 6 floats
        Measurement noise standard deviations (m, m, rad, m/s, m/s, rad/s).
    mismatch : bool
        Controller uses :meth:`Vehicle.rexrov_controller_model`, plant the exact RexROV.
    current_known : bool
        Whether the controller is told the measured current.
    horizon : int
        Shooting intervals.
    seed : int
        Campaign seed.
    solver_options : dict
        Backend options.
    """

    reference: str = "s2"
    solver: str = "ipopt"
    trials: int = 50
    duration: float = 30.0
    max_current: float = 0.5
    current_noise: float = 0.02
    noise_std: tuple[float, ...] = (0.02, 0.02, 0.005, 0.01, 0.01, 0.005)
    mismatch: bool = True
    current_known: bool = True
    horizon: int = 20
    seed: int = 0
    solver_options: dict = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        Reference.paper(self.reference)  # validates the name
        object.__setattr__(self, "trials", check.positive_int("trials", self.trials))
        object.__setattr__(self, "duration", check.positive_float("duration", self.duration))
        object.__setattr__(self, "max_current", check.nonnegative_float("max_current", self.max_current))
        object.__setattr__(
            self, "current_noise", check.nonnegative_float("current_noise", self.current_noise)
        )
        object.__setattr__(self, "noise_std", check.vector("noise_std", self.noise_std, 6, nonnegative=True))
        object.__setattr__(self, "horizon", check.positive_int("horizon", self.horizon))
        object.__setattr__(self, "seed", check.positive_int("seed", self.seed, minimum=0))

    @property
    def name(self) -> str:
        """Folder name: reference, solver, seed and a hash of every other setting."""
        settings = repr({key: getattr(self, key) for key in sorted(self.__dataclass_fields__)})
        digest = hashlib.sha256(settings.encode()).hexdigest()[:8]
        return f"{self.reference}_{self.solver.replace('+', '-')}_seed{self.seed}_{digest}"


@dataclass(frozen=True)
class CampaignResult:
    """Per-trial metrics and the paper-style averages.

    ``summary`` holds the mean over trials of ``max_abs_ex``, ``max_abs_ey`` (m),
    ``std_ex``, ``std_ey`` (m) and ``var_ex``, ``var_ey`` (m², the paper's "covariance"), and
    the total ``failures``; ``trials`` the per-trial metric dicts in trial order.
    """

    config: CampaignConfig
    trials: tuple[dict, ...]
    summary: dict
    directory: Path


def _trial_setup(config: CampaignConfig, index: int) -> tuple[Current, MeasurementNoise, int]:
    rng = np.random.default_rng([config.seed, index])
    current = Current(
        speed=float(rng.uniform(0.0, config.max_current)),
        direction=float(rng.uniform(-math.pi, math.pi)),
        speed_noise=config.current_noise,
        direction_noise=config.current_noise,
        max_speed=max(2.0, config.max_current),
    )
    return current, MeasurementNoise(config.noise_std), int(rng.integers(2**31))


def _trial_path(directory: str | Path, index: int) -> Path:
    return Path(directory) / f"trial_{index:04d}.npz"


def run_trial(config: CampaignConfig, index: int, directory: str | Path) -> dict:
    """Run (or load, if saved) trial ``index``; return its metrics."""
    path = _trial_path(directory, index)
    if path.exists():
        return ClosedLoopResult.load(str(path)).metrics()
    reference = Reference.paper(config.reference)
    model = Vehicle.rexrov_controller_model() if config.mismatch else Vehicle.rexrov()
    problem = TrackingProblem(model, reference, horizon=config.horizon)
    current, noise, simulation_seed = _trial_setup(config, index)
    controller = NMPC(problem, config.solver, options=config.solver_options or None, seed=simulation_seed)
    try:
        run = simulate(
            controller,
            reference.initial_state(reference.t_start),
            min(config.duration, problem.latest_start() - reference.t_start),
            current=current,
            current_known=config.current_known,
            noise=noise,
            plant=Vehicle.rexrov(),
            seed=simulation_seed,
        )
    except SimulationInterrupted as stop:  # no record of an unfinished trial is written
        raise KeyboardInterrupt(f"trial {index} interrupted; finished trials are saved") from stop
    partial = path.with_suffix(".partial.npz")
    run.save(str(partial))
    partial.replace(path)  # atomic: a killed run never leaves a half-written trial
    return run.metrics()


def run_campaign(
    config: CampaignConfig,
    out_dir: str | Path = "out/campaigns",
    *,
    executor: str = "local",
    workers: int = 2,
    progress: bool = True,
) -> CampaignResult:
    """Run all trials of ``config`` (resuming saved ones) and summarise them."""
    if not isinstance(config, CampaignConfig):
        raise ValueError(f"config must be a CampaignConfig, got {type(config).__name__}")
    check.choice("executor", executor, EXECUTORS)
    workers = check.positive_int("workers", workers)
    directory = Path(out_dir) / config.name
    directory.mkdir(parents=True, exist_ok=True)
    metrics: dict[int, dict] = {}
    saved = [i for i in range(config.trials) if _trial_path(directory, i).exists()]
    for index in saved:  # resumed trials load in milliseconds: not part of the bar's rate
        metrics[index] = run_trial(config, index, directory)
    pending = [i for i in range(config.trials) if i not in metrics]
    with ProgressBar(config.trials, f"campaign {config.name}", progress, initial=len(saved)) as bar:
        if executor == "local":
            for index in pending:
                metrics[index] = run_trial(config, index, directory)
                bar.update(1)
        elif pending:
            with concurrent.futures.ProcessPoolExecutor(max_workers=workers) as pool:
                futures = {pool.submit(run_trial, config, i, directory): i for i in pending}
                for future in concurrent.futures.as_completed(futures):
                    metrics[futures[future]] = future.result()
                    bar.update(1)
    trials = tuple(metrics[i] for i in range(config.trials))
    return CampaignResult(config, trials, summarise(trials), directory)


def summarise(trials: Sequence[dict]) -> dict:
    """Paper-style averages over trials (see :class:`CampaignResult`)."""
    keys = ("max_abs_ex", "max_abs_ey", "std_ex", "std_ey", "var_ex", "var_ey", "solve_time_median")
    summary = {f"mean_{key}": float(np.mean([trial[key] for trial in trials])) for key in keys}
    summary["failures"] = float(np.sum([trial["failures"] for trial in trials]))
    summary["trials"] = float(len(trials))
    return summary


def format_summary(result: CampaignResult) -> str:
    """Two-line text summary in the units of the paper's tables."""
    s = result.summary
    return (
        f"{result.config.name}: {int(s['trials'])} trials, mean max|e_x| {s['mean_max_abs_ex']:.3f} m, "
        f"mean max|e_y| {s['mean_max_abs_ey']:.3f} m, mean std e_x {s['mean_std_ex']:.3f} m, "
        f"mean std e_y {s['mean_std_ey']:.3f} m\n"
        f"mean var e_x {s['mean_var_ex']:.4f} m², mean var e_y {s['mean_var_ey']:.4f} m², "
        f"failures {int(s['failures'])}, median solve time {1e3 * s['mean_solve_time_median']:.2f} ms"
    )
