"""Write the input file of examples/c/main.c for one IGWO step of the s2 problem.

Usage: ``python examples/c/write_input.py build/input.txt [seed]``.  Also prints what Python
computes for the same data, so the two outputs can be compared.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.optimize import ImprovedGreyWolf


def write_input(path: str | Path, seed: int = 0, problem: uo.TrackingProblem | None = None) -> dict:
    """Write the file; return the problem, parameters, controls and Python's cost terms."""
    reference = uo.Reference.paper("s2")
    problem = problem or uo.TrackingProblem(uo.Vehicle.rexrov(), reference)
    x0 = reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    rng = np.random.default_rng(seed)
    dim, n, iterations = problem.control_dim, 20, 30
    offset = np.zeros(dim)
    lower, upper = -np.ones(dim), np.ones(dim)
    algorithm = ImprovedGreyWolf(lower, upper, n, iterations, None)
    positions = lower + rng.random((n, dim)) * algorithm.width
    draws = rng.random((iterations, 8, n, dim))
    a = np.array([algorithm._a(t) for t in range(iterations)])
    w = np.array([algorithm._w(t) for t in range(iterations)])
    controls = rng.uniform(-0.5, 0.5, dim)
    header = f"{n} {dim} {iterations} {p.size}\n"
    blocks = [p, offset, lower, upper, positions, draws, a, w, controls]
    body = "\n".join(" ".join(repr(float(v)) for v in np.ravel(block)) for block in blocks)
    Path(path).write_text(header + body + "\n")
    objective, penalty = (float(v) for v in problem.build().cost(controls, p))
    cost, _ = uo.score(problem, problem.controls_from_scaled(controls), x0, 3.0)
    return {
        "problem": problem,
        "p": p,
        "controls": controls,
        "objective": objective,
        "penalty": penalty,
        "score": cost,
    }


def main(argv: list[str] | None = None) -> dict:
    """Command-line entry: write the file and print Python's values."""
    argv = sys.argv[1:] if argv is None else argv
    path = argv[0] if argv else "input.txt"
    seed = int(argv[1]) if len(argv) > 1 else 0
    result = write_input(path, seed)
    print(f"python score {result['score']:.17g}\npython penalty {result['penalty']:.17g}")
    return result


if __name__ == "__main__":
    main()
