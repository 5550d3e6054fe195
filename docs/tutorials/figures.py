"""Figures for a report: path, errors on a log scale, thrust, heading and velocities, an animation.

Three NMPC runs of the s2 reference with the same solver and different conditions, labelled by
the user (not by the solver name, which all three share); every tracking figure marks the steps
solved with the soft terminal constraint, steps that failed and steps past a deadline.  Written
as SVG (vector, for a report) and PNG; the closed loop is also written as a GIF when pillow is
installed.

Run: ``python docs/tutorials/figures.py`` (writes into ``out/tutorials/figures/``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import uuv_ocp as uo
from uuv_ocp import plotting


def main(
    duration: float = 20.0,
    horizon: int = 20,
    solver: str = "fatrop",
    out: str | Path = "out/tutorials/figures",
) -> dict:
    """Run the three cases and write the figures; return name -> path of every file written."""
    out = Path(out)
    reference = uo.Reference.paper("s2")
    vehicle = uo.Vehicle.rexrov()
    problem = uo.TrackingProblem(vehicle, reference, horizon=horizon, dt=0.1)
    x0 = reference.initial_state(0.0)
    current = uo.Current(0.3, 0.5)
    runs = [
        uo.simulate(uo.NMPC(problem, solver), x0, duration),
        uo.simulate(uo.NMPC(problem, solver), x0, duration, current=current),
        uo.simulate(uo.NMPC(problem, solver), x0, duration, current=current, current_known=False),
    ]
    labels = [f"{solver}, still water", f"{solver}, current known", f"{solver}, current unknown"]
    written = {}
    for suffix in (".svg", ".png"):
        files = plotting.save_tracking_figures(
            runs, out, prefix="s2_", suffix=suffix, labels=labels, vehicle=vehicle
        )
        written.update({f"{name}{suffix}": path for name, path in files.items()})
    # the same figures one by one, with their options
    figure = plotting.error_figure(runs, "s2: tracking error", labels=labels, heading=False)
    written["errors_xy.pdf"] = plotting.save_figure(figure, out / "s2_errors_xy.pdf")
    try:
        animation = plotting.closed_loop_animation(runs, labels=labels, stride=5)
        written["loop.gif"] = plotting.save_animation(animation, out / "s2_loop.gif", fps=10)
    except plotting.AnimationWriterUnavailable as missing:
        print(f"animation skipped: {missing}")
    for name, path in sorted(written.items()):
        print(f"{name:<16} {path}")
    return written


if __name__ == "__main__":
    main()
    sys.exit(0)
