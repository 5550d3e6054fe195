"""Monte Carlo campaigns: many closed-loop trials with random currents, noise and mismatch.

The paper (§4.2) ran every reference 50 times and averaged the maximum absolute error and the
error covariance per direction (its Tables 1–4).  :func:`run_campaign` does the same for any
vehicle and reference that :class:`~uuv_ocp.tracking.TrackingProblem` and
:func:`~uuv_ocp.control.simulation.simulate` support (3-DOF and 6-DOF; the current is
horizontal): trial ``i`` draws its current (speed, direction), its Gauss–Markov path and its
measurement noise from ``numpy.random.default_rng([seed, i])``, so any single trial can be
reproduced alone, on any executor (:mod:`uuv_ocp.studies.executors`).

Records (:mod:`uuv_ocp.studies.records`): trial ``i`` is written to
``<out>/<name>/trial_<i>.npz`` with its full configuration (:meth:`CampaignConfig.trial_settings`:
vehicles, reference, solver and options, horizon, dt, duration, disturbances, seed, trial index,
package version) and a checksum, and indexed in ``<out>/index.sqlite``.  The folder ``<name>``
is keyed by everything but the trial count, so a rerun, or the same campaign with more trials,
reuses every sound record; a record that fails its checks is reported (:class:`RecordWarning`)
and recomputed, and a damaged index is moved aside and rebuilt (:class:`IndexWarning`).  An
interrupted campaign loses only the trials in progress and writes no record of them; a local
worker process that dies is replaced and its trials rerun (:class:`WorkerRestartWarning`).
A full disk or a locked index stops the campaign with a one-line :class:`StorageError`.
A trial whose run faults (non-finite measurement, plant blow-up) is recorded
up to the fault and counted in the summary's ``faults``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._version import __version__
from uuv_ocp.control.disturbances import Current, MeasurementNoise
from uuv_ocp.control.faults import RandomFaults, ThrusterFault
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.control.simulation import ClosedLoopResult, SimulationInterrupted, simulate
from uuv_ocp.estimation.base import Estimator, EstimatorOptions, available_estimators
from uuv_ocp.estimation.faults import FaultDetectorOptions
from uuv_ocp.estimation.sensors import Sensors
from uuv_ocp.interrupts import check_interrupt, remember_interrupts
from uuv_ocp.progress import ProgressBar
from uuv_ocp.reference.path import Reference
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.specs import reference_from_spec, vehicle_from_spec
from uuv_ocp.studies.executors import (
    EXECUTORS,
    MAX_TRIES,
    SchedulerUnreachable,
    TaskRunner,
    WorkerCrashed,
    WorkerRestartWarning,
    require_dask,
)
from uuv_ocp.studies.records import (
    INDEX_NAME,
    IndexWarning,
    RecordWarning,
    StorageError,
    canonical,
    check_index,
    check_writable,
    index_trial,
    query_trials,
    read_record,
    sweep_temporaries,
    write_record,
    write_text,
)
from uuv_ocp.tracking import TrackingProblem, vehicle_dimensions

__all__ = [
    "EXECUTORS",
    "INDEX_NAME",
    "CampaignConfig",
    "CampaignResult",
    "RandomFaults",
    "IndexWarning",
    "RecordWarning",
    "SchedulerUnreachable",
    "StorageError",
    "WorkerCrashed",
    "WorkerRestartWarning",
    "format_summary",
    "format_summary_table",
    "query_trials",
    "run_campaign",
    "run_campaigns",
    "run_trial",
    "summarise",
    "trial_task",
]

#: Vehicles whose rounded "controller" model ``mismatch=True`` uses when no model is named.
ROUNDED_MODELS = {"rexrov": "rexrov-controller"}


def _reference_fingerprint(reference: Reference, t_end: float) -> str:
    """SHA-256 of the reference's states sampled over the run: its content, whatever its source."""
    times = np.linspace(reference.t_start, min(reference.t_end, t_end), 257)
    samples = np.ascontiguousarray(reference.evaluate(times), dtype=float)
    return hashlib.sha256(samples.tobytes() + repr((reference.t_start, reference.t_end)).encode()).hexdigest()


