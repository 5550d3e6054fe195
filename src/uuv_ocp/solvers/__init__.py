"""Solver registry: every backend is chosen by name and judged by :func:`uuv_ocp.score`.

A backend is a class constructed as ``Backend(problem, options)`` with a method
``solve(p, warm_start) -> SolveResult``.  Adding one is a single :func:`register_solver` call.

A backend is stateful (its solver memory, zero-copy buffers, warm starts of a C step) and is
owned by whoever created it; no two threads ever share one through this module:

- :func:`new_solver` builds a backend of your own (what :class:`~uuv_ocp.control.NMPC` does);
- :func:`solve` checks a backend out of a small package-level pool, keyed by the problem's
  content, the solver name and the options, for the length of the call: a backend in use is
  never handed to another call (a second thread gets another one, built then), so repeated
  solves stay fast without sharing;
- :func:`get_solver` returns the calling thread's backend for (problem content, name,
  options), built on its first request in that thread.
"""

from __future__ import annotations

import contextlib
import difflib
import json
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any

from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import instance_parameters
from uuv_ocp.optimize import ALGORITHMS, MinimizeResult, minimize, register_algorithm
from uuv_ocp.optimize.loop import PopulationAlgorithm
from uuv_ocp.solvers.base import check_backend
from uuv_ocp.solvers.fatrop import FatropSolver
from uuv_ocp.solvers.hybrid import hybrid_factory
from uuv_ocp.solvers.ipopt import IpoptSolver
from uuv_ocp.solvers.mppi import MppiSolver
from uuv_ocp.solvers.multistart import multistart_factory
from uuv_ocp.solvers.nlp import NlpSolver
from uuv_ocp.solvers.result import Iterate, SolveResult
from uuv_ocp.solvers.rti import RtiSolver
from uuv_ocp.solvers.slsqp import SlsqpSolver
from uuv_ocp.solvers.sqp import SqpSolver
from uuv_ocp.solvers.swarm import SwarmSolver, swarm_factory

SolverFactory = Callable[[Transcribed, dict[str, Any] | None], Any]

KINDS = ("exact", "swarm")
_BUILTIN: dict[str, tuple[SolverFactory, str]] = {
    "ipopt": (IpoptSolver, "exact"),
    "fatrop": (FatropSolver, "exact"),
    "sqp": (SqpSolver, "exact"),
    "sqp-rti": (RtiSolver, "exact"),
    "slsqp": (SlsqpSolver, "exact"),
    # "mppi" in ALGORITHMS is the static update of uo.minimize; as a solver it is the
    # receding-horizon MppiSolver (shifted warm start, smoothing) on the same weights
    **{method: (swarm_factory(method), "swarm") for method in ALGORITHMS if method != "mppi"},
    "mppi": (MppiSolver, "swarm"),  # a sampling method: a warm start for the hybrids like a swarm
}


