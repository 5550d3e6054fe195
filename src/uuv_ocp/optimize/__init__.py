"""General-purpose population optimisers (IGWO, GWO, SSA, PSO, MPPI) behind one ``minimize``.

Modules: :mod:`~uuv_ocp.optimize.loop` (the shared loop, :class:`MinimizeResult`, box checks),
:mod:`~uuv_ocp.optimize.schedules` (``a(t)``, ``w(t)``), one module per algorithm
(:mod:`~uuv_ocp.optimize.gwo`, :mod:`~uuv_ocp.optimize.igwo`, :mod:`~uuv_ocp.optimize.ssa`,
:mod:`~uuv_ocp.optimize.pso`, :mod:`~uuv_ocp.optimize.mppi`), and
:mod:`~uuv_ocp.optimize.minimize` (the registry and the front door).  Test functions live in
:mod:`~uuv_ocp.optimize.benchmark_functions`.

Note that the name ``minimize`` in this package is the function, which shadows the submodule of
the same name as an attribute; import from the submodule with
``from uuv_ocp.optimize.minimize import ...``.
"""

from uuv_ocp.optimize.gwo import GreyWolf, gwo_update
from uuv_ocp.optimize.igwo import ImprovedGreyWolf, igwo_update
from uuv_ocp.optimize.loop import MinimizeResult, PopulationAlgorithm
from uuv_ocp.optimize.minimize import ALGORITHMS, available_methods, minimize, register_algorithm
from uuv_ocp.optimize.mppi import PathIntegral, importance_weights
from uuv_ocp.optimize.pso import ParticleSwarm
from uuv_ocp.optimize.schedules import (
    CONVERGENCE_FACTORS,
    PAPER_CONVERGENCE_LABELS,
    convergence_factor,
    inertia_weight,
)
from uuv_ocp.optimize.ssa import SparrowSearch

__all__ = [
    "ALGORITHMS",
    "register_algorithm",
    "CONVERGENCE_FACTORS",
    "GreyWolf",
    "ImprovedGreyWolf",
    "MinimizeResult",
    "PAPER_CONVERGENCE_LABELS",
    "ParticleSwarm",
    "PathIntegral",
    "PopulationAlgorithm",
    "SparrowSearch",
    "available_methods",
    "convergence_factor",
    "gwo_update",
    "igwo_update",
    "importance_weights",
    "inertia_weight",
    "minimize",
]