@dataclass(frozen=True)
class CampaignConfig:
    """What a campaign runs.

    Parameters
    ----------
    reference : str
        Reference spec: a paper name (``"s1"`` … ``"s10"``) or anything
        :func:`uuv_ocp.specs.reference_from_spec` takes (``"waypoints FILE"``, ``FILE.toml``, …).
    solver : str
        Solver name.
    trials : int
        Number of trials, >= 1 (not part of the campaign's identity: more trials reuse the first).
    duration : float
        Simulated time per trial (s), > 0; shortened to the reference window.
    max_current : float
        Trial current speeds are uniform in ``[0, max_current]`` (m/s), directions uniform.
    current_noise : float
        Gauss–Markov noise intensity of speed (m/s/√s) and direction (rad/√s).
    noise_std : tuple of floats
        Measurement noise standard deviations, one per state (3-DOF: m, m, rad, m/s, m/s, rad/s).
    mismatch : bool
        The controller uses ``controller_model`` (default: the vehicle's rounded model,
        ``rexrov-controller`` for ``rexrov``), the plant ``vehicle``; else both use ``vehicle``.
    current_known : bool
        Whether the controller is told the measured current.
    horizon : int
        Shooting intervals.
    seed : int
        Campaign seed.
    solver_options : dict
        Backend options (plain data).
    vehicle : str
        Plant vehicle spec (``"rexrov"``, ``"bluerov2-heavy"``, ``"rexrov2"``, ``FILE.toml``).
    controller_model : str or None
        Vehicle spec of the controller's model when ``mismatch`` is true.
    dt : float
        Sampling time (s), > 0.
    current_decay : float
        Gauss–Markov decay rate of the current's speed and direction (1/s), >= 0.
    estimator : str or None
        ``None`` (default): the controller gets the state plus ``noise_std`` noise (and the
        current if ``current_known``).  A name of :func:`uuv_ocp.available_estimators`
        (``"ekf"``, ...): the controller gets the state, and unless ``current_known`` the
        current, that this estimator infers from the vehicle's sensor suite
        (:meth:`Sensors.auv <uuv_ocp.Sensors.auv>` of the controller's model; the sensors
        carry their own noise, so ``noise_std`` is not used).
    faults : RandomFaults or dict or None
        Thruster faults drawn per trial (:class:`~uuv_ocp.control.faults.RandomFaults`; a dict
        of its fields, as a campaign file's ``[faults]`` table gives it): trial ``i`` draws them
        from ``numpy.random.default_rng([seed, i, FAULT_STREAM])``, a stream of its own (the
        trial's current and noise are those of the fault-free campaign), and its record holds
        them (``faults_drawn`` in :meth:`trial_settings`).  Needs a vehicle whose controls are
        thruster forces (``"bluerov2-heavy-thrusters"``) for the plant and the controller.
    fault_tolerant : bool
        The fault-tolerant NMPC: the estimator also estimates a thruster-force bias, and the
        fault detector (:mod:`uuv_ocp.estimation.faults`, default options) tells the controller
        the estimated health.  Needs ``estimator`` and a thruster vehicle.  Default False.
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
    vehicle: str = "rexrov"
    controller_model: str | None = None
    dt: float = 0.1
    current_decay: float = 0.1
    estimator: str | None = None
    faults: RandomFaults | None = None
    fault_tolerant: bool = False

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        for name in ("reference", "solver", "vehicle"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"{name} must be a string, got {getattr(self, name)!r}")
        if self.controller_model is not None and not isinstance(self.controller_model, str):
            raise ValueError(
                f"controller_model must be a vehicle spec string or None, got {self.controller_model!r}"
            )
        REGISTRY.factory(self.solver)  # unknown names raise, naming the known ones
        object.__setattr__(self, "trials", check.positive_int("trials", self.trials))
        object.__setattr__(self, "duration", check.positive_float("duration", self.duration))
        object.__setattr__(self, "max_current", check.nonnegative_float("max_current", self.max_current))
        object.__setattr__(
            self, "current_noise", check.nonnegative_float("current_noise", self.current_noise)
        )
        object.__setattr__(
            self, "current_decay", check.nonnegative_float("current_decay", self.current_decay)
        )
        check.boolean("mismatch", self.mismatch)
        check.boolean("current_known", self.current_known)
        if self.estimator is not None and self.estimator not in available_estimators():
            raise ValueError(
                f"estimator must be one of {available_estimators()} or None, got {self.estimator!r}"
            )
        object.__setattr__(self, "horizon", check.positive_int("horizon", self.horizon))
        object.__setattr__(self, "dt", check.positive_float("dt", self.dt))
        object.__setattr__(self, "seed", check.positive_int("seed", self.seed, minimum=0))
        if not isinstance(self.solver_options, dict):
            raise ValueError(f"solver_options must be a dict, got {self.solver_options!r}")
        canonical(self.solver_options)  # plain data only: it is part of every record's key
        if self.mismatch and self.controller_model is None and self.vehicle not in ROUNDED_MODELS:
            raise ValueError(
                f"controller_model must name the controller's vehicle when mismatch is true for vehicle "
                f"{self.vehicle!r} (a rounded model is known only for {list(ROUNDED_MODELS)}), got None"
            )
        plant = self.plant()
        states = vehicle_dimensions(plant)[0]
        object.__setattr__(
            self, "noise_std", check.vector("noise_std", self.noise_std, states, nonnegative=True)
        )
        problem = self.problem()  # the horizon fits the reference, the model matches the plant
        self._check_faults(problem)

    def _check_faults(self, problem: TrackingProblem) -> None:
        """Validate ``faults`` and ``fault_tolerant`` (``ValueError`` names the field)."""
        faults = self.faults
        if isinstance(faults, dict):  # a campaign file's [faults] table
            try:
                faults = RandomFaults(**faults)
            except TypeError as error:
                raise ValueError(
                    f"faults: {error} (fields: count, window, kinds, effectiveness, stuck_range)"
                ) from None
            object.__setattr__(self, "faults", faults)
        if faults is not None and not isinstance(faults, RandomFaults):
            raise ValueError(
                f"faults must be a uuv_ocp.RandomFaults, a dict of its fields or None, got {faults!r}"
            )
        check.boolean("fault_tolerant", self.fault_tolerant)
        if faults is None and not self.fault_tolerant:
            return
        field_name = "faults" if faults is not None else "fault_tolerant"
        for role, vehicle in (("vehicle", self.plant()), ("controller_model", problem.vehicle)):
            if getattr(vehicle, "thrusters", None) is None or "health" not in {
                item.name for item in problem.model_parameters
            }:
                raise ValueError(
                    f"{field_name} needs a {role} whose controls are thruster forces "
                    f"(e.g. 'bluerov2-heavy-thrusters'), got {getattr(self, role) or self.model_spec!r}"
                )
        count = len(problem.vehicle.control_bound)
        if faults is not None and faults.count > count:
            raise ValueError(
                f"faults.count must be at most the vehicle's {count} thrusters, got {faults.count}"
            )
        if self.fault_tolerant and self.estimator is None:
            raise ValueError(
                "fault_tolerant needs an estimator (e.g. 'ekf'): the detector reads its thruster-force bias"
            )

    # ------------------------------------------------------------ what it builds
    @property
    def model_spec(self) -> str:
        """Vehicle spec of the controller's model."""
        if not self.mismatch:
            return self.vehicle
        return self.controller_model or ROUNDED_MODELS[self.vehicle]

    def plant(self) -> Any:
        """Return the plant vehicle."""
        return vehicle_from_spec(self.vehicle)

    def problem(self) -> TrackingProblem:
        """Return the controller's tracking problem."""
        model = vehicle_from_spec(self.model_spec)
        if vehicle_dimensions(model) != vehicle_dimensions(self.plant()):
            raise ValueError(
                f"controller_model must have the plant's dimensions {vehicle_dimensions(self.plant())}, "
                f"got {self.model_spec!r} with {vehicle_dimensions(model)}"
            )
        reference = reference_from_spec(self.reference, spatial=model.layout.reference == "spatial")
        return TrackingProblem(model, reference, horizon=self.horizon, dt=self.dt)

    def run_duration(self, problem: TrackingProblem | None = None) -> float:
        """Return the simulated time of each trial (s): ``duration`` inside the reference window."""
        problem = problem or self.problem()
        return min(self.duration, problem.latest_start() - problem.reference.t_start)

    def steps(self, problem: TrackingProblem | None = None) -> int:
        """Control steps of a trial that does not fault."""
        return int(np.floor(self.run_duration(problem) / self.dt + 1e-9))

    def settings(self) -> dict[str, Any]:
        """Return a copy of :attr:`_settings`: the configuration except the trial count."""
        return dict(self._settings)

    @functools.cached_property
    def _settings(self) -> dict[str, Any]:
        """The campaign's full configuration except the trial count, as plain data.

        Vehicles and reference are given by spec and by content (parameter values; the
        reference's states sampled over the run), so an edited vehicle or waypoint file makes a
        new campaign.
        """
        problem = self.problem()
        duration = self.run_duration(problem)
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "trials"}
        if self.estimator is None:  # the campaigns without one keep the names they had
            del values["estimator"]
        else:
            values["sensors"] = "auv"
        for name in ("faults", "fault_tolerant"):  # likewise the campaigns without faults
            if not values[name]:
                del values[name]
        values.update(
            model=self.model_spec,
            plant_content=self.plant(),
            model_content=problem.vehicle,
            reference_content=_reference_fingerprint(
                problem.reference, problem.reference.t_start + duration + self.horizon * self.dt
            ),
            run_duration=duration,
            version=__version__,
        )
        return values

    def trial_settings(self, index: int) -> dict[str, Any]:
        """Return the configuration of trial ``index``: :meth:`settings`, the index, its faults."""
        settings = {**self.settings(), "trial": int(index)}
        if self.faults is not None:  # the drawn faults, so that a record says what it flew
            settings["faults_drawn"] = [dataclasses.asdict(item) for item in trial_faults(self, index)]
        return settings

    @property
    def name(self) -> str:
        """Folder name: reference, solver, seed and a hash of every setting but the trial count."""
        digest = hashlib.sha256(canonical(self.settings()).encode()).hexdigest()[:12]
        label = re.sub(r"[^A-Za-z0-9.-]+", "-", Path(self.reference).name)[:32].strip("-")
        vehicle = (
            "" if self.vehicle == "rexrov" else re.sub(r"[^A-Za-z0-9.-]+", "-", Path(self.vehicle).stem) + "_"
        )
        return f"{vehicle}{label}_{self.solver.replace('+', '-')}_seed{self.seed}_{digest}"


