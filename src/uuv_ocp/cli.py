"""Command line: ``uuv-ocp demo | track | solvers`` (also ``python -m uuv_ocp.cli``)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from uuv_ocp.experiments import format_tracking_table, track_references
from uuv_ocp.references import PAPER_REFERENCES
from uuv_ocp.solvers import available_solvers


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uuv-ocp", description="Optimal control of UUVs with CasADi."
    )
    commands = parser.add_subparsers(dest="command")

    demo = commands.add_parser(
        "demo", help="track all ten paper references with NMPC + IPOPT for 30 s"
    )
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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``uuv-ocp`` console script."""
    args = _parser().parse_args(argv)
    command = args.command or "demo"
    if command == "solvers":
        print("\n".join(available_solvers()))
        return 0
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
