"""The front door :func:`minimize` and the registry :data:`ALGORITHMS` of population optimisers.

:func:`minimize` is scipy-like: one function, one result type
(:class:`~uuv_ocp.optimize.loop.MinimizeResult`).  The objective is *vectorised*: ``fun(X)``
receives the whole population ``X`` of shape ``(population, dim)`` and returns
``(population,)`` costs, and it is called exactly once per iteration (plus once for the initial
population).  This is what lets the NMPC map a compiled CasADi cost over the population instead
of looping over individuals in Python.
"""

from __future__ import annotations

import numbers
import threading
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from uuv_ocp._validation import positive_float, positive_int
from uuv_ocp.optimize.gwo import GreyWolf
from uuv_ocp.optimize.igwo import ImprovedGreyWolf
from uuv_ocp.optimize.loop import MinimizeResult, Objective, PopulationAlgorithm, validate_bounds
from uuv_ocp.optimize.mppi import PathIntegral
from uuv_ocp.optimize.pso import ParticleSwarm
from uuv_ocp.optimize.ssa import SparrowSearch

__all__ = ["ALGORITHMS", "available_methods", "minimize", "register_algorithm"]

_LOCK = threading.Lock()
_ALGORITHMS: dict[str, type[PopulationAlgorithm]] = {
    cls.name: cls for cls in (ImprovedGreyWolf, GreyWolf, SparrowSearch, ParticleSwarm, PathIntegral)
}
#: Registry name -> algorithm class (a read-only view; :func:`register_algorithm` adds to it).
ALGORITHMS: Mapping[str, type[PopulationAlgorithm]] = MappingProxyType(_ALGORITHMS)


def register_algorithm(algorithm: type[PopulationAlgorithm], *, overwrite: bool = False) -> None:
    """Make a population algorithm available to :func:`minimize` by its ``name``.

    The swarm backends take it too once it is registered as a solver
    (:func:`uuv_ocp.register_swarm` does both).

    Raises
    ------
    ValueError
        ``algorithm`` is not a :class:`~uuv_ocp.optimize.loop.PopulationAlgorithm` subclass,
        its ``name`` is not a non-empty identifier, or the name is taken (``overwrite=False``).
    """
    if not (isinstance(algorithm, type) and issubclass(algorithm, PopulationAlgorithm)):
        raise ValueError(f"algorithm must be a PopulationAlgorithm subclass, got {algorithm!r}")
    name = algorithm.name
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"algorithm.name must be a non-empty identifier, got {name!r}")
    with _LOCK:
        if name in _ALGORITHMS and not overwrite:
            raise ValueError(f"algorithm {name!r} is registered already (pass overwrite=True)")
        _ALGORITHMS[name] = algorithm


def available_methods() -> list[str]:
    """Sorted names accepted by :func:`minimize` (``method=``).

    Returns
    -------
    list of str
        The keys of :data:`ALGORITHMS`, sorted.
    """
    return sorted(ALGORITHMS)