class SolverRegistry:
    """Name -> (backend factory, kind).  The package's default instance is :data:`REGISTRY`.

    A ``"<first>+<second>"`` name is a hybrid whenever ``first`` is registered with
    ``kind="swarm"`` and ``second`` with ``kind="exact"``: plug-ins can be either half.
    ``"multistart-<exact>"`` (:mod:`uuv_ocp.solvers.multistart`) exists for every ``kind="exact"``
    name; it is resolved here like a hybrid, not registered as an exact backend, so no
    ``"<swarm>+multistart-<exact>"`` hybrid is offered.
    """

    def __init__(self, factories: dict[str, tuple[SolverFactory, str]] | None = None) -> None:
        self._factories: dict[str, tuple[SolverFactory, str]] = dict(factories or {})

    def register(
        self, name: str, factory: SolverFactory, *, kind: str = "exact", overwrite: bool = False
    ) -> None:
        """Add a backend under ``name`` (``kind`` says which half of a hybrid it can be)."""
        if not isinstance(name, str) or not name or "+" in name:
            raise ValueError(f"solver name must be a non-empty string without '+', got {name!r}")
        if not callable(factory):
            raise ValueError(f"factory must be callable as factory(problem, options), got {factory!r}")
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
        if name in self._factories and not overwrite:
            raise ValueError(f"solver {name!r} is already registered; pass overwrite=True")
        if isinstance(factory, type):  # a class: its protocol can be read now, before any build
            check_backend(factory, name)
        self._factories[name] = (factory, kind)

    def kind(self, name: str) -> str:
        """``"exact"``, ``"swarm"``, ``"hybrid"`` or ``"multistart"``."""
        name = self.resolve(name)
        if name in self._factories:
            return self._factories[name][1]
        return "hybrid" if "+" in name else "multistart"

    def names(self) -> list[str]:
        """Sorted list of registered names, including the ``"<swarm>+<exact>"`` hybrids."""
        swarms = [name for name, (_, kind) in self._factories.items() if kind == "swarm"]
        exact = [name for name, (_, kind) in self._factories.items() if kind == "exact"]
        hybrids = [f"{first}+{second}" for first in swarms for second in exact]
        multistarts = [f"multistart-{second}" for second in exact]
        return sorted({*self._factories, *hybrids, *multistarts})

    def resolve(self, name: str) -> str:
        """Return the registered spelling of ``name`` (case-insensitive, halves of hybrids too).

        Raises
        ------
        ValueError
            Unknown name; the message lists the valid names and suggests the closest ones.
        """
        if not isinstance(name, str):
            raise ValueError(f"solver must be a string from available_solvers(), got {name!r}")
        if name in self._factories:
            return name
        spelled = {registered.lower(): registered for registered in self._factories}
        lowered = name.strip().lower()
        if "+" in lowered:
            first, _, second = lowered.partition("+")
            swarm, exact = spelled.get(first), spelled.get(second)
            if (
                swarm
                and exact
                and self._factories[swarm][1] == "swarm"
                and self._factories[exact][1] == "exact"
            ):
                return f"{swarm}+{exact}"
        elif lowered.startswith("multistart-"):
            inner = spelled.get(lowered[len("multistart-") :])
            if inner is not None and self._factories[inner][1] == "exact":
                return f"multistart-{inner}"
        elif lowered in spelled:
            return spelled[lowered]
        names = self.names()
        close = difflib.get_close_matches(lowered, [known.lower() for known in names], n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(repr(n) for n in close)}?" if close else ""
        raise ValueError(
            f"solver must be one of {names} (or '<swarm>+<exact>', 'multistart-<exact>'), got {name!r}{hint}"
        )

    def factory(self, name: str) -> SolverFactory:
        """Return the factory for ``name`` (see :meth:`resolve`); ``ValueError`` if unknown."""
        name = self.resolve(name)
        if name in self._factories:
            return self._factories[name][0]
        if "+" in name:
            first, _, second = name.partition("+")
            return hybrid_factory(name, self._factories[first][0], self._factories[second][0])
        return multistart_factory(name, self._factories[name[len("multistart-") :]][0])


REGISTRY = SolverRegistry(_BUILTIN)


def register_solver(
    name: str, factory: SolverFactory, *, kind: str = "exact", overwrite: bool = False
) -> None:
    """Register a backend ``factory(problem, options) -> Backend`` under ``name``.

    ``kind="swarm"`` or ``"exact"`` says which half of a ``"<swarm>+<exact>"`` hybrid it can be.
    A class is checked against :class:`~uuv_ocp.solvers.base.Backend` here (``TypeError``
    naming the missing member); what a factory function returns, when it is first built.
    """
    REGISTRY.register(name, factory, kind=kind, overwrite=overwrite)


def register_swarm(algorithm: type[PopulationAlgorithm], *, overwrite: bool = False) -> None:
    """Register a population algorithm as :func:`uuv_ocp.minimize` method *and* swarm backend.

    One class (a :class:`~uuv_ocp.optimize.loop.PopulationAlgorithm` subclass with a ``name``)
    becomes ``minimize(method=name)``, ``solve(problem, name)``, ``NMPC(problem, name)``, the
    hybrids ``"name+<exact>"`` and every registry-iterating test, on the compiled population
    evaluation of the problem like the built-in swarms.
    """
    register_algorithm(algorithm, overwrite=overwrite)
    REGISTRY.register(algorithm.name, swarm_factory(algorithm.name), kind="swarm", overwrite=overwrite)


def available_solvers() -> list[str]:
    """Names accepted by :func:`solve`, sorted."""
    return REGISTRY.names()


def _options_key(options: dict[str, Any] | None) -> str:
    return json.dumps(options or {}, sort_keys=True, default=repr)


#: Most idle backends :func:`solve` keeps (the least recently returned is dropped first).
POOL_SIZE = 16
#: Most backends :func:`get_solver` keeps per thread (the least recently requested is dropped).
THREAD_SOLVERS = 16

_POOL: OrderedDict[tuple[Any, ...], list[Any]] = OrderedDict()  # key -> idle backends
_POOL_LOCK = threading.Lock()
_THREAD = threading.local()  # .solvers: this thread's get_solver backends by key


def _checked(problem: Transcribed, name: str, options: dict[str, Any] | None) -> tuple[str, tuple[Any, ...]]:
    """Validate the arguments of a backend request; the registered name and the backend's key."""
    if not isinstance(problem, Transcribed):
        raise ValueError(f"problem must be a uuv_ocp.Ocp or TrackingProblem, got {type(problem).__name__}")
    if options is not None and not isinstance(options, dict):
        raise ValueError(f"options must be a dict or None, got {options!r}")
    name = REGISTRY.resolve(name)
    return name, (type(problem), problem.spec().key, name, _options_key(options))