@dataclass(frozen=True)
class CampaignResult:
    """Per-trial metrics and the paper-style averages.

    ``summary`` holds the mean over the trials that ran to their end of ``max_abs_ex``,
    ``max_abs_ey`` (m), ``std_ex``, ``std_ey`` (m), ``var_ex``, ``var_ey`` (m², the paper's
    "covariance") and ``solve_time_median`` (s); the total ``failures`` (fallback steps),
    ``faults`` (trials stopped by a fault), ``trials``; ``trials`` the per-trial metric dicts
    in trial order (faulted ones included, up to their fault); ``faults`` the fault reason per
    trial (``None`` for a complete one); ``recomputed`` the trials whose saved record failed its
    checks; ``resumed`` how many trials were read back from sound records.
    """

    config: CampaignConfig
    trials: tuple[dict, ...]
    summary: dict
    directory: Path
    faults: tuple[str | None, ...] = ()
    recomputed: tuple[int, ...] = ()
    resumed: int = 0


def _trial_setup(config: CampaignConfig, index: int) -> tuple[Current, MeasurementNoise, int]:
    rng = np.random.default_rng([config.seed, index])
    current = Current(
        speed=float(rng.uniform(0.0, config.max_current)),
        direction=float(rng.uniform(-math.pi, math.pi)),
        speed_noise=config.current_noise,
        direction_noise=config.current_noise,
        decay=config.current_decay,
        max_speed=max(2.0, config.max_current),
    )
    return current, MeasurementNoise(config.noise_std), int(rng.integers(2**31))


