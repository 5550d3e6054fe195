"""Command line: ``uuv-ocp demo | track | solvers | compare | campaign | reproduce | codegen | hpipm``.

Also ``python -m uuv_ocp.cli``.  Exit status: 0 on success; 2 for a bad flag or value, with one
line ``error: ...`` on standard error naming the flag (nothing runs; a mistyped flag or
subcommand gets the nearest one, "did you mean --reference?"); 2 without a subcommand,
after the help and the suggestion ``uuv-ocp demo``; 130 when interrupted (finished runs are
saved and resumed by the same command).  ``demo`` and ``track`` show their progress on standard
error where bars are drawn (:mod:`uuv_ocp.progress`: a terminal, or ``UUV_OCP_PROGRESS=always``),
not with ``--quiet``.
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from uuv_ocp.ocp import MAX_HORIZON
from uuv_ocp.reference.path import PAPER_REFERENCES
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.specs import VEHICLE_PRESETS
from uuv_ocp.studies.compare import format_tracking_table, track_references
from uuv_ocp.studies.executors import SchedulerUnreachable, WorkerCrashed
from uuv_ocp.studies.records import StorageError, write_text

DEMO_HINT = "start with `uuv-ocp demo` (all ten paper references, NMPC + IPOPT + EKF, 30 s each)"
#: The demo's current (m/s, rad): constant, unknown to the controller, estimated by the EKF
DEMO_CURRENT = (0.5, 1.0)
DEMO_ESTIMATOR = "ekf"
#: The reference of the demo's oracle row (the controller told the true state and current)
ORACLE_REFERENCE = "s2"
_VEHICLE_HELP = f"{' | '.join(VEHICLE_PRESETS)} | FILE.toml | FILE.py:CLASS (docs/vehicles.md)"
_REFERENCE_HELP = (
    f"{PAPER_REFERENCES[0]}..{PAPER_REFERENCES[-1]} | waypoints FILE | lawnmower FILE | hold X,Y,PSI | "
    "FILE.toml (docs/references.md)"
)


class _UsageError(Exception):
    """A bad flag or value: printed as one line, exit status 2."""


def _nearest(word: str, candidates: Sequence[str]) -> str | None:
    """Return the candidate nearest a mistyped ``word`` (:func:`difflib.get_close_matches`) or ``None``."""
    matches = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return matches[0] if matches else None


class _Parser(argparse.ArgumentParser):
    """``argparse`` whose errors are one line (``error: <prog>: ...``) and exit status 2.

    A value outside a flag's choices (a subcommand included) names the nearest choice.
    """

    def error(self, message: str) -> NoReturn:
        """Raise :class:`_UsageError` instead of printing the usage and exiting."""
        raise _UsageError(f"{self.prog}: {message} (see {self.prog} --help)")

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        # argparse (3.11) lists the choices but suggests none; the nearest is what was meant
        choices = action.choices
        if choices is None or value in choices:
            return
        names = [str(choice) for choice in choices]
        guess = _nearest(str(value), names)
        hint = f"; did you mean {guess!r}?" if guess is not None else ""
        raise argparse.ArgumentError(
            action, f"invalid choice: {value!r} (choose from {', '.join(map(repr, names))}){hint}"
        )

    def option_strings(self) -> list[str]:
        """Every flag this parser knows (``--reference``, ``-r``, ...)."""
        return [flag for action in self._actions for flag in action.option_strings]


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="uuv-ocp",
        description="Optimal control of UUVs with CasADi.",
        epilog=DEMO_HINT,
    )
    commands = parser.add_subparsers(dest="command")

    demo = commands.add_parser(
        "demo",
        help="track all ten paper references with NMPC + IPOPT for 30 s under a current the "
        "controller does not know (an EKF estimates it), and s2 with the oracle",
    )
    demo.add_argument("--out", default="out", help="output folder (figures, saved runs)")
    demo.add_argument("--fresh", action="store_true", help="recompute runs already saved in --out")
    demo.add_argument("--quiet", "-q", action="store_true", help="no progress on standard error")

    track = commands.add_parser("track", help="closed-loop tracking of chosen references")
    track.add_argument("--reference", "-r", nargs="+", default=["s2"], help=_REFERENCE_HELP)
    track.add_argument("--vehicle", "-v", default="rexrov", help=_VEHICLE_HELP)
    track.add_argument("--solver", "-s", default="ipopt", help="a name from `uuv-ocp solvers`")
    track.add_argument("--duration", type=float, default=30.0, help="simulated time (s)")
    track.add_argument("--horizon", type=int, default=20, help="shooting intervals N")
    track.add_argument("--dt", type=float, default=0.1, help="sampling time (s)")
    track.add_argument("--out", default="out", help="output folder")
    track.add_argument("--fresh", action="store_true", help="recompute saved runs")
    track.add_argument(
        "--current",
        metavar="SPEED,DIRECTION",
        default=None,
        help="constant current: speed (m/s, >= 0) and direction of the flow (rad, 0 = +x), "
        "e.g. 0.3,1.57; told to the controller unless --estimator is given (default: still water)",
    )
    track.add_argument(
        "--estimator",
        "-e",
        default=None,
        help="the current is unknown to the controller, which gets the state and current this "
        "estimator (ekf | ukf | ...: uuv_ocp.available_estimators()) infers from the vehicle's "
        "sensors (uo.Sensors.auv); default: none, the oracle (true state, current told)",
    )
    track.add_argument("--quiet", "-q", action="store_true", help="no progress on standard error")

    follow = commands.add_parser("follow", help="closed-loop path following (NMPC or ILOS guidance)")
    follow.add_argument("--vehicle", "-v", default="remus100", help=_VEHICLE_HELP)
    follow.add_argument(
        "--path",
        "-p",
        nargs="+",
        default=["survey"],
        help="survey (the REMUS tutorial's lawnmower: 4 lanes of 150 m, 60 m apart, 10 m deep; "
        "planar vehicles: in the plane) | " + _REFERENCE_HELP,
    )
    follow.add_argument(
        "--solver",
        "-s",
        default="sqp-rti",
        help="a name from `uuv-ocp solvers`, or ilos (guidance)",
    )
    follow.add_argument("--speed", type=float, default=1.5, help="commanded along-path speed (m/s)")
    follow.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated time (s; default: the path's window)",
    )
    follow.add_argument("--horizon", type=int, default=20, help="shooting intervals N")
    follow.add_argument("--dt", type=float, default=0.5, help="sampling time of the NMPC (s; ILOS: 0.1 s)")
    follow.add_argument(
        "--current", metavar="SPEED,DIRECTION", default=None, help="constant current (m/s, rad), as for track"
    )
    follow.add_argument(
        "--estimator",
        "-e",
        default=None,
        help="the current unknown, estimated (ekf | ukf | mhe)",
    )
    follow.add_argument(
        "--current-std",
        metavar="SIGMA[,SIGMA,...]",
        default=None,
        help="the estimator's current noise intensity (m/s/sqrt(s)): one value, or one per "
        "inertial axis (default: a 6-DOF vehicle's uuv_ocp.estimation.SURVEY_CURRENT_STD, 0.01 "
        "horizontal and 1e-4 vertical: a survey's current is horizontal; else 0.01)",
    )
    follow.add_argument(
        "--current-filter",
        type=float,
        default=None,
        help="time constant (s, >= 0) of the low-pass on the estimated current the NMPC is told "
        "(default: uuv_ocp.estimation.SURVEY_CURRENT_FILTER, 20 s; 0: the estimate itself)",
    )
    follow.add_argument("--seed", type=int, default=0, help="the sensors' noise")
    follow.add_argument("--quiet", "-q", action="store_true", help="no progress on standard error")

    solvers = commands.add_parser("solvers", help="list the registered solver names, or one's options")
    solvers.add_argument("name", nargs="?", help="print this solver's options (a Markdown table)")

    compare = commands.add_parser("compare", help="one instance, several solvers, one judge")
    compare.add_argument("--reference", "-r", nargs="+", default=["s2"], help=_REFERENCE_HELP)
    compare.add_argument("--vehicle", "-v", default="rexrov", help=_VEHICLE_HELP)
    compare.add_argument(
        "--solvers", nargs="+", default=["ipopt", "sqp", "fatrop", "igwo", "gwo", "ssa", "pso"]
    )
    compare.add_argument("--t0", type=float, default=3.0, help="start time on the reference (s)")
    compare.add_argument("--seed", type=int, default=1)

    campaign = commands.add_parser("campaign", help="Monte Carlo trials with currents, noise, mismatch")
    campaign.add_argument(
        "--config", help="campaign file (TOML, docs/campaigns.md); replaces the trial flags"
    )
    campaign.add_argument("--reference", "-r", nargs="+", default=["s2"], help=_REFERENCE_HELP)
    campaign.add_argument("--vehicle", "-v", default="rexrov", help="the plant: " + _VEHICLE_HELP)
    campaign.add_argument("--solver", "-s", default="ipopt")
    campaign.add_argument("--trials", type=int, default=50)
    campaign.add_argument("--duration", type=float, default=30.0)
    campaign.add_argument("--horizon", type=int, default=20)
    campaign.add_argument("--dt", type=float, default=0.1, help="sampling time (s)")
    campaign.add_argument("--max-current", type=float, default=0.5, help="m/s")
    campaign.add_argument("--seed", type=int, default=0)
    campaign.add_argument(
        "--estimator", default=None, help="the controller gets the state and current from it (e.g. ekf)"
    )
    campaign.add_argument(
        "--no-mismatch", action="store_true", help="the controller's model is the plant's (any vehicle)"
    )
    campaign.add_argument(
        "--faults",
        default=None,
        help="thrusters that fault in each trial, drawn per trial (a thruster vehicle, e.g. "
        "bluerov2-heavy-thrusters)",
    )
    campaign.add_argument(
        "--fault-kinds", default="failed,loss", help="drawn among these: failed, loss (50 %%), stuck"
    )
    campaign.add_argument(
        "--fault-window", default="5,15", help="EARLIEST,LATEST fault time (s after the start)"
    )
    campaign.add_argument(
        "--fault-tolerant", action="store_true", help="the NMPC with the fault detector (needs --estimator)"
    )
    campaign.add_argument(
        "--executor",
        choices=["local", "dask", "process"],
        default=None,
        help="local: --workers processes on this machine (default); dask: dask.distributed",
    )
    campaign.add_argument("--workers", type=int, default=None, help="worker processes (default 2)")
    campaign.add_argument("--scheduler", default=None, help="dask: join the scheduler at tcp://host:port")
    campaign.add_argument("--out", default=None, help="output folder (default out/campaigns)")

    reproduce = commands.add_parser("reproduce", help="the paper's experiment: tables, figures, verdicts")
    reproduce.add_argument("--out", default="docs/reproduction", help="report.md, figures/, campaigns/")
    reproduce.add_argument("--quick", action="store_true", help="reduced size (CI): 3 references, 2 trials")
    reproduce.add_argument("--trials", type=int, default=None, help="per campaign (default 50; quick 2)")
    reproduce.add_argument("--references", "-r", nargs="+", default=None, help="subset of the references")
    reproduce.add_argument("--solvers", nargs="+", default=None, help="subset of the solvers")
    reproduce.add_argument("--every-pair", action="store_true", help="every solver on every reference")
    reproduce.add_argument("--executor", default=None, help="campaign executor (default: processes)")
    reproduce.add_argument("--workers", type=int, default=2)

    codegen = commands.add_parser("codegen", help="generate, compile and verify C for a problem")
    codegen.add_argument("--reference", "-r", nargs="+", default=["s2"], help=_REFERENCE_HELP)
    codegen.add_argument("--vehicle", "-v", default="rexrov", help=_VEHICLE_HELP)
    codegen.add_argument("--out", default="build", help="output folder")
    codegen.add_argument("--horizon", type=int, default=20)
    codegen.add_argument("--population", type=int, default=20)

    hpipm = commands.add_parser("hpipm", help="build HPIPM and BLASFEO for this CPU (faster sqp-rti QPs)")
    hpipm.add_argument(
        "action", choices=("build", "status"), help="build and install, or show the build in use"
    )
    hpipm.add_argument("--source", default=None, help="folder with blasfeo/ and hpipm/ (default: the sdist)")
    hpipm.add_argument("--target", default="auto", help="BLASFEO target (default: auto, from the CPU)")
    hpipm.add_argument("--jobs", type=int, default=2, help="parallel make jobs")
    return parser


def _run_hpipm(args: argparse.Namespace) -> int:
    from uuv_ocp.native import hpipm

    if args.action == "status":
        try:  # every file checked as for the C step: a refused build is named, never used
            native = hpipm.installed(strict=True)
        except hpipm.NativeHpipmError as error:
            print(f"native HPIPM: refused ({error}); the C step links the CasADi wheel's")
            return 1
        if native is None:
            print("native HPIPM: none (the C step links the CasADi wheel's, TARGET_GENERIC)")
        else:
            print(f"native HPIPM: {native.directory} (BLASFEO TARGET={native.target})")
        return 0
    try:
        hpipm.build(args.source, args.target, jobs=args.jobs)
    except ValueError as error:
        return _fail(str(error))
    except hpipm.NativeHpipmError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


def _fail(message: str) -> int:
    """Print ``error: message`` as one line on standard error; return the exit status 2."""
    print("error: " + " ".join(str(message).split()), file=sys.stderr)
    return 2


def _finite(flag: str, value: float, *, positive: bool = True) -> None:
    if not math.isfinite(value) or (positive and value <= 0):
        raise _UsageError(f"{flag} must be a finite number{' > 0' if positive else ''}, got {value:g}")


def _horizon(value: int) -> None:
    if not 1 <= value <= MAX_HORIZON:
        raise _UsageError(f"--horizon must be an integer in [1, {MAX_HORIZON}], got {value}")


def _flag_error(flag: str, noun: str, error: ValueError) -> _UsageError:
    """``--flag must be ...`` from the API's ``noun must be ...`` message (others: ``--flag: ...``)."""
    message = str(error)
    if message.startswith(f"{noun} "):
        return _UsageError(f"{flag} {message.removeprefix(noun + ' ')}")
    return _UsageError(f"{flag}: {message}")


