"""Metaheuristic warm start of an exact solver: ``"<swarm>+<exact>"``, e.g. ``"igwo+ipopt"``.

The swarm runs first on the condensed cost; its best control sequence, with the states of its
rollout through the same RK4 model, becomes the exact solver's initial guess.  The exact
solver's result is returned (``solver="igwo+ipopt"``), with the swarm's evaluations added and
its best fitness in ``details["swarm_fitness"]``.  In a closed loop the next swarm is centred
on the exact solver's shifted plan.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from uuv_ocp.build import Transcribed
from uuv_ocp.solvers.result import Iterate, SolveResult


class HybridSolver:
    """Run ``first`` (a swarm), then ``second`` (an exact solver) from the swarm's best plan.

    Options: ``{"swarm": {...}, "exact": {...}}`` passed to the two backends.
    """

    def __init__(self, name: str, first: Any, second: Any) -> None:
        self.name = name
        self.first = first
        self.second = second

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
    ) -> SolveResult:
        """Swarm, then exact solve warm-started on the swarm's plan."""
        start = time.perf_counter()
        swarm = self.first.solve(p, warm_start, rng)
        guess = Iterate(scaled_controls=swarm.iterate.scaled_controls, states=swarm.iterate.states)
        exact = self.second.solve(p, guess)
        details = dict(exact.details)
        details.update({"swarm_fitness": swarm.details.get("fitness"), "swarm_cost": swarm.cost})
        return dataclasses.replace(
            exact,
            solver=self.name,
            solve_time=time.perf_counter() - start,
            evaluations=exact.evaluations + swarm.evaluations,
            history=swarm.history,
            details=details,
        )


def hybrid_factory(name: str, first: Callable, second: Callable) -> Callable:
    """Registry factory for ``"<first>+<second>"``."""

    def factory(problem: Transcribed, options: dict[str, Any] | None = None) -> HybridSolver:
        options = dict(options or {})
        swarm_options = options.pop("swarm", None)
        exact_options = options.pop("exact", None)
        if options:
            raise ValueError(
                f"options of {name!r} take only 'swarm' and 'exact' dicts, got {sorted(options)}"
            )
        return HybridSolver(name, first(problem, swarm_options), second(problem, exact_options))

    return factory
