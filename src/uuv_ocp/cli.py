"""Command line: ``uuv-ocp demo | track | solvers`` (also ``python -m uuv_ocp.cli``)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from uuv_ocp.reference.path import PAPER_REFERENCES
from uuv_ocp.solvers import available_solvers
from uuv_ocp.studies.compare import format_tracking_table, track_references


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uuv-ocp", description="Optimal control of UUVs with CasADi.")
    commands = parser.add_subparsers(dest="command")

    demo = commands.add_parser("demo", help="track all ten paper references with NMPC + IPOPT for 30 s")
    demo.add_argument("--out", default="out", help="output folder (figures, saved runs)")
    demo.add_argument("--fresh", action="store_true", help="recompute runs already saved in --out")

    track = commands.add_parser("track", help="closed-loop tracking of chosen references")
    track.add_argument(
        "--reference", "-r", nargs="+", default=["s2"], help=f"names from {list(PAPER_REFERENCES)}"
    )
    track.add_argument("--solver", "-s", default="ipopt", help="a name from `uuv-ocp solvers`")
    track.add_argument("--duration", type=float, default=30.0, help="simulated time (s)")
    track.add_argument("--horizon", type=int, default=20, help="shooting intervals N")
    track.add_argument("--dt", type=float, default=0.1, help="sampling time (s)")
    track.add_argument("--out", default="out", help="output folder")
    track.add_argument("--fresh", action="store_true", help="recompute saved runs")

    commands.add_parser("solvers", help="list the registered solver names")

    compare = commands.add_parser("compare", help="one instance, several solvers, one judge")
    compare.add_argument("--reference", "-r", default="s2")
    compare.add_argument(
        "--solvers", nargs="+", default=["ipopt", "sqp", "fatrop", "igwo", "gwo", "ssa", "pso"]
    )
    compare.add_argument("--t0", type=float, default=3.0, help="start time on the reference (s)")
    compare.add_argument("--seed", type=int, default=1)

    campaign = commands.add_parser("campaign", help="Monte Carlo trials with currents, noise, mismatch")
    campaign.add_argument("--reference", "-r", default="s2")
    campaign.add_argument("--solver", "-s", default="ipopt")
    campaign.add_argument("--trials", type=int, default=50)
    campaign.add_argument("--duration", type=float, default=30.0)
    campaign.add_argument("--max-current", type=float, default=0.5, help="m/s")
    campaign.add_argument("--seed", type=int, default=0)
    campaign.add_argument("--executor", choices=["local", "process"], default="local")
    campaign.add_argument("--workers", type=int, default=2)
    campaign.add_argument("--out", default="out/campaigns")

    codegen = commands.add_parser("codegen", help="generate, compile and verify C for a problem")
    codegen.add_argument("--reference", "-r", default="s2")
    codegen.add_argument("--out", default="build", help="output folder")
    codegen.add_argument("--horizon", type=int, default=20)
    codegen.add_argument("--population", type=int, default=20)
    return parser


def _problem(name: str, horizon: int = 20):
    from uuv_ocp import TrackingProblem, Vehicle
    from uuv_ocp.reference.path import Reference

    return TrackingProblem(Vehicle.rexrov(), Reference.paper(name), horizon=horizon)


def _run_compare(args: argparse.Namespace) -> int:
    from uuv_ocp.studies.compare import compare, format_comparison

    problem = _problem(args.reference)
    x0 = problem.reference.evaluate([args.t0])[0]
    rows = compare(problem, args.solvers, x0=x0, t0=args.t0, seed=args.seed)
    print(f"{args.reference} at t0 = {args.t0} s, on the reference (moving); cost from uuv_ocp.score()")
    print(format_comparison(rows))
    return 0


def _run_codegen(args: argparse.Namespace) -> int:
    from uuv_ocp.codegen import generate_c

    generated = generate_c(_problem(args.reference, args.horizon), args.out, population=args.population)
    print(f"library   {generated.library}{' (reused from cache)' if generated.reused else ''}")
    print(f"source    {generated.source}\nheader    {generated.header}")
    for name, error in generated.max_error.items():
        print(f"verified  {name:<16} max relative difference compiled vs symbolic {error:.1e}")
    if generated.simd:
        print("cost_batch is the SIMD population kernel (docs/codegen.md); cost_batch_exact is CasADi's")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``uuv-ocp`` console script."""
    args = _parser().parse_args(argv)
    command = args.command or "demo"
    if command == "solvers":
        print("\n".join(available_solvers()))
        return 0
    if command == "campaign":
        from uuv_ocp.studies.campaign import CampaignConfig, format_summary, run_campaign

        try:
            config = CampaignConfig(
                reference=args.reference,
                solver=args.solver,
                trials=args.trials,
                duration=args.duration,
                max_current=args.max_current,
                seed=args.seed,
            )
            available = available_solvers()
            if args.solver not in available:
                raise ValueError(f"--solver must be one of {available}, got {args.solver!r}")
            result = run_campaign(config, args.out, executor=args.executor, workers=args.workers)
        except ValueError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("\ninterrupted: finished trials are saved; rerun the command to resume", file=sys.stderr)
            return 130
        print(format_summary(result))
        print(f"trials saved in {result.directory}")
        return 0
    if command in ("compare", "codegen"):
        if args.reference not in PAPER_REFERENCES:
            print(
                f"error: --reference must be one of {list(PAPER_REFERENCES)}, got {args.reference!r}",
                file=sys.stderr,
            )
            return 2
        try:
            return _run_compare(args) if command == "compare" else _run_codegen(args)
        except (ValueError, RuntimeError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    if command == "demo":
        names, solver, duration, horizon, dt = PAPER_REFERENCES, "ipopt", 30.0, 20, 0.1
    else:
        unknown = [name for name in args.reference if name not in PAPER_REFERENCES]
        if unknown:
            print(
                f"error: --reference must be among {list(PAPER_REFERENCES)}, got {unknown}",
                file=sys.stderr,
            )
            return 2
        if args.solver not in available_solvers() and "+" not in args.solver:
            print(
                f"error: --solver must be one of {available_solvers()}, got {args.solver!r}",
                file=sys.stderr,
            )
            return 2
        names, solver, duration, horizon, dt = (
            args.reference,
            args.solver,
            args.duration,
            args.horizon,
            args.dt,
        )
    start = time.perf_counter()
    try:
        rows = track_references(
            names,
            solver,
            duration=duration,
            horizon=horizon,
            dt=dt,
            out_dir=args.out,
            fresh=args.fresh,
        )
    except KeyboardInterrupt as interrupt:
        print(f"\ninterrupted: {interrupt}. Run the same command again to resume.", file=sys.stderr)
        return 130
    print()
    print(f"NMPC tracking, RexROV, N = {horizon}, dt = {dt} s, terminal equality, solver {solver}")
    print("errors in m over the whole run and for t >= t0 + 5 s; solve times per step in ms")
    print(format_tracking_table(rows))
    print(f"\nfigures and saved runs in {args.out}/  ({time.perf_counter() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