#: Third word of a trial's fault generator seed ``[seed, trial, FAULT_STREAM]``: a stream apart
#: from the trial's current and noise, which stay those of the campaign without faults.
FAULT_STREAM = 27
#: Random-walk intensity (N/√s) of the fault-tolerant NMPC's thruster-force bias: the value the
#: detector's defaults were tuned with (:mod:`uuv_ocp.estimation.faults`).
FAULT_BIAS_STD = 5.0


def trial_faults(config: CampaignConfig, index: int) -> tuple[ThrusterFault, ...]:
    """Return trial ``index``'s drawn thruster faults (none without ``config.faults``)."""
    if config.faults is None:
        return ()
    problem = config.problem()
    rng = np.random.default_rng([config.seed, index, FAULT_STREAM])
    return config.faults.draw(rng, problem.vehicle.control_bound, t0=problem.reference.t_start)


def _trial_path(directory: str | Path, index: int) -> Path:
    return Path(directory) / f"trial_{index:04d}.npz"


def trial_task(config: CampaignConfig, index: int) -> ClosedLoopResult:
    """Simulate trial ``index`` of ``config``: the one task function of every executor.

    Writes nothing: the campaign driver records what this returns.  A Ctrl-C raises
    ``KeyboardInterrupt`` without a result.
    """
    problem = config.problem()
    current, noise, simulation_seed = _trial_setup(config, index)
    controller = NMPC(problem, config.solver, options=config.solver_options or None, seed=simulation_seed)
    # with an estimator the sensors carry the noise; the estimator runs on the controller's model
    sensing: dict[str, Any] = {"noise": noise, "faults": trial_faults(config, index)}
    if config.estimator is not None:
        sensors = Sensors.auv(problem.vehicle)
        # the fault-tolerant NMPC's detector reads the estimator's thruster-force bias
        options = EstimatorOptions(bias=True, bias_std=FAULT_BIAS_STD) if config.fault_tolerant else None
        estimator = Estimator(problem, config.estimator, sensors=sensors, options=options)
        sensing = {"estimator": estimator, "faults": sensing["faults"]}
        if config.fault_tolerant:
            sensing["fault_detector"] = FaultDetectorOptions()
    try:
        return simulate(
            controller,
            problem.initial_state(),
            config.run_duration(problem),
            current=current,
            current_known=config.current_known,
            plant=config.plant(),
            seed=simulation_seed,
            **sensing,
        )
    except SimulationInterrupted as stop:  # no record of an unfinished trial is written
        raise KeyboardInterrupt(f"trial {index} interrupted; finished trials are saved") from stop


