"""A BlueROV2 Heavy (6-DOF Fossen model) flies a lawnmower survey at constant depth.

The vehicle starts on the first lane ``dive`` metres above the survey depth, at rest; NMPC
(``TrackingProblem`` on :class:`uuv_ocp.model.Vehicle6DOF`, terminal equality) dives to the
survey depth and follows the lanes and the turns between them, with roll and pitch regulated
to zero.  Printed: the largest depth, heading and horizontal errors after the transient
(``settle`` seconds), the largest roll and pitch, and the solver failures.

Run: ``python examples/bluerov2_depth.py``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF

DEPTH = 2.0  # m (NED: positive down)
SPEED = 0.3  # m/s along the lanes and turns
WIDTH = 6.0  # m, lane length
SPACING = 2.0  # m between lanes (turn radius: SPACING / 2)


@dataclass(frozen=True)
class Outcome:
    """What :func:`main` returns (the tests check it against the survey's geometry)."""

    problem: uo.TrackingProblem
    run: uo.ClosedLoopResult
    depth_error: float  # m, largest |z − z_R| after the transient
    heading_error: float  # rad, largest wrapped |ψ − ψ_R| after the transient


def wrapped(angle: np.ndarray) -> np.ndarray:
    """Angles in [−π, π)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def main(
    duration: float = 60.0,
    horizon: int = 20,
    solver: str = "sqp",
    lanes: int = 3,
    dive: float = 0.5,
    settle: float = 5.0,
    options: dict | None = None,
) -> Outcome:
    """Closed-loop survey of ``duration`` seconds; errors counted from ``settle`` seconds on.

    ``options`` go to the solver (e.g. ``{"qpsol": "hpipm-ocp"}`` for ``sqp-rti``).
    """
    boat = Vehicle6DOF.bluerov2_heavy()  # generalised force τ (6); thrusters=True: 8 T200 forces
    survey = uo.Reference.lawnmower(
        (0.0, 0.0), width=WIDTH, spacing=SPACING, lanes=lanes, speed=SPEED, depth=DEPTH
    )
    problem = uo.TrackingProblem(boat, survey, horizon=horizon, dt=0.1)
    x0 = survey.initial_state(0.0)  # on the path, at rest: [x, y, z, φ, θ, ψ, u, v, w, p, q, r]
    x0[2] -= dive  # start above the survey depth
    run = uo.simulate(uo.NMPC(problem, solver, options=options), x0, duration)
    settled = run.t >= settle
    error = run.states - run.reference
    depth_error = float(np.max(np.abs(error[settled, 2])))
    heading_error = float(np.max(np.abs(wrapped(error[settled, 5]))))
    horizontal = float(np.max(np.linalg.norm(error[settled, :2], axis=1)))
    print(f"{survey.name}: {survey.description}; {boat.name}, N = {horizon}, NMPC + {solver}")
    print(
        f"after t = {settle:g} s: max depth error {depth_error:.2e} m, max heading error "
        f"{heading_error:.2e} rad, max horizontal error {horizontal:.2e} m"
    )
    print(
        f"max |roll| {np.max(np.abs(run.states[:, 3])):.3f} rad, max |pitch| "
        f"{np.max(np.abs(run.states[:, 4])):.3f} rad (dive of {dive:g} m from rest); "
        f"failures {run.failures} of {run.controls.shape[0]} steps, median solve "
        f"{1e3 * np.median(run.solve_times):.1f} ms"
    )
    return Outcome(problem, run, depth_error, heading_error)


if __name__ == "__main__":
    main()
    sys.exit(0)