def _solver(flag: str, name: str) -> str:
    """Return the registered spelling of solver ``name`` (case-insensitive), or a usage error."""
    try:
        return REGISTRY.resolve(name)
    except ValueError as error:
        raise _flag_error(flag, "solver", error) from None


def _vehicle(spec: str):
    from uuv_ocp.specs import vehicle_from_spec

    try:
        return vehicle_from_spec(spec)
    except ValueError as error:
        raise _flag_error("--vehicle", "vehicle", error) from None


def _references(words: Sequence[str], vehicle, *, single: bool = False) -> list:
    """Build the references the ``--reference`` words name (6-DOF: paper ones at a depth)."""
    from uuv_ocp.specs import reference_from_spec, split_reference_specs

    groups = split_reference_specs(words)
    if single and len(groups) != 1:
        raise _UsageError(f"--reference takes one reference here, got {len(groups)}: {' '.join(words)}")
    try:
        return [reference_from_spec(group, spatial=vehicle.layout.reference == "spatial") for group in groups]
    except ValueError as error:
        raise _flag_error("--reference", "reference", error) from None


def _output_folder(folder: str) -> None:
    """Create ``--out`` now (so that a bad folder fails before any run) and check it is writable."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise _UsageError(f"--out {folder}: cannot create the folder ({error.strerror or error})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise _UsageError(f"--out {folder}: the folder is not writable")


def _current(text: str | None):
    """Parse ``--current SPEED,DIRECTION`` into a constant :class:`~uuv_ocp.Current` (or ``None``)."""
    if text is None:
        return None
    from uuv_ocp.control.disturbances import Current

    parts = text.split(",")
    try:
        speed, direction = (float(part) for part in parts)
    except ValueError:  # not two numbers
        raise _UsageError(
            f"--current must be SPEED,DIRECTION (m/s, rad; e.g. 0.3,1.57), got {text!r}"
        ) from None
    try:
        return Current(speed=speed, direction=direction)
    except ValueError as error:
        raise _flag_error("--current", "current", error) from None


def _estimator(name: str | None) -> str | None:
    """Check ``--estimator NAME`` against the registered estimators (the nearest one suggested)."""
    if name is None:
        return None
    from uuv_ocp.estimation import available_estimators

    names = available_estimators()
    if name not in names:
        guess = _nearest(name, names)
        hint = f"; did you mean {guess!r}?" if guess is not None else ""
        raise _UsageError(f"--estimator must be one of {', '.join(names)}, got {name!r}{hint}")
    return name


def _check_track(args: argparse.Namespace) -> tuple[Any, list]:
    """Validate the ``track`` flags; return the vehicle and the references."""
    args.solver = _solver("--solver", args.solver)
    args.current = _current(args.current)
    args.estimator = _estimator(args.estimator)
    _finite("--duration", args.duration)
    _finite("--dt", args.dt)
    _horizon(args.horizon)
    if args.duration < args.dt:
        raise _UsageError(
            f"--duration must be at least one sampling interval --dt = {args.dt:g} s, got {args.duration:g}"
        )
    vehicle = _vehicle(args.vehicle)
    references = _references(args.reference, vehicle)
    for reference in references:
        if args.horizon * args.dt >= reference.t_end - reference.t_start:
            raise _UsageError(
                f"--horizon {args.horizon} x --dt {args.dt:g} s = {args.horizon * args.dt:g} s must be "
                f"shorter than the window of {reference.name}, [{reference.t_start:g}, {reference.t_end:g}] s"
            )
    _output_folder(args.out)
    return vehicle, references


def _problem(args: argparse.Namespace, horizon: int = 20):
    from uuv_ocp import TrackingProblem

    vehicle = _vehicle(args.vehicle)
    (reference,) = _references(args.reference, vehicle, single=True)
    return TrackingProblem(vehicle, reference, horizon=horizon)


def _run_compare(args: argparse.Namespace) -> int:
    from uuv_ocp.studies.compare import compare, format_comparison

    _finite("--t0", args.t0, positive=False)
    solvers = [_solver("--solvers", name) for name in args.solvers]
    if args.seed < 0:
        raise _UsageError(f"--seed must be an integer >= 0, got {args.seed}")
    problem = _problem(args)
    problem.check_time(args.t0)
    x0 = problem.reference.evaluate([args.t0])[0]
    rows = compare(problem, solvers, x0=x0, t0=args.t0, seed=args.seed)
    print(
        f"{problem.reference.name} ({problem.vehicle.name}) at t0 = {args.t0} s, on the reference (moving); "
        "cost from uuv_ocp.score()"
    )
    print(format_comparison(rows))
    return 0


def _run_codegen(args: argparse.Namespace) -> int:
    from uuv_ocp.native.runtime import MIN_IGWO_POPULATION, BuildDirectoryError
    from uuv_ocp.solvers.rti_export import generate_c

    _horizon(args.horizon)
    if args.population < MIN_IGWO_POPULATION:
        raise _UsageError(
            f"--population must be an integer >= {MIN_IGWO_POPULATION} (the IGWO step), got {args.population}"
        )
    try:
        generated = generate_c(_problem(args, args.horizon), args.out, population=args.population)
    except BuildDirectoryError as refused:
        raise _UsageError(f"--out: {refused}") from None
    print(f"library   {generated.library}{' (reused from cache)' if generated.reused else ''}")
    print(f"source    {generated.source}\nheader    {generated.header}")
    for name, error in generated.max_error.items():
        print(f"verified  {name:<16} max relative difference compiled vs symbolic {error:.1e}")
    if generated.simd:
        print("cost_batch is the SIMD population kernel (docs/codegen.md); cost_batch_exact is CasADi's")
    return 0


def _run_reproduce(args: argparse.Namespace) -> int:
    from uuv_ocp.studies.campaign import EXECUTORS
    from uuv_ocp.studies.reproduce import reproduce

    if args.trials is not None and args.trials < 1:
        raise _UsageError(f"--trials must be an integer >= 1, got {args.trials}")
    if args.workers < 1:
        raise _UsageError(f"--workers must be an integer >= 1, got {args.workers}")
    # processes on this machine: "process" where campaign.py names it so, else its "local"
    executor = args.executor or ("process" if "process" in EXECUTORS else "local")
    if executor not in EXECUTORS:
        raise _UsageError(f"--executor must be one of {list(EXECUTORS)}, got {args.executor!r}")
    unknown = [name for name in args.references or () if name not in PAPER_REFERENCES]
    if unknown:  # the paper's references only: its tables have no others
        raise _UsageError(f"--references must be among {list(PAPER_REFERENCES)}, got {unknown}")
    for name in args.solvers or ():
        _solver("--solvers", name)
    _output_folder(args.out)
    start = time.perf_counter()
    try:
        result = reproduce(
            args.out,
            quick=args.quick,
            trials=args.trials,
            references=args.references,
            solvers=args.solvers,
            every_pair=args.every_pair,
            executor=executor,
            workers=args.workers,
        )
    except KeyboardInterrupt:
        print("\ninterrupted: finished trials are saved; rerun the command to resume", file=sys.stderr)
        return 130
    counts = {name: sum(v.verdict == name for v in result.verdicts) for name in ("holds", "does not hold")}
    print(f"report    {result.report}  ({len(result.figures)} figures, {time.perf_counter() - start:.1f} s)")
    print(
        f"verdicts  {counts['holds']} hold, {counts['does not hold']} do not hold, "
        f"{len(result.verdicts) - sum(counts.values())} not comparable"
    )
    for (reference, solver), seconds in result.elapsed.items():
        print(f"campaign  {reference:>4} {solver:<12} {seconds:8.1f} s")
    return 0


def _one_line_warning(message: Any, category: Any, *args: Any, **kwargs: Any) -> None:
    """Show a campaign's warning as ``warning: message``, one line (no source line)."""
    print(f"warning: {' '.join(str(message).split())}", file=sys.stderr)