def _index_row(
    config: CampaignConfig, index: int, directory: Path, run: ClosedLoopResult, digest: str
) -> dict:
    """Write trial ``index``'s row of the folder's index; return its metrics."""
    metrics = run.metrics()
    index_trial(
        directory.parent,
        _trial_path(directory, index),
        campaign=config.name,
        trial=index,
        config=config.trial_settings(index),
        digest=digest,
        run=run,
        metrics=metrics,
    )
    return metrics


def _record(config: CampaignConfig, index: int, directory: Path, run: ClosedLoopResult) -> dict:
    """Write trial ``index``'s record and index row; return its metrics."""
    digest = write_record(_trial_path(directory, index), run, config.trial_settings(index))
    return _index_row(config, index, directory, run, digest)


def _load(
    config: CampaignConfig, index: int, directory: Path, steps: int
) -> tuple[ClosedLoopResult, str] | None:
    return read_record(_trial_path(directory, index), config.trial_settings(index), steps=steps)


def run_trial(config: CampaignConfig, index: int, directory: str | Path) -> dict:
    """Run trial ``index`` into the campaign folder ``directory`` (or read its sound record).

    Returns the trial's metrics (:meth:`ClosedLoopResult.metrics`).
    """
    directory = Path(directory)
    saved = _load(config, index, directory, config.steps())
    if saved is not None:
        return saved[0].metrics()
    return _record(config, index, directory, trial_task(config, index))


