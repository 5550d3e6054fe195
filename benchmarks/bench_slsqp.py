"""One open-loop solve of s2 (RexROV, N = 20) by ``slsqp`` against IPOPT, and where its time goes.

From the feasible start of ``tests/conftest.py`` (s2 at t0 = 3 s, slightly off the path): the
relative cost difference to IPOPT, SLSQP's iterations, the wall time of a solve (built once
before) and the share of it inside scipy's SLSQP routine (cProfile).

Run: ``python -m benchmarks.bench_slsqp``.
"""

from __future__ import annotations

import cProfile
import pstats
import time

import numpy as np

import uuv_ocp as uo


def main() -> None:
    """Print the comparison and the profile share."""
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)
    x0 = uo.Reference.paper("s2").evaluate([3.0])[0] + np.array([0.05, -0.04, 0.02, 0.03, 0.01, -0.01])
    reference = uo.solve(problem, "ipopt", x0=x0, t0=3.0)
    uo.solve(problem, "slsqp", x0=x0, t0=3.0)  # builds its functions
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    result = uo.solve(problem, "slsqp", x0=x0, t0=3.0)
    profile.disable()
    elapsed = time.perf_counter() - start
    inside = sum(
        row[3]
        for key, row in pstats.Stats(profile).stats.items()
        if key[2] == "<built-in method scipy.optimize._slsqplib.slsqp>"
    )
    relative = (result.cost - reference.cost) / reference.cost
    print(f"slsqp: success {result.success}, cost {relative:+.1e} rel. to IPOPT")
    print(
        f"       {result.iterations} iterations, {elapsed:.2f} s, {inside / elapsed:.0%} inside scipy's SLSQP"
    )


if __name__ == "__main__":
    main()