def _run_campaign(args: argparse.Namespace) -> int:
    """``uuv-ocp campaign``: flags or ``--config FILE``; the file's ``[run]`` fills unset run flags."""
    from uuv_ocp.studies.campaign import CampaignConfig, format_summary, format_summary_table, run_campaigns
    from uuv_ocp.studies.campaign_file import load_campaign_file

    try:
        if args.config is not None:
            loaded = load_campaign_file(args.config)
            configs, run = loaded.configs, loaded.run
        else:
            configs = (
                CampaignConfig(
                    reference=" ".join(args.reference),
                    vehicle=args.vehicle,
                    solver=_solver("--solver", args.solver),
                    trials=args.trials,
                    duration=args.duration,
                    horizon=args.horizon,
                    dt=args.dt,
                    max_current=args.max_current,
                    seed=args.seed,
                    **_campaign_faults(args),
                ),
            )
            run = {}
        executor = args.executor or run.get("executor", "local")
        workers = args.workers if args.workers is not None else run.get("workers", 2)
        scheduler = args.scheduler or run.get("scheduler")
        out = args.out or run.get("out", "out/campaigns")
        _output_folder(str(out))
        if not isinstance(workers, int) or workers < 1:
            raise _UsageError(f"--workers must be an integer >= 1, got {workers}")
        with warnings.catch_warnings():  # a damaged record or index, a restarted pool: one line each
            warnings.showwarning = _one_line_warning
            results = run_campaigns(configs, out, executor=executor, workers=workers, scheduler=scheduler)
    except (ValueError, StorageError, SchedulerUnreachable, WorkerCrashed) as error:  # one line each
        return _fail(str(error))
    except OSError as error:
        return _fail(f"--out: {error.strerror or error} ({error.filename or ''})")
    except KeyboardInterrupt:
        print("\ninterrupted: finished trials are saved; rerun the command to resume", file=sys.stderr)
        return 130
    for result in results:
        print(format_summary(result))
        print(f"trials saved in {result.directory}")
    if args.config is not None:  # the file and the table of its campaigns, beside the results
        stem = Path(args.config).stem
        table = format_summary_table(results)
        try:  # atomic: a full disk leaves the previous files whole
            write_text(Path(out) / f"{stem}.toml", loaded.text, "campaign file")
            write_text(Path(out) / f"{stem}_summary.txt", table + "\n", "summary")
        except StorageError as error:
            return _fail(str(error))
        print(table)
        print(f"config and summary saved as {Path(out) / stem}.toml and {Path(out) / stem}_summary.txt")
    return 0