def run_campaign(
    config: CampaignConfig,
    out_dir: str | Path = "out/campaigns",
    *,
    executor: str = "local",
    workers: int = 2,
    progress: bool = True,
    scheduler: str | None = None,
) -> CampaignResult:
    """Run all trials of ``config`` (reusing sound records) and summarise them.

    Parameters
    ----------
    config : CampaignConfig
    out_dir : str or Path
        Output folder: the campaign's records go to ``out_dir / config.name``, the index to
        ``out_dir / "index.sqlite"``.  Checked writable before any trial runs.
    executor : {"local", "dask", "process"}
        ``"local"``: ``workers`` processes on this machine (in this process for ``workers=1``);
        ``"dask"``: dask.distributed (a LocalCluster of ``workers`` processes, or the cluster at
        ``scheduler``); ``"process"``: the local pool even for one worker.
    workers : int
        Worker processes, >= 1.
    progress : bool
        Show a progress bar.
    scheduler : str, optional
        Dask scheduler address ``tcp://host:port`` (``executor="dask"`` only).

    Returns
    -------
    CampaignResult

    Raises
    ------
    StorageError
        A record or the index could not be written (disk full, quota, a locked index); one
        line naming the folder.  Every finished trial is saved: rerunning resumes.
    WorkerCrashed
        A trial's local worker process died each of :data:`~uuv_ocp.studies.executors.MAX_TRIES`
        times it ran; raised after every other trial is recorded.
    SchedulerUnreachable
        ``scheduler`` did not answer within
        :data:`~uuv_ocp.studies.executors.DASK_CONNECT_TIMEOUT` seconds.
    """
    return run_campaigns(
        [config], out_dir, executor=executor, workers=workers, progress=progress, scheduler=scheduler
    )[0]


def run_campaigns(
    configs: Sequence[CampaignConfig],
    out_dir: str | Path = "out/campaigns",
    *,
    executor: str = "local",
    workers: int = 2,
    progress: bool = True,
    scheduler: str | None = None,
) -> tuple[CampaignResult, ...]:
    """Run several campaigns on one executor (started once, trials of all campaigns interleaved).

    Parameters are those of :func:`run_campaign`, with a sequence of configurations; each
    campaign gets its own folder in ``out_dir``.  Returns one :class:`CampaignResult` per
    configuration, in order.
    """
    configs, workers = _checked_configs(configs, executor, workers, scheduler)
    out = check_writable(out_dir)
    repaired = check_index(out)
    if repaired:
        warnings.warn(repaired, IndexWarning, stacklevel=3)
    metrics, faults, recomputed = _resume(configs, out)
    resumed = [len(m) for m in metrics]
    pending = [
        ((c, i), (config, i))
        for c, config in enumerate(configs)
        for i in range(config.trials)
        if i not in metrics[c]
    ]
    total = sum(config.trials for config in configs)
    label = f"campaign {configs[0].name}" if len(configs) == 1 else f"{len(configs)} campaigns"
    # remember_interrupts: a Ctrl-C that CasADi swallows while a trial's problem is built is
    # raised by that trial's first closed-loop step, or after the record being written
    crashed: list[str] = []

    def restarted(message: str, keys: list) -> None:
        trials = ", ".join(f"{configs[c].name} trial {i}" for c, i in keys)
        warnings.warn(f"{message}: {trials}", WorkerRestartWarning, stacklevel=2)

    with ProgressBar(total, label, progress, initial=sum(resumed)) as bar, remember_interrupts():
        if pending:
            with TaskRunner(executor, workers, scheduler, on_restart=restarted) as runner:
                for (c, index), run in runner.run(trial_task, pending):
                    config = configs[c]
                    if isinstance(run, WorkerCrashed):  # the others go on; reported at the end
                        crashed.append(f"{config.name} trial {index}")
                        continue
                    metrics[c][index] = _record(config, index, out / config.name, run)
                    faults[c][index] = run.fault
                    bar.update(1)
                    check_interrupt()
    if crashed:
        raise WorkerCrashed(
            f"{', '.join(crashed)}: the worker process died each of the {MAX_TRIES} times it ran "
            "(killed, out of memory, or a crash in native code); no record written for "
            f"{'it' if len(crashed) == 1 else 'them'}, every other trial is saved (rerun to retry)"
        )
    return tuple(
        _write_result(config, metrics[c], faults[c], recomputed[c], resumed[c], out / config.name)
        for c, config in enumerate(configs)
    )


