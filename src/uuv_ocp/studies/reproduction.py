"""The paper's experiment as data: settings, budgets, bands, speed limits, loading the trials.

What :func:`uuv_ocp.studies.reproduce.reproduce` runs and :mod:`uuv_ocp.studies.report`
judges, in a module below both: the report reads these definitions, and ``reproduce`` runs the
campaigns and then writes the report (so neither imports the other in a loop).  Every name is
also importable from :mod:`uuv_ocp.studies.reproduce`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.estimation.base import available_estimators
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.reference.path import PAPER_REFERENCES, Reference
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.studies import paper_data
from uuv_ocp.studies.campaign import CampaignConfig, CampaignResult

__all__ = [
    "ESTIMATOR",
    "FULL_BUDGETS",
    "HYBRID",
    "QUICK_BUDGETS",
    "ReproductionResult",
    "ReproductionSettings",
    "SOLVERS",
    "SpeedLimit",
    "load_trials",
    "speed_limit",
    "time_to_band",
]

#: The hybrid the paper does not have: IGWO at its budget as the warm start of fatrop, the
#: fastest exact backend on the tracking problem (docs/benchmarks.md); pso+fatrop is marginally
#: better only on obstacle fields, where the swarm's homotopy class matters.
HYBRID = "igwo+fatrop"
#: The paper's four optimisers (Tables 3–4), then the exact solvers and the hybrid it lacks.
SOLVERS = ("igwo", "gwo", "ssa", "sqp", "ipopt", "fatrop", HYBRID)
#: The paper's budgets (population, iterations), §4.3 (:data:`paper_data.BUDGETS`).
FULL_BUDGETS: Mapping[str, tuple[int, int]] = paper_data.BUDGETS
#: Quick mode: small swarms, so that CI runs every solver on CasADi's virtual machine in minutes.
QUICK_BUDGETS: Mapping[str, tuple[int, int]] = MappingProxyType(
    {"igwo": (8, 6), "gwo": (8, 6), "ssa": (8, 6)}
)
#: Quick mode: references (case I, case II and one of Figure 10's), trials and duration (s).
QUICK_REFERENCES = ("s1", "s2", "s5")
QUICK_TRIALS = 2
QUICK_DURATION = 4.0
#: The solver of Tables 1–2 (§4.2: IGWO-NMPC on the ten references).
TABLE_SOLVER = "igwo"
#: The reference of Tables 3–4 and Figures 11–12 (case II, §4.3).
COMPARISON_REFERENCE = "s2"
#: Bands (m) of the time-to-band metric on ``|e_x|``: the paper's "stable at about 0.3 m" for
#: case II (:data:`paper_data.STABLE_LEVEL`), and a tighter one.
PRIMARY_BAND = paper_data.STABLE_LEVEL[COMPARISON_REFERENCE][1]
TIGHT_BAND = 0.1
#: The estimator of the column "current unknown, estimated" beside the paper's setting
ESTIMATOR = "ekf"


# ------------------------------------------------------------------------------ metrics
def time_to_band(result: ClosedLoopResult, band: float, *, axis: str = "x") -> float:
    """Time from the start after which the tracking error stays inside ``±band`` to the end.

    With ``e_k`` the error samples at ``t_k`` (``|x − x_R|`` for ``axis="x"``, ``|y − y_R|`` for
    ``"y"``, the larger of the two for ``"xy"``), let ``k`` be the last sample with
    ``|e_k| > band``.  The error is taken as linear between samples, so the run enters the band
    for good at ``t_k + (t_{k+1} − t_k)(|e_k| − band)/(|e_k| − |e_{k+1}|)``; the result is that
    time minus ``t_0``.  It is 0 if every sample is inside the band and ``inf`` if the last one
    is outside (the run never settles).

    Parameters
    ----------
    result : ClosedLoopResult
        A closed-loop run of a tracking problem.
    band : float
        Half-width of the band (m), > 0.
    axis : {"x", "y", "xy"}
        Which error.

    Returns
    -------
    float
        Time to band (s), in ``[0, t_n − t_0]`` or ``inf``.
    """
    band = check.positive_float("band", band)
    check.choice("axis", axis, ("x", "y", "xy"))
    errors = np.abs(np.asarray(result.errors, dtype=float))
    error = {"x": errors[:, 0], "y": errors[:, 1], "xy": np.max(errors, axis=1)}[axis]
    t = np.asarray(result.t, dtype=float)
    if error.size == 0 or not np.all(np.isfinite(error)):
        raise ValueError(f"result must have finite tracking errors, got {error.size} samples with NaN/inf")
    outside = np.flatnonzero(error > band)
    if outside.size == 0:
        return 0.0
    last = int(outside[-1])
    if last == error.size - 1:
        return math.inf
    # |e| is linear between the samples: where it crosses the band
    share = (error[last] - band) / (error[last] - error[last + 1])
    return float(t[last] + share * (t[last + 1] - t[last]) - t[0])


@dataclass(frozen=True)
class SpeedLimit:
    """When a reference's path speed passes the vehicle's top speeds (still water).

    Parameters
    ----------
    reference : str
        Reference name.
    surge_speed : float
        Surge-only top speed ``Vehicle.max_speed()[0]`` (m/s).
    crab_speed, crab_angle : float
        Top speed over ground with sway thrust, and its crab angle (m/s, rad;
        :meth:`Vehicle.max_horizontal_speed`).
    exceeds_surge_at, exceeds_crab_at : float or None
        First time (s) in ``[t_start, t_start + duration]`` the path speed exceeds each top
        speed; ``None`` if it does not.
    peak_speed : float
        Largest path speed on that interval (m/s).
    """

    reference: str
    surge_speed: float
    crab_speed: float
    crab_angle: float
    exceeds_surge_at: float | None
    exceeds_crab_at: float | None
    peak_speed: float


def speed_limit(
    name: str, duration: float = 30.0, vehicle: Vehicle | None = None, resolution: float = 0.01
) -> SpeedLimit:
    """Compute when the path speed of ``Reference.paper(name)`` passes the top speeds.

    The path speed ``hypot(u_R, v_R)`` (from the reference's AD derivatives) is sampled every
    ``resolution`` seconds and each first crossing is refined by bisection to 1e-9 s.

    Parameters
    ----------
    name : str
        Paper reference.
    duration : float
        Length of the interval from the reference's start (s), clipped to its window.
    vehicle : Vehicle, optional
        Default: the exact RexROV.
    resolution : float
        Sampling step (s) of the first search.
    """
    reference = Reference.paper(name)
    vehicle = Vehicle.rexrov() if vehicle is None else vehicle
    duration = check.positive_float("duration", duration)
    resolution = check.positive_float("resolution", resolution)
    end = min(reference.t_start + duration, reference.t_end)
    times = np.linspace(
        reference.t_start, end, max(2, int(math.ceil((end - reference.t_start) / resolution)) + 1)
    )

    def speed(t: np.ndarray) -> np.ndarray:
        states = reference.evaluate(np.atleast_1d(t))
        return np.hypot(states[:, 3], states[:, 4])

    speeds = speed(times)
    crab_speed, crab_angle = vehicle.max_horizontal_speed()
    surge = float(vehicle.max_speed()[0])

    def first_crossing(top: float) -> float | None:
        over = np.flatnonzero(speeds > top)
        if over.size == 0:
            return None
        k = int(over[0])
        if k == 0:
            return float(times[0])
        low, high = float(times[k - 1]), float(times[k])
        while high - low > 1e-9:
            middle = 0.5 * (low + high)
            low, high = (low, middle) if speed(np.array([middle]))[0] > top else (middle, high)
        return high

    return SpeedLimit(
        name,
        surge,
        crab_speed,
        crab_angle,
        first_crossing(surge),
        first_crossing(crab_speed),
        float(speeds.max()),
    )


# ----------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class ReproductionSettings:
    """What :func:`reproduce` runs.

    As in the paper: IGWO (:data:`TABLE_SOLVER`) on every reference (Tables 1–2) and every
    solver on :data:`COMPARISON_REFERENCE`, s2 (Tables 3–4); ``every_pair=True`` runs every
    solver on every reference.

    Parameters
    ----------
    references : tuple of str
        Paper references (default the ten of Tables 1–2).
    solvers : tuple of str
        Solver names (default :data:`SOLVERS`).
    trials : int
        Trials per reference and solver (paper: 50).
    duration : float
        Simulated time per trial (s), clipped to each reference's window by the campaign.
    budgets : mapping of str to (int, int)
        Swarm (population, iterations) by swarm name; a hybrid's swarm half uses its swarm's.
    swarm_options : mapping
        Further options of every swarm (and of a hybrid's swarm half); quick mode:
        ``{"compiled": False}``, since compiling the tiny swarms' cost would take longer than
        running them on CasADi's virtual machine.
    seed : int
        Campaign seed (trial ``i`` of every campaign draws from ``default_rng([seed, i])``).
    quick : bool
        Whether these are the reduced quick settings (the report says so).
    every_pair : bool
        Run every solver on every reference, not only on s2.
    campaign : CampaignConfig
        Disturbance and model settings shared by every campaign (its reference, solver,
        trials, duration, seed and options are replaced per campaign).
    estimator : str or None
        The column "current unknown, estimated" of Tables 1–2: the :data:`TABLE_SOLVER`
        campaigns run again, by the same code, with the current unknown to the controller,
        which gets the state and the current this estimator infers from the vehicle's sensors
        (:meth:`Sensors.auv <uuv_ocp.Sensors.auv>`; they replace the full-state noise).
        Default :data:`ESTIMATOR`; ``None``: no column.  The verdicts stay on the paper's
        setting.
    """

    references: tuple[str, ...] = paper_data.REFERENCES
    solvers: tuple[str, ...] = SOLVERS
    trials: int = paper_data.TRIALS
    duration: float = 30.0
    budgets: Mapping[str, tuple[int, int]] = field(default_factory=lambda: dict(FULL_BUDGETS))
    swarm_options: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    quick: bool = False
    every_pair: bool = False
    campaign: CampaignConfig = field(default_factory=lambda: CampaignConfig(mismatch=True))
    estimator: str | None = ESTIMATOR

    def __post_init__(self) -> None:
        """Validate the fields (``ValueError`` names the first bad one)."""
        for name, values in (("references", self.references), ("solvers", self.solvers)):
            if isinstance(values, str) or not isinstance(values, Sequence) or not values:
                raise ValueError(f"{name} must be a non-empty sequence of names, got {values!r}")
            if len(set(values)) != len(values):
                raise ValueError(f"{name} must not repeat a name, got {list(values)}")
        object.__setattr__(self, "references", tuple(self.references))
        object.__setattr__(self, "solvers", tuple(self.solvers))
        unknown = [name for name in self.references if name not in PAPER_REFERENCES]
        if unknown:
            raise ValueError(f"references must be among {list(PAPER_REFERENCES)}, got {unknown}")
        for name in self.solvers:
            try:
                REGISTRY.factory(name)
            except ValueError:
                raise ValueError(f"solvers: {name!r} is not a registered solver name") from None
        object.__setattr__(self, "trials", check.positive_int("trials", self.trials))
        object.__setattr__(self, "duration", check.positive_float("duration", self.duration))
        object.__setattr__(self, "seed", check.positive_int("seed", self.seed, minimum=0))
        object.__setattr__(self, "quick", check.boolean("quick", self.quick))
        object.__setattr__(self, "every_pair", check.boolean("every_pair", self.every_pair))
        budgets = {}
        for name, budget in dict(self.budgets).items():
            if not (isinstance(budget, tuple) and len(budget) == 2):
                raise ValueError(f"budgets[{name!r}] must be (population, iterations), got {budget!r}")
            budgets[name] = (
                check.positive_int(f"budgets[{name!r}] population", budget[0], minimum=4),
                check.positive_int(f"budgets[{name!r}] iterations", budget[1]),
            )
        object.__setattr__(self, "budgets", MappingProxyType(budgets))
        if not isinstance(self.swarm_options, Mapping):
            raise ValueError(f"swarm_options must be a mapping, got {self.swarm_options!r}")
        object.__setattr__(self, "swarm_options", MappingProxyType(dict(self.swarm_options)))
        if not isinstance(self.campaign, CampaignConfig):
            raise ValueError(f"campaign must be a CampaignConfig, got {type(self.campaign).__name__}")
        if self.estimator is not None and self.estimator not in available_estimators():
            raise ValueError(
                f"estimator must be one of {available_estimators()} or None, got {self.estimator!r}"
            )

    @classmethod
    def quick_settings(cls, **changes: Any) -> ReproductionSettings:
        """Return the reduced settings of ``--quick`` (:data:`QUICK_REFERENCES` … :data:`QUICK_BUDGETS`)."""
        settings: dict[str, Any] = {
            "references": QUICK_REFERENCES,
            "trials": QUICK_TRIALS,
            "duration": QUICK_DURATION,
            "budgets": dict(QUICK_BUDGETS),
            "swarm_options": {"compiled": False},
            "quick": True,
        }
        settings.update(changes)
        return cls(**settings)

    def solver_options(self, solver: str) -> dict[str, Any]:
        """Backend options of ``solver``: the swarm budget (a hybrid's swarm half), else none."""
        swarm, plus, _ = solver.partition("+")
        if swarm not in self.budgets:
            return {}
        population, iterations = self.budgets[swarm]
        options = {"population": population, "iterations": iterations, **self.swarm_options}
        return {"swarm": options} if plus else options

    def config(self, reference: str, solver: str, *, estimated: bool = False) -> CampaignConfig:
        """Return the campaign of one reference and solver (``estimated``: of the estimated column)."""
        base = self.campaign
        if estimated:
            if self.estimator is None:
                raise ValueError("estimated=True needs settings.estimator (it is None: no such column)")
            changes: dict[str, Any] = {"estimator": self.estimator, "current_known": False}
        else:
            changes = {"current_known": base.current_known}
        return CampaignConfig(
            reference=reference,
            solver=solver,
            trials=self.trials,
            duration=self.duration,
            max_current=base.max_current,
            current_noise=base.current_noise,
            noise_std=base.noise_std,
            mismatch=base.mismatch,
            horizon=base.horizon,
            seed=self.seed,
            solver_options=self.solver_options(solver),
            **changes,
        )

    def pairs(self) -> list[tuple[str, str]]:
        """Return (reference, solver) of every campaign, reference-major (see the class doc)."""
        return [
            (reference, solver)
            for reference in self.references
            for solver in self.solvers
            if self.every_pair or solver == TABLE_SOLVER or reference == COMPARISON_REFERENCE
        ]

    def configs(self) -> list[CampaignConfig]:
        """Every campaign of the paper's setting, in the order of :meth:`pairs`."""
        return [self.config(reference, solver) for reference, solver in self.pairs()]

    def estimated_references(self) -> tuple[str, ...]:
        """Return the references of the estimated column: :data:`TABLE_SOLVER`'s (none without it)."""
        if self.estimator is None:
            return ()
        return tuple(reference for reference, solver in self.pairs() if solver == TABLE_SOLVER)

    def estimated_configs(self) -> list[CampaignConfig]:
        """Return the campaigns of the column "current unknown, estimated", by reference."""
        return [
            self.config(reference, TABLE_SOLVER, estimated=True) for reference in self.estimated_references()
        ]


# ------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class ReproductionResult:
    """What :func:`reproduce` produced.

    Parameters
    ----------
    settings : ReproductionSettings
    campaigns : mapping of (reference, solver) to CampaignResult
    elapsed : mapping of (reference, solver) to float
        Wall time (s) of each campaign in this call (a resumed campaign only loads its trials).
    report : Path
        ``report.md``.
    figures : mapping of str to Path
        Every figure written, by name.
    tables : mapping of str to list of dict
        The report's tables as rows (``"table1"`` … ``"table4"``, ``"solve_times"``,
        ``"time_to_band"``, ``"speed_limits"``, ``"all_solvers"``).
    verdicts : tuple of Verdict
        One per claim of the paper (:class:`uuv_ocp.studies.report.Verdict`).
    estimated : mapping of str to CampaignResult
        The campaigns of the column "current unknown, estimated", by reference (empty
        without ``settings.estimator``).
    """

    settings: ReproductionSettings
    campaigns: Mapping[tuple[str, str], CampaignResult]
    elapsed: Mapping[tuple[str, str], float]
    report: Path
    figures: Mapping[str, Path]
    tables: Mapping[str, list[dict]]
    verdicts: tuple[Any, ...]
    estimated: Mapping[str, CampaignResult] = field(default_factory=dict)


def load_trials(result: CampaignResult) -> list[ClosedLoopResult]:
    """Return the closed-loop runs of a campaign, read from its ``trial_XXXX.npz`` files in order."""
    runs = []
    for index in range(len(result.trials)):
        path = Path(result.directory) / f"trial_{index:04d}.npz"
        if not path.exists():
            raise ValueError(f"campaign {result.directory}: trial file {path.name} is missing")
        runs.append(ClosedLoopResult.load(str(path)))
    return runs