def _campaign_faults(args: argparse.Namespace) -> dict[str, Any]:
    """Return the fault, estimator and mismatch flags of ``uuv-ocp campaign`` as CampaignConfig fields."""
    from uuv_ocp.control.faults import RandomFaults

    fields: dict[str, Any] = {}
    estimator = _estimator(args.estimator)
    if estimator is not None:
        # the sensors carry the noise: noise_std is not used, only sized to the vehicle's state
        fields.update(estimator=estimator, current_known=False)
        fields["noise_std"] = (0.0,) * _vehicle(args.vehicle).layout.state_dim
    if args.no_mismatch:
        fields["mismatch"] = False
    if args.fault_tolerant:
        fields["fault_tolerant"] = True
    if args.faults is None:
        return fields
    try:
        count = int(args.faults)
    except ValueError:
        raise _UsageError(
            f"--faults must be an integer >= 0 (thrusters per trial), got {args.faults!r}"
        ) from None
    try:
        window = tuple(float(part) for part in args.fault_window.split(","))
    except ValueError:
        raise _UsageError(
            f"--fault-window must be EARLIEST,LATEST (s; e.g. 5,15), got {args.fault_window!r}"
        ) from None
    kinds = tuple(part.strip() for part in args.fault_kinds.split(",") if part.strip())
    try:
        fields["faults"] = RandomFaults(count=count, window=window, kinds=kinds)  # type: ignore[arg-type]
    except ValueError as error:
        message = str(error)
        for field, flag in (("count", "--faults"), ("window", "--fault-window"), ("kinds", "--fault-kinds")):
            if message.startswith(field + " "):
                raise _UsageError(f"{flag} {message.removeprefix(field + ' ')}") from None
        raise _UsageError(f"--faults: {message}") from None
    return fields