def _checked_configs(
    configs: Sequence[CampaignConfig], executor: str, workers: object, scheduler: object
) -> tuple[list[CampaignConfig], int]:
    """Refuse a bad argument of :func:`run_campaigns` by name; return the configurations and workers."""
    configs = list(configs)
    if not configs or not all(isinstance(config, CampaignConfig) for config in configs):
        raise ValueError(f"configs must be a non-empty sequence of CampaignConfig, got {configs!r}")
    if len({config.name for config in configs}) != len(configs):
        raise ValueError("configs must be different campaigns, got the same campaign twice")
    check.choice("executor", executor, EXECUTORS)
    workers = check.positive_int("workers", workers)
    if scheduler is not None:
        if executor != "dask":
            raise ValueError(f"scheduler is for executor 'dask', got executor {executor!r}")
        if not isinstance(scheduler, str) or "://" not in scheduler:
            raise ValueError(f"scheduler must be an address like 'tcp://host:8786', got {scheduler!r}")
    if executor == "dask":
        require_dask()
    return configs, workers


def _resume(
    configs: list[CampaignConfig], out: Path
) -> tuple[list[dict[int, dict]], list[dict[int, str | None]], list[list[int]]]:
    """Read back every sound trial record: metrics and faults by trial, and the refused ones."""
    metrics: list[dict[int, dict]] = [{} for _ in configs]
    faults: list[dict[int, str | None]] = [{} for _ in configs]
    recomputed: list[list[int]] = [[] for _ in configs]
    for c, config in enumerate(configs):  # resumed trials load in milliseconds: not part of the bar's rate
        directory = out / config.name
        directory.mkdir(exist_ok=True)
        sweep_temporaries(directory)  # what writers killed mid-write left
        steps = config.steps()
        for index in range(config.trials):
            existed = _trial_path(directory, index).exists()
            saved = _load(config, index, directory, steps)
            if saved is None:
                if existed:
                    recomputed[c].append(index)
                continue
            run, digest = saved
            # rebuild the index row: the files are the authority
            metrics[c][index], faults[c][index] = _index_row(config, index, directory, run, digest), run.fault
    return metrics, faults, recomputed


def _write_result(
    config: CampaignConfig,
    metrics: dict[int, dict],
    faults: dict[int, str | None],
    recomputed: list[int],
    resumed: int,
    directory: Path,
) -> CampaignResult:
    """Return one campaign's result; write its configuration and summary beside its trials."""
    trials = tuple(metrics[i] for i in range(config.trials))
    fault_list = tuple(faults[i] for i in range(config.trials))
    result = CampaignResult(
        config, trials, summarise(trials, fault_list), directory, fault_list, tuple(recomputed), resumed
    )
    write_text(directory / "config.toml", _config_toml(config), "campaign file")
    write_text(directory / "summary.txt", format_summary(result) + "\n", "summary")
    return result


def _config_toml(config: CampaignConfig) -> str:
    """Return the configuration as a campaign file (:mod:`uuv_ocp.studies.campaign_file`) of one solver."""
    return to_toml([config])


#: keys of a campaign file's ``[campaign]`` and ``[disturbance]`` tables (CampaignConfig fields,
#: plus ``solvers``): read by :mod:`uuv_ocp.studies.campaign_file`, written by :func:`to_toml`
CAMPAIGN_KEYS = (
    "vehicle",
    "controller_model",
    "reference",
    "solver",
    "solvers",
    "trials",
    "duration",
    "horizon",
    "dt",
    "seed",
)
DISTURBANCE_KEYS = (
    "max_current",
    "current_noise",
    "current_decay",
    "current_known",
    "noise_std",
    "mismatch",
    "estimator",
)
#: keys of a campaign file's ``[faults]`` table: RandomFaults' fields and ``fault_tolerant``
FAULT_KEYS = ("count", "window", "kinds", "effectiveness", "stuck_range", "fault_tolerant")


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_value(str(k))} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


