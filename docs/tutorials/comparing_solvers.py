"""Choosing and comparing solvers: every kind of backend on one NMPC instance, judged alike.

``uo.available_solvers()`` lists the names; ``uo.compare`` solves one instance with each (after
a first solve that builds it, so the time is a steady-state solve), judges each plan with
:func:`uuv_ocp.score` and ranks them: feasible plans by cost first, the rest by violation.

Run: ``python docs/tutorials/comparing_solvers.py`` (writes ``out/tutorials/comparison.png``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import uuv_ocp as uo
from uuv_ocp.solvers import REGISTRY

SOLVERS = ("ipopt", "fatrop", "sqp", "igwo", "pso", "igwo+fatrop")


def main(
    solvers: tuple[str, ...] = SOLVERS,
    horizon: int = 20,
    swarm_budget: tuple[int, int] = (20, 30),
    out: str | Path | None = "out/tutorials/comparison.png",
) -> list:
    """Compare ``solvers`` on the s2 state at t = 3 s; the swarms get ``(population, iterations)``."""
    names = uo.available_solvers()
    for kind in ("exact", "swarm", "hybrid"):
        of_kind = [name for name in names if REGISTRY.kind(name) == kind]
        print(f"{kind:>6}: {', '.join(of_kind)}")
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=horizon, dt=0.1)
    t0 = 3.0
    x0 = reference.evaluate([t0])[0]  # on the path, moving with it
    population, iterations = swarm_budget
    budget = {"population": population, "iterations": iterations}
    options: dict[str, dict] = {}
    for name in solvers:
        kind = REGISTRY.kind(name)
        if kind == "swarm":
            options[name] = dict(budget)
        elif kind == "hybrid":
            options[name] = {"swarm": dict(budget)}  # a hybrid's options go to its two halves
    rows = uo.compare(problem, list(solvers), x0=x0, t0=t0, seed=1, options=options)
    print(uo.format_comparison(rows))
    if out is not None:
        from uuv_ocp.plotting import comparison_figure, save_figure

        title = f"s2 at t = {t0:g} s, N = {horizon}; swarms {population} x {iterations}"
        print(f"figure: {save_figure(comparison_figure(rows, title), out)}")
    return rows


if __name__ == "__main__":
    main()
    sys.exit(0)
