"""Generated C: one problem as a C library, compiled, verified, and used from Python.

``uo.generate_c(problem, directory)`` writes the problem's functions as C (CasADi's code
generator, plus the SIMD swarm fitness and the all-C IGWO step), compiles them with the system
C compiler, loads them back and checks each against its symbolic twin.  Here the compiled
``rollout`` predicts the states of a plan that ``sqp`` solved, and the compiled ``cost`` gives
its objective; both agree with the solver and the judge.  Without a C compiler the script says
so and stops.

Run: ``python docs/tutorials/generated_c.py`` (writes into ``build/tutorial_c/``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import uuv_ocp as uo
from uuv_ocp.native.compile import CompilerNotFoundError, find_c_compiler


def main(horizon: int = 20, population: int = 20, directory: str | Path = "build/tutorial_c") -> dict | None:
    """Generate, compile and use the C of an s2 tracking problem; ``None`` without a compiler."""
    try:
        compiler = find_c_compiler()
    except CompilerNotFoundError as missing:
        print(f"skipped: {missing}")
        return None
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=horizon, dt=0.1)
    code = uo.generate_c(problem, directory, population=population)
    print(f"compiler {compiler}; library {code.library} (reused from the cache: {code.reused})")
    print(f"header {code.header}; SIMD swarm fitness: {code.simd}")
    for name, error in sorted(code.max_error.items()):
        print(f"  {name:<18} largest relative difference to the symbolic function {error:.1e}")

    t0 = 3.0
    x0 = reference.evaluate([t0])[0]
    plan = uo.solve(problem, "sqp", x0=x0, t0=t0)
    p = problem.parameters(x0, t0)  # the instance as one parameter vector
    scaled = problem.scaled_from_controls(plan.controls)  # the plan as the functions take it
    states = np.array(code["rollout"](scaled, p)).T  # X is (nx, N+1): one column per node
    objective, penalty = (float(value) for value in code["cost"](scaled, p))
    rollout_gap = float(np.max(np.abs(states - plan.states)))
    print(f"sqp plan: cost {plan.cost:.9g} (judge); compiled cost {objective:.9g} + penalty {penalty:.1e}")
    print(f"compiled rollout vs the solver's predicted states: largest difference {rollout_gap:.1e}")
    return {"code": code, "plan": plan, "states": states, "objective": objective, "penalty": penalty}


if __name__ == "__main__":
    main()
    sys.exit(0)
