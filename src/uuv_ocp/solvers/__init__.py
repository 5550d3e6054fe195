"""Solver registry: every backend is chosen by name and judged by :func:`uuv_ocp.score`.

A backend is a class constructed as ``Backend(problem, options)`` with a method
``solve(p, warm_start) -> SolveResult``.  Adding one is a single :func:`register_solver` call.
Backend instances are cached on the problem (keyed by name and options), so repeated solves
of the same problem never rebuild CasADi objects.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from uuv_ocp.problem import TrackingProblem
from uuv_ocp.solvers.nlp import FatropSolver, IpoptSolver, NlpSolver, SqpSolver
from uuv_ocp.solvers.swarm import SwarmSolver, swarm_factory
from uuv_ocp.solvers.result import Iterate, SolveResult
from uuv_ocp.optimize.population import ALGORITHMS, MinimizeResult, minimize

SolverFactory = Callable[[TrackingProblem, dict[str, Any] | None], Any]

_BUILTIN: dict[str, SolverFactory] = {
    "ipopt": IpoptSolver,
    "fatrop": FatropSolver,
    "sqp": SqpSolver,
    **{method: swarm_factory(method) for method in ALGORITHMS},
}
EXACT_SOLVERS = ("fatrop", "ipopt", "sqp")


class SolverRegistry:
    """Name -> backend factory.  The package's default instance is :data:`REGISTRY`."""

    def __init__(self, factories: dict[str, SolverFactory] | None = None) -> None:
        self._factories: dict[str, SolverFactory] = dict(factories or {})

    def register(self, name: str, factory: SolverFactory, *, overwrite: bool = False) -> None:
        """Add a backend under ``name``."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"solver name must be a non-empty string, got {name!r}")
        if name in self._factories and not overwrite:
            raise ValueError(f"solver {name!r} is already registered; pass overwrite=True")
        self._factories[name] = factory

    def names(self) -> list[str]:
        """Sorted list of registered names, including the ``"<swarm>+<exact>"`` hybrids."""
        hybrids = [f"{swarm}+{exact}" for swarm in ALGORITHMS for exact in EXACT_SOLVERS]
        return sorted([*self._factories, *hybrids])

    def factory(self, name: str) -> SolverFactory:
        """The factory for ``name``; ``ValueError`` listing valid names otherwise."""
        if name in self._factories:
            return self._factories[name]
        if isinstance(name, str) and "+" in name:
            from uuv_ocp.solvers.hybrid import hybrid_factory

            first, _, second = name.partition("+")
            if first in ALGORITHMS and second in EXACT_SOLVERS:
                return hybrid_factory(name, self._factories[first], self._factories[second])
        raise ValueError(f"solver must be one of {self.names()} (or '<swarm>+<exact>'), got {name!r}")


REGISTRY = SolverRegistry(_BUILTIN)


def register_solver(name: str, factory: SolverFactory, *, overwrite: bool = False) -> None:
    """Register a backend class ``factory(problem, options)`` under ``name``."""
    REGISTRY.register(name, factory, overwrite=overwrite)


def available_solvers() -> list[str]:
    """Names accepted by :func:`solve`, sorted."""
    return REGISTRY.names()


def _options_key(options: dict[str, Any] | None) -> str:
    return json.dumps(options or {}, sort_keys=True, default=repr)


def get_solver(problem: TrackingProblem, name: str, options: dict[str, Any] | None = None) -> Any:
    """Backend instance for ``problem`` (built once per problem, name and options)."""
    if not isinstance(problem, TrackingProblem):
        raise ValueError(f"problem must be a uuv_ocp.TrackingProblem, got {type(problem).__name__}")
    if options is not None and not isinstance(options, dict):
        raise ValueError(f"options must be a dict or None, got {options!r}")
    factory = REGISTRY.factory(name)
    cache = problem._cache.setdefault("solvers", {})
    key = (name, _options_key(options))
    if key not in cache:
        cache[key] = factory(problem, options)
    return cache[key]


def solve(
    problem: TrackingProblem,
    solver: str = "ipopt",
    *,
    x0: object,
    t0: float = 0.0,
    u_prev: object | None = None,
    current: object | None = None,
    warm_start: Iterate | None = None,
    options: dict[str, Any] | None = None,
) -> SolveResult:
    """Solve one instance of ``problem`` with the backend named ``solver``.

    Parameters
    ----------
    problem : TrackingProblem
    solver : str
        A name from :func:`available_solvers`, or ``"<swarm>+<exact>"``.
    x0 : array_like, shape (6,)
        Initial state (m, m, rad, m/s, m/s, rad/s).
    t0 : float
        Start time on the reference (s).
    u_prev : array_like, shape (3,), optional
        Last applied control (N, N, N·m) for the first rate bound; zero by default.
    current : array_like, shape (2,) or (N, 2), optional
        Inertial current velocity (m/s) assumed by the model.
    warm_start : Iterate, optional
        From a previous :class:`SolveResult` (``result.iterate`` or ``result.iterate.shift()``).
    options : dict, optional
        Backend options (see each backend's documentation).

    Returns
    -------
    SolveResult
        Never raises on solver failure: ``success=False`` and ``status`` say what happened.
    """
    backend = get_solver(problem, solver, options)
    p = problem.parameters(x0, t0, u_prev, current)
    if warm_start is not None and not isinstance(warm_start, Iterate):
        raise ValueError(f"warm_start must be a uuv_ocp Iterate or None, got {type(warm_start).__name__}")
    return backend.solve(p, warm_start)


__all__ = [
    "FatropSolver",
    "IpoptSolver",
    "Iterate",
    "NlpSolver",
    "REGISTRY",
    "SolveResult",
    "SolverRegistry",
    "SqpSolver",
    "SwarmSolver",
    "MinimizeResult",
    "minimize",
    "available_solvers",
    "get_solver",
    "register_solver",
    "solve",
]