def to_toml(configs: Sequence[CampaignConfig]) -> str:
    """Return a campaign file that :func:`~uuv_ocp.studies.campaign_file.load_campaign_file` reads back.

    The file's format is :mod:`uuv_ocp.studies.campaign_file`'s; it reads back to ``configs``,
    which must differ only in their solver (and its options).
    """
    first = configs[0]
    lines = ["[campaign]"]
    for key in CAMPAIGN_KEYS:
        if key == "solver":
            continue
        if key == "solvers":
            lines.append(f"solvers = {_toml_value([c.solver for c in configs])}")
        elif getattr(first, key) is not None:
            lines.append(f"{key} = {_toml_value(getattr(first, key))}")
    lines.append("\n[disturbance]")
    lines += [
        f"{key} = {_toml_value(getattr(first, key))}"
        for key in DISTURBANCE_KEYS
        if getattr(first, key) is not None  # no estimator: the key is left out
    ]
    if first.faults is not None or first.fault_tolerant:
        lines.append("\n[faults]")
        if first.faults is not None:
            lines += [
                f"{item.name} = {_toml_value(getattr(first.faults, item.name))}"
                for item in dataclasses.fields(first.faults)
            ]
        lines.append(f"fault_tolerant = {_toml_value(first.fault_tolerant)}")
    for config in configs:
        if config.solver_options:
            lines.append(f'\n[solver_options."{config.solver}"]')
            lines += [f"{key} = {_toml_value(value)}" for key, value in config.solver_options.items()]
    return "\n".join(lines) + "\n"


def summarise(trials: Sequence[dict], faults: Sequence[str | None] | None = None) -> dict:
    """Paper-style averages over trials (see :class:`CampaignResult`).

    Parameters
    ----------
    trials : sequence of dict
        Per-trial metrics (:meth:`ClosedLoopResult.metrics`).
    faults : sequence of str or None, optional
        Fault reason per trial; faulted trials are counted in ``faults`` and left out of the
        means (their errors stop at the fault).  Default: no faults.
    """
    faults = list(faults) if faults is not None else [None] * len(trials)
    if len(faults) != len(trials):
        raise ValueError(f"faults must have one entry per trial ({len(trials)}), got {len(faults)}")
    complete = [trial for trial, fault in zip(trials, faults, strict=True) if fault is None]
    keys = ("max_abs_ex", "max_abs_ey", "std_ex", "std_ey", "var_ex", "var_ey", "solve_time_median")
    summary = {
        f"mean_{key}": float(np.mean([trial[key] for trial in complete])) if complete else math.nan
        for key in keys
    }
    summary["failures"] = float(np.sum([trial["failures"] for trial in trials]))
    summary["faults"] = float(len(trials) - len(complete))
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
        f"failures {int(s['failures'])}, faults {int(s.get('faults', 0))}, "
        f"median solve time {1e3 * s['mean_solve_time_median']:.2f} ms"
    )


def format_summary_table(results: Sequence[CampaignResult]) -> str:
    """One row per campaign: trials, faults, fallback steps, mean errors (m), median solve time (ms)."""
    header = (
        f"{'vehicle':<16}{'reference':<12}{'solver':<12}{'trials':>7}{'faults':>7}{'fail':>6}"
        f"{'max|ex|':>9}{'max|ey|':>9}{'std ex':>8}{'std ey':>8}{'var ex':>9}{'var ey':>9}{'med ms':>8}"
    )
    lines = [header, "-" * len(header)]
    for result in results:
        s, c = result.summary, result.config
        lines.append(
            f"{c.vehicle[:15]:<16}{c.reference[:11]:<12}{c.solver[:11]:<12}{int(s['trials']):>7}"
            f"{int(s['faults']):>7}{int(s['failures']):>6}{s['mean_max_abs_ex']:>9.3f}{s['mean_max_abs_ey']:>9.3f}"
            f"{s['mean_std_ex']:>8.3f}{s['mean_std_ey']:>8.3f}{s['mean_var_ex']:>9.4f}{s['mean_var_ey']:>9.4f}"
            f"{1e3 * s['mean_solve_time_median']:>8.2f}"
        )
    return "\n".join(lines)
