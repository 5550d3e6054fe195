"""Campaign files: ``uuv-ocp campaign --config campaign.toml``.

A TOML file with up to four tables; every key is optional (the defaults are
:class:`~uuv_ocp.studies.campaign.CampaignConfig`'s) and an unknown key is an error naming it::

    [campaign]
    vehicle = "rexrov"                 # plant: a vehicle spec (preset or FILE.toml)
    controller_model = "rexrov-controller"   # the controller's model when mismatch = true
    reference = "s2"                   # a reference spec (s1..s10, "waypoints FILE", FILE.toml)
    solvers = ["sqp", "ipopt"]         # one campaign per solver (or solver = "sqp")
    trials = 50
    duration = 30.0                    # s per trial
    horizon = 20
    dt = 0.1                           # s
    seed = 0

    [disturbance]
    max_current = 0.5                  # m/s: trial current speeds uniform in [0, max_current]
    current_noise = 0.02               # Gauss–Markov intensity (m/s/√s and rad/√s)
    current_decay = 0.1                # 1/s
    current_known = true
    noise_std = [0.02, 0.02, 0.005, 0.01, 0.01, 0.005]   # one per state
    mismatch = true

    [faults]                           # thruster faults drawn per trial (a thruster vehicle)
    count = 1                          # thrusters that fault in each trial
    window = [5.0, 15.0]               # s after the start
    kinds = ["failed", "loss"]         # and/or "stuck"
    effectiveness = 0.5                # what a "loss" leaves
    fault_tolerant = true              # the NMPC with the fault detector (needs an estimator)

    [run]
    executor = "local"                 # "local" or "dask"
    workers = 2
    scheduler = "tcp://host:8786"      # dask only: join this cluster
    out = "out/campaigns"

    [solver_options.ipopt]             # options per solver, as NMPC(options=...) takes them
    max_iter = 100

Relative file paths inside ``vehicle``, ``controller_model`` and ``reference`` are relative to
the working directory, as on the command line.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

# the keys and the writer live with the configuration (below this module): a run writes its
# config.toml without importing the file reader
from uuv_ocp.studies.campaign import CAMPAIGN_KEYS, DISTURBANCE_KEYS, FAULT_KEYS, CampaignConfig, to_toml

__all__ = [
    "CAMPAIGN_KEYS",
    "DISTURBANCE_KEYS",
    "FAULT_KEYS",
    "RUN_KEYS",
    "TABLES",
    "CampaignFile",
    "load_campaign_file",
    "to_toml",
]

RUN_KEYS = ("executor", "workers", "scheduler", "out")
TABLES = ("campaign", "disturbance", "faults", "run", "solver_options")


@dataclass(frozen=True)
class CampaignFile:
    """A parsed campaign file.

    Parameters
    ----------
    configs : tuple of CampaignConfig
        One campaign per solver, in the file's order.
    run : dict
        The ``[run]`` table as given (``executor``, ``workers``, ``scheduler``, ``out``).
    text : str
        The file's text, saved beside the results.
    path : Path
        Where it was read from.
    """

    configs: tuple[CampaignConfig, ...]
    run: dict
    text: str
    path: Path


def _unknown(source: str, table: str, values: dict, allowed: Sequence[str]) -> None:
    for key in values:
        if key not in allowed:
            where = f"{table}.{key}" if table else key
            raise ValueError(f"{source}: unknown key {where!r} (expected one of {list(allowed)})")


def load_campaign_file(path: str | Path) -> CampaignFile:
    """Parse a campaign file (module doc); ``ValueError`` names the file and the bad key or value."""
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ValueError(f"{source}: cannot read the file ({error.strerror or error})") from None
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{source}: not valid TOML ({error})") from None
    _unknown(source, "", document, TABLES)
    for table in TABLES:
        if not isinstance(document.get(table, {}), dict):
            raise ValueError(f"{source}: {table} must be a table [{table}], got {document[table]!r}")
    campaign = dict(document.get("campaign", {}))
    disturbance = dict(document.get("disturbance", {}))
    run = dict(document.get("run", {}))
    faults = dict(document.get("faults", {}))
    options = dict(document.get("solver_options", {}))
    _unknown(source, "campaign", campaign, CAMPAIGN_KEYS)
    _unknown(source, "disturbance", disturbance, DISTURBANCE_KEYS)
    _unknown(source, "run", run, RUN_KEYS)
    _unknown(source, "faults", faults, FAULT_KEYS)
    fault_options: dict = {}
    if "fault_tolerant" in faults:
        fault_options["fault_tolerant"] = faults.pop("fault_tolerant")
    if faults:
        fault_options["faults"] = {
            key: tuple(value) if isinstance(value, list) else value for key, value in faults.items()
        }
    if "solver" in campaign and "solvers" in campaign:
        raise ValueError(f"{source}: give campaign.solver or campaign.solvers, not both")
    solvers = campaign.pop("solvers", None)
    if solvers is None:
        solvers = [campaign.pop("solver", "ipopt")]
    if isinstance(solvers, str):
        solvers = [solvers]
    if not isinstance(solvers, list) or not solvers or not all(isinstance(s, str) for s in solvers):
        raise ValueError(
            f"{source}: campaign.solvers must be a non-empty list of solver names, got {solvers!r}"
        )
    for name, values in options.items():
        if name not in solvers or not isinstance(values, dict):
            raise ValueError(
                f"{source}: unknown key solver_options.{name!r} (a table per solver among {solvers})"
            )
    if "noise_std" in disturbance and isinstance(disturbance["noise_std"], list):
        disturbance["noise_std"] = tuple(disturbance["noise_std"])
    configs = []
    for solver in solvers:
        try:
            configs.append(
                CampaignConfig(
                    solver=solver,
                    solver_options=dict(options.get(solver, {})),
                    **campaign,
                    **disturbance,
                    **fault_options,
                )
            )
        except (ValueError, TypeError) as error:
            raise ValueError(f"{source}: {error}") from None
    return CampaignFile(tuple(configs), run, text, path)