def minimize(
    fun: Objective,
    lower: object,
    upper: object,
    method: str = "igwo",
    *,
    population: int | None = None,
    iterations: int | None = None,
    max_evaluations: int | None = None,
    seed: int | np.random.Generator | None = None,
    initial_population: object = None,
    options: Mapping[str, Any] | None = None,
    time_limit: float | None = None,
) -> MinimizeResult:
    """Minimise a vectorised objective over a box with a population optimiser.

    Parameters
    ----------
    fun : callable
        ``fun(X) -> costs`` with ``X`` of shape ``(population, dim)`` and costs of shape
        ``(population,)`` (any array of exactly ``population`` elements, e.g. a CasADi
        ``(1, population)`` row, is flattened).  Called once for the initial population and once
        per iteration; non-finite costs (NaN, ``±inf``) count as ``+inf``, i.e. rank last.
    lower, upper : array_like, shape (dim,), or scalar
        Box bounds, finite, ``lower < upper``.  One of them may be a scalar broadcast to the
        other's shape; two arrays must have equal shapes.
    method : {"igwo", "gwo", "ssa", "pso"}
        Algorithm, see :func:`available_methods`.
    population : int, optional
        Population size (>= 4).  Default per method as in the paper: igwo 20, gwo 30,
        ssa 50, pso 30.
    iterations : int, optional
        Iteration budget ``T`` (>= 1); also sets the schedules (``a(t)``, ``w(t)``).
        Default: igwo 30, gwo 40, ssa 80, pso 40.
    max_evaluations : int, optional
        Stop before an iteration that would exceed this many evaluations (the initial
        population counts); must be >= ``population``.
    seed : int, numpy.random.Generator or None
        All randomness goes through ``numpy.random.default_rng(seed)``; the same int seed
        gives bit-identical results.
    initial_population : array_like, shape (k, dim), optional
        ``k <= population`` starting points placed first (clipped to the box), e.g. a
        shifted previous plan; the remaining individuals are uniform in the box.
    options : mapping, optional
        Algorithm parameters, see each algorithm class.
    time_limit : float, optional
        Wall-clock budget in seconds (finite, > 0) from the start of the call.  Checked after
        the initial population and after every iteration (a call of ``fun`` is never
        interrupted): once exceeded, no further iteration starts and the best point so far is
        returned with ``deadline_hit=True`` and a message saying the deadline stopped it.
        Random draws are those of the unlimited run up to the stop.

    Returns
    -------
    MinimizeResult
        ``success`` is ``False`` (and ``fun`` is ``inf``) if ``fun`` never returned a finite
        cost; the message then says so.

    Raises
    ------
    ValueError
        On any invalid argument; the message names the parameter, the expected range and the
        value received.  Also if ``fun`` returns costs of the wrong shape or non-numbers (the
        message names ``fun``, the expected and the actual shape).
    """
    if not callable(fun):
        raise ValueError(f"fun must be callable, got {fun!r}")
    if method not in ALGORITHMS:
        raise ValueError(f"method must be one of {available_methods()}, got {method!r}")
    cls = ALGORITHMS[method]
    lo, up = validate_bounds(lower, upper)
    dim = lo.shape[0]
    n = cls.default_population if population is None else positive_int("population", population, 4)
    T = cls.default_iterations if iterations is None else positive_int("iterations", iterations, 1)
    if max_evaluations is not None:
        if isinstance(max_evaluations, bool) or not isinstance(max_evaluations, numbers.Integral):
            raise ValueError(
                f"max_evaluations must be an integer >= population ({n}) or None, got {max_evaluations!r}"
            )
        if max_evaluations < n:
            raise ValueError(
                f"max_evaluations must be an integer >= population ({n}), got {max_evaluations!r}"
            )
        max_evaluations = int(max_evaluations)
    seeds = None
    if initial_population is not None:
        try:
            seeds = np.array(initial_population, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"initial_population must be a real array of shape (k, {dim}) with "
                f"1 <= k <= population ({n}), got {initial_population!r}"
            ) from error
        if seeds.ndim != 2 or seeds.shape[1] != dim or not 1 <= seeds.shape[0] <= n:
            raise ValueError(
                f"initial_population must have shape (k, {dim}) with 1 <= k <= population "
                f"({n}), got shape {seeds.shape}"
            )
        if not np.all(np.isfinite(seeds)):
            raise ValueError("initial_population must be finite (no NaN or inf)")
    if isinstance(seed, bool):
        raise ValueError(f"seed must be an int, a numpy.random.Generator or None, got {seed!r}")
    try:
        rng = np.random.default_rng(seed)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"seed must be an int >= 0, a numpy.random.Generator or None, got {seed!r}"
        ) from error
    if time_limit is not None:
        time_limit = positive_float("time_limit", time_limit)
    algorithm = cls(lo, up, n, T, options)
    return algorithm.run(fun, rng, seeds, max_evaluations, time_limit)