def _unrecognized(
    parser: argparse.ArgumentParser, args: argparse.Namespace, extras: list[str]
) -> _UsageError:
    """One line for arguments no flag takes, with the nearest flag of each mistyped one."""
    command = getattr(args, "command", None)
    owner = parser
    if command is not None:
        owner = next(
            action.choices[command]
            for action in parser._actions
            if isinstance(action, argparse._SubParsersAction)
        )
    flags = owner.option_strings() if isinstance(owner, _Parser) else []
    unknown = [word.split("=", 1)[0] for word in extras if word.startswith("-")]
    nearest = {flag: _nearest(flag, flags) for flag in unknown}
    guesses = [
        guess if len(unknown) == 1 else f"{guess} for {flag}"
        for flag, guess in nearest.items()
        if guess is not None
    ]
    hint = f"; did you mean {', '.join(guesses)}?" if guesses else ""
    return _UsageError(
        f"{owner.prog}: unrecognized arguments: {' '.join(extras)}{hint} (see {owner.prog} --help)"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``uuv-ocp`` console script; returns the exit status (see module doc)."""
    parser = _parser()
    try:
        args, extras = parser.parse_known_args(argv)
        if extras:
            raise _unrecognized(parser, args, extras)
        if args.command is None:
            parser.print_help(sys.stderr)
            print(f"\nno command given: {DEMO_HINT}", file=sys.stderr)
            return 2
        return _dispatch(args)
    except _UsageError as error:
        return _fail(str(error))


def _dispatch(args: argparse.Namespace) -> int:
    """Run the subcommand ``args.command``; return the exit status."""
    command = args.command
    if command == "solvers":
        return _run_solvers(args)
    if command == "campaign":
        return _run_campaign(args)
    if command == "hpipm":
        return _run_hpipm(args)
    if command == "reproduce":
        return _run_reproduce_guarded(args)
    if command in ("compare", "codegen"):
        return _run_compare_or_codegen(args)
    if command == "follow":
        return _run_follow(args)
    return _run_tracking(args)


def _run_solvers(args: argparse.Namespace) -> int:
    """``uuv-ocp solvers [NAME]``: the registered names, or the options of one."""
    if args.name is None:
        print("\n".join(REGISTRY.names()))
        return 0
    from uuv_ocp.solvers.catalog import options_table

    print(options_table(_solver("NAME", args.name)))
    return 0


def _run_reproduce_guarded(args: argparse.Namespace) -> int:
    """``uuv-ocp reproduce``, its failures as one line and exit status 2."""
    try:
        return _run_reproduce(args)
    except (ValueError, StorageError, WorkerCrashed) as error:  # one line each
        return _fail(str(error))
    except OSError as error:
        return _fail(f"--out {args.out}: {error.strerror or error} ({error.filename or args.out})")


def _run_compare_or_codegen(args: argparse.Namespace) -> int:
    """``uuv-ocp compare`` or ``codegen``, its failures on standard error and exit status 2."""
    try:
        return _run_compare(args) if args.command == "compare" else _run_codegen(args)
    except ValueError as error:
        return _fail(str(error))
    except RuntimeError as error:  # e.g. a compiler's failure: its output, as it came
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        return _fail(f"{error.strerror or error}: {error.filename or ''}")


@dataclass(frozen=True)
class _TrackingPlan:
    """What ``demo`` or ``track`` runs: the loop's settings and its jobs.

    ``duration`` and ``dt`` in s; ``jobs`` are ``(reference, estimator or None, file prefix)``.
    """

    vehicle: Any
    solver: str
    duration: float
    horizon: int
    dt: float
    current: Any
    jobs: list


def _demo_plan(args: argparse.Namespace) -> _TrackingPlan:
    """Return the demo's fixed plan: every paper reference with the EKF loop, and the oracle on s2."""
    from uuv_ocp.control.disturbances import Current
    from uuv_ocp.model.planar import Vehicle

    _output_folder(args.out)
    # the realistic loop on every reference, then the oracle beside it on s2
    jobs: list = [(name, DEMO_ESTIMATOR, "") for name in PAPER_REFERENCES]
    jobs.append((ORACLE_REFERENCE, None, "oracle_"))
    return _TrackingPlan(
        vehicle=Vehicle.rexrov(),
        solver="ipopt",
        duration=30.0,
        horizon=20,
        dt=0.1,
        current=Current(DEMO_CURRENT[0], DEMO_CURRENT[1]),
        jobs=jobs,
    )


def _track_plan(args: argparse.Namespace) -> _TrackingPlan:
    """Return the plan of ``track`` from its flags, validated (:func:`_check_track`) before anything runs."""
    vehicle, names = _check_track(args)
    return _TrackingPlan(
        vehicle=vehicle,
        solver=args.solver,
        duration=args.duration,
        horizon=args.horizon,
        dt=args.dt,
        current=args.current,
        jobs=[(name, args.estimator, "") for name in names],
    )


def _run_tracking(args: argparse.Namespace) -> int:
    """``uuv-ocp demo`` or ``track``: run the plan's loops, then print their table."""
    plan = _demo_plan(args) if args.command == "demo" else _track_plan(args)
    start = time.perf_counter()
    try:
        rows = _track_jobs(plan, args)
    except KeyboardInterrupt as interrupt:
        print(f"\ninterrupted: {interrupt}. Run the same command again to resume.", file=sys.stderr)
        return 130
    except (ValueError, StorageError) as error:  # a StorageError names its file and folder
        return _fail(str(error))
    except OSError as error:
        return _fail(f"--out {args.out}: {error.strerror or error} ({error.filename or args.out})")
    _print_tracking_summary(plan, rows)
    print(f"\nfigures and saved runs in {args.out}/  ({time.perf_counter() - start:.1f} s)")
    return 0


def _track_jobs(plan: _TrackingPlan, args: argparse.Namespace) -> list:
    """Run the plan's jobs one after the other; return their table rows."""
    rows: list = []
    for index, (name, estimator, prefix) in enumerate(plan.jobs, 1):
        # one reference at a time, so that each says it has started before its controller
        # is built (seconds, minutes under load) and its own bar appears
        _announce(index, len(plan.jobs), name, plan.solver, estimator, quiet=args.quiet)
        rows += track_references(
            [name],
            plan.solver,
            duration=plan.duration,
            horizon=plan.horizon,
            dt=plan.dt,
            vehicle=plan.vehicle,
            out_dir=args.out,
            fresh=args.fresh,
            progress=not args.quiet,
            current=plan.current,
            estimator=estimator,
            prefix=prefix,
        )
    return rows


def _print_tracking_summary(plan: _TrackingPlan, rows: list) -> None:
    """Print the heading lines (vehicle, current, estimators) and the table of ``rows``."""
    vehicle = plan.vehicle
    print()
    print(
        f"NMPC tracking, {vehicle.name}, N = {plan.horizon}, dt = {plan.dt} s, terminal equality, "
        f"solver {plan.solver}"
    )
    estimators = sorted({estimator for _, estimator, _ in plan.jobs if estimator is not None})
    oracle = any(estimator is None for _, estimator, _ in plan.jobs)
    if plan.current is not None:
        print(_current_line(plan.current, estimators, oracle=oracle))
    if estimators:
        print(
            f"loop {'/'.join(estimators)}: state and current estimated by an {'/'.join(estimators).upper()} "
            f"from {_sensor_list(vehicle)}"
            + ("; loop oracle: told the true state and current" if oracle else "")
        )
    print("errors in m over the whole run and for t >= t0 + 5 s; solve times per step in ms")
    print(format_tracking_table(rows))


def _current_line(current: Any, estimators: list[str], *, oracle: bool) -> str:
    """``constant current 0.5 m/s towards 1 rad (...)``: who of the loops is told the current."""
    told = "known to the controller"
    if estimators:
        told = "unknown to the controller" + (", told to the oracle's" if oracle else "")
    return f"constant current {current.speed:g} m/s towards {current.direction:g} rad ({told})"


def _announce(
    index: int, count: int, reference: Any, solver: str, estimator: str | None, *, quiet: bool
) -> None:
    """``[2/10] s3 with ipopt`` (``+ ekf``) on standard error, where progress bars are drawn."""
    from uuv_ocp.progress import drawn

    if drawn(not quiet):
        name = reference if isinstance(reference, str) else reference.name
        loop = f" + {estimator}" if estimator else ""
        print(f"[{index}/{count}] {name} with {solver}{loop}", file=sys.stderr, flush=True)


def _sensor_list(vehicle: Any) -> str:
    """``position 1 Hz, dvl 5 Hz, ...``: the sensors of :meth:`Sensors.auv` on ``vehicle``."""
    from uuv_ocp.estimation import Sensors

    return ", ".join(f"{sensor.name} {sensor.rate:g} Hz" for sensor in Sensors.auv(vehicle))


#: ``follow --path survey``: the REMUS 100 tutorial's lawnmower (docs/tutorials/remus_survey.md)
SURVEY_WIDTH, SURVEY_SPACING, SURVEY_LANES, SURVEY_DEPTH = 150.0, 60.0, 4, 10.0  # m, m, -, m
#: the guidance's sampling time (s) and the survey's hold after its length at --speed (s)
ILOS_DT, FOLLOW_EXTRA = 0.1, 60.0


def _follow_path(args: argparse.Namespace, vehicle: Any) -> Any:
    """Return the ``--path`` reference: the survey (at ``--speed``) or a reference spec."""
    from uuv_ocp.reference.path import Reference

    if args.path == ["survey"]:
        depth = SURVEY_DEPTH if vehicle.layout.reference == "spatial" else None
        return Reference.lawnmower(
            (0.0, 0.0),
            width=SURVEY_WIDTH,
            spacing=SURVEY_SPACING,
            lanes=SURVEY_LANES,
            speed=args.speed,
            depth=depth,
            hold=FOLLOW_EXTRA,
            name="survey",
        )
    from uuv_ocp.specs import reference_from_spec

    try:
        return reference_from_spec(args.path, spatial=vehicle.layout.reference == "spatial")
    except ValueError as error:
        raise _flag_error("--path", "reference", error) from None


def _check_follow(args: argparse.Namespace) -> tuple[Any, Any]:
    """Validate the ``follow`` flags before anything is built; return the vehicle and the path."""
    ilos = args.solver.lower() == "ilos"
    args.solver = "ilos" if ilos else _solver("--solver", args.solver)
    args.current = _current(args.current)
    args.estimator = _estimator(args.estimator)
    _finite("--speed", args.speed)
    _finite("--dt", args.dt)
    _horizon(args.horizon)
    if args.duration is not None:
        _finite("--duration", args.duration)
    if ilos and args.estimator is not None:
        raise _UsageError("--estimator is for the NMPC: ILOS guidance takes no current")
    if args.current_filter is not None and not (
        math.isfinite(args.current_filter) and args.current_filter >= 0
    ):
        raise _UsageError(f"--current-filter must be a finite number >= 0 (s), got {args.current_filter:g}")
    vehicle = _vehicle(args.vehicle)
    given = args.current_std is not None or args.current_filter is not None
    args.current_std = _current_std(args.current_std, vehicle.layout.current_dim)
    if args.estimator is None and given:
        raise _UsageError("--current-std and --current-filter set the estimator: give --estimator too")
    path = _follow_path(args, vehicle)
    if args.duration is None:
        if not math.isfinite(path.t_end):
            raise _UsageError(f"--duration is needed: the path {path.name} has no end")
        args.duration = path.t_end - path.t_start  # the survey: its length at --speed + 60 s
    return vehicle, path


def _current_std(text: str | None, current_dim: int) -> float | tuple[float, ...]:
    """Parse ``--current-std``: one intensity or one per current axis (m/s/√s), each > 0.

    Without the flag a 6-DOF vehicle's vertical entry is small (``SURVEY_CURRENT_STD``): an
    ocean current at survey depth is horizontal, and a vertical current made of sensor noise is
    what the depth loop would chase (``benchmarks/bench_path.py``).
    """
    if text is None:
        from uuv_ocp.estimation import SURVEY_CURRENT_STD

        return SURVEY_CURRENT_STD if current_dim == len(SURVEY_CURRENT_STD) else SURVEY_CURRENT_STD[0]
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise _UsageError(
            f"--current-std must be one number or {current_dim} comma-separated numbers "
            f"(m/s/sqrt(s)), got {text!r}"
        ) from None
    if len(values) not in (1, current_dim):
        raise _UsageError(
            f"--current-std must have 1 or {current_dim} entries (the vehicle's current axes), "
            f"got {len(values)}"
        )
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise _UsageError(f"--current-std must be finite numbers > 0, got {text!r}")
    return values[0] if len(values) == 1 else values


def _follow_estimator_options(args: argparse.Namespace) -> Any:
    """Return the ``follow`` estimator's options: the current's noise per axis, the NMPC's low-pass."""
    import uuv_ocp as uo
    from uuv_ocp.estimation import SURVEY_CURRENT_FILTER

    told = SURVEY_CURRENT_FILTER if args.current_filter is None else args.current_filter
    return uo.EstimatorOptions(current_std=args.current_std, current_filter=told)


def _run_follow(args: argparse.Namespace) -> int:
    """``uuv-ocp follow``: one closed loop along a path, then its metrics (:func:`uuv_ocp.path_metrics`)."""
    vehicle, path = _check_follow(args)
    import numpy as np

    import uuv_ocp as uo

    try:
        measured: Any
        if args.solver == "ilos":
            measured = uo.TrackingProblem(vehicle, path, horizon=1, dt=ILOS_DT)
            controller: Any = uo.LosGuidance(measured, uo.LosOptions(speed=args.speed))
            x0 = path.initial_state(path.t_start)
        else:
            measured = uo.PathFollowingProblem(
                vehicle, path, speed=args.speed, horizon=args.horizon, dt=args.dt
            )
            controller = uo.NMPC(measured, solver=args.solver)
            x0 = measured.initial_state(path.initial_state(path.t_start))
        estimator = None
        if args.estimator is not None:
            estimator = uo.Estimator(
                measured,
                args.estimator,
                sensors=uo.Sensors.auv(vehicle),
                options=_follow_estimator_options(args),
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a finite path's end: its hold covers it
            run = uo.simulate(
                controller,
                x0,
                args.duration,
                current=args.current,
                estimator=estimator,
                seed=args.seed,
                progress=not args.quiet,
            )
    except ValueError as error:
        return _fail(str(error))
    except KeyboardInterrupt as interrupt:
        print(f"\ninterrupted: {interrupt}", file=sys.stderr)
        return 130
    found = uo.path_metrics(run, measured)
    step = 1e3 * float(np.median(run.solve_times)) if len(run.solve_times) else math.nan
    print(f"\npath following, {vehicle.name}, {path.name}, {args.speed:g} m/s, controller {args.solver}")
    if args.current is not None:
        told = f"estimated by an {args.estimator.upper()}" if args.estimator else "known to the controller"
        print(f"constant current {args.current.speed:g} m/s towards {args.current.direction:g} rad ({told})")
    head = "| cross-track RMS m | max m | depth RMS m | fin activity deg | energy kJ | step ms | path done |"
    print(head + "\n" + "|---" * 7 + "|")
    print(
        f"| {found['cross_track_rms']:.3f} | {found['cross_track_max']:.2f} | {found['depth_rms']:.3f} | "
        f"{math.degrees(found['fin_activity']):.1f} | {found['energy'] / 1e3:.2f} | {step:.2f} | "
        f"{'yes' if found['completed'] else 'no'} |"
    )
    return 0 if run.fault is None else _fail(f"the run stopped: {run.fault}")


if __name__ == "__main__":
    sys.exit(main())
