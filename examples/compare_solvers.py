"""Every registered solver on one s2 instance: a table judged by score(), and a convergence plot.

Run: ``python examples/compare_solvers.py`` (writes ``out/compare_convergence.png``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import uuv_ocp as uo  # noqa: E402
from uuv_ocp.studies.compare import ComparisonRow  # noqa: E402

DEFAULT_SOLVERS = ("ipopt", "sqp", "fatrop", "igwo", "gwo", "ssa", "pso", "igwo+ipopt")


def main(
    solvers: tuple[str, ...] = DEFAULT_SOLVERS,
    horizon: int = 20,
    swarm_options: dict | None = None,
    out: str | Path = "out",
) -> list[ComparisonRow]:
    """Compare the solvers; return the rows and save the convergence figure."""
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=horizon)
    x0 = reference.evaluate([3.0])[0]
    options = {name: dict(swarm_options) for name in solvers if "+" not in name and swarm_options}
    options = {name: value for name, value in options.items() if name in ("igwo", "gwo", "ssa", "pso")}
    rows = uo.compare(problem, solvers, x0=x0, t0=3.0, seed=1, options=options)
    print(uo.format_comparison(rows))
    figure, axes = plt.subplots(figsize=(6.4, 4.0))
    exact = min(row.cost for row in rows if row.history is None)
    for row in rows:
        if row.history is not None and "+" not in row.solver:
            axes.semilogy(np.arange(row.history.size), row.history / exact, label=row.solver)
    axes.set_xlabel("iteration")
    axes.set_ylabel("best fitness / exact optimum")
    axes.set_title(f"Swarm convergence on one s2 NMPC step (N = {horizon})")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend()
    figure.tight_layout()
    path = Path(out) / "compare_convergence.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    print(f"convergence plot: {path}")
    return rows


if __name__ == "__main__":
    main()
    sys.exit(0)