def new_solver(problem: Transcribed, name: str, options: dict[str, Any] | None = None) -> Any:
    """Build a new backend ``name`` for ``problem``, owned by the caller (shared with nobody).

    Raises
    ------
    ValueError
        Not a problem, an unknown name or options that are not a dict (or that the backend
        rejects), before anything is built.
    TypeError
        The factory's product does not conform to :class:`~uuv_ocp.solvers.base.Backend`
        (the message names the backend and the missing member).
    """
    name, _ = _checked(problem, name, options)
    factory = REGISTRY.factory(name)
    with BUILD_LOCK:  # constructors build CasADi objects
        backend = factory(problem, options)
    check_backend(backend, name)  # a factory function's product is known only now
    return backend


def get_solver(problem: Transcribed, name: str, options: dict[str, Any] | None = None) -> Any:
    """Return the calling thread's backend for ``problem`` (one per thread, content, name, options).

    Equal problems share it within a thread; another thread gets a backend of its own.  Use
    :func:`new_solver` for a backend that nothing else hands out.
    """
    name, key = _checked(problem, name, options)
    solvers: OrderedDict[tuple[Any, ...], Any] | None = getattr(_THREAD, "solvers", None)
    if solvers is None:
        solvers = _THREAD.solvers = OrderedDict()
    backend = solvers.get(key)
    if backend is None:
        backend = solvers[key] = new_solver(problem, name, options)
        if len(solvers) > THREAD_SOLVERS:
            solvers.popitem(last=False)
    else:
        solvers.move_to_end(key)
    return backend


@contextlib.contextmanager
def checked_out(problem: Transcribed, name: str, options: dict[str, Any] | None = None) -> Iterator[Any]:
    """Lend a backend from the pool for the ``with`` block (exclusively; see the module doc)."""
    name, key = _checked(problem, name, options)
    with _POOL_LOCK:
        idle = _POOL.get(key)
        backend = idle.pop() if idle else None
    if backend is None:
        backend = new_solver(problem, name, options)
    try:
        yield backend
    finally:
        with _POOL_LOCK:
            _POOL.setdefault(key, []).append(backend)
            _POOL.move_to_end(key)
            while sum(len(idle) for idle in _POOL.values()) > POOL_SIZE:
                oldest = next(iter(_POOL))
                _POOL[oldest].pop(0)
                if not _POOL[oldest]:
                    del _POOL[oldest]


def solve(
    problem: Transcribed,
    solver: str = "ipopt",
    *,
    x0: object,
    t0: float = 0.0,
    u_prev: object | None = None,
    current: object | None = None,
    warm_start: Iterate | None = None,
    options: dict[str, Any] | None = None,
    parameters: dict[str, Any] | None = None,
) -> SolveResult:
    """Solve one instance of ``problem`` with the backend named ``solver``.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    solver : str
        A name from :func:`available_solvers`, or ``"<swarm>+<exact>"``.
    x0 : array_like, shape (nx,)
        Initial state (3-DOF tracking: m, m, rad, m/s, m/s, rad/s).
    t0 : float
        Start time on the reference (s); tracking problems only.
    u_prev : array_like, shape (3,), optional
        Last applied control (N, N, N·m) for the first rate bound; zero clipped into the box by default.
    current : array_like, shape (2,) or (N, 2), optional
        Inertial current velocity (m/s) assumed by the model.
    warm_start : Iterate, optional
        From a previous :class:`SolveResult` (``result.iterate`` or ``result.iterate.shift()``).
    options : dict, optional
        Backend options (see each backend's documentation).
    parameters : dict, optional
        Values of an :class:`~uuv_ocp.ocp.Ocp`'s declared parameters by name.

    Returns
    -------
    SolveResult
        Never raises on solver failure: ``success=False`` and ``status`` say what happened.
    """
    with checked_out(problem, solver, options) as backend:
        p = instance_parameters(problem, x0, t0, u_prev=u_prev, current=current, parameters=parameters)
        if warm_start is not None and not isinstance(warm_start, Iterate):
            raise ValueError(f"warm_start must be a uuv_ocp Iterate or None, got {type(warm_start).__name__}")
        return backend.solve(p, warm_start)


__all__ = [
    "FatropSolver",
    "IpoptSolver",
    "MppiSolver",
    "Iterate",
    "NlpSolver",
    "REGISTRY",
    "RtiSolver",
    "SolveResult",
    "SolverRegistry",
    "SlsqpSolver",
    "SqpSolver",
    "SwarmSolver",
    "register_swarm",
    "MinimizeResult",
    "minimize",
    "available_solvers",
    "get_solver",
    "new_solver",
    "register_solver",
    "solve",
]
