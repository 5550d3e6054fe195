"""IPOPT backend: the multiple-shooting NLP of :mod:`uuv_ocp.solvers.nlp` solved by ``ipopt``."""

from __future__ import annotations

from typing import Any

from uuv_ocp.solvers.nlp import NLP_OPTIONS, NlpSolver
from uuv_ocp.solvers.options import Option, option_names, revise
from uuv_ocp.transcription.multiple_shooting import NlpData

IPOPT_MAX_ITER = 200
"""IPOPT's iteration limit when ``max_iter`` is ``None``."""

IPOPT_OPTIONS: tuple[Option, ...] = revise(
    NLP_OPTIONS, max_iter={"meaning": f"{IPOPT_MAX_ITER} (`ipopt.max_iter`)"}
)


class IpoptSolver(NlpSolver):
    """Interior-point IPOPT (MUMPS), warm-started with primal and dual shifts."""

    name = "ipopt"
    plugin = "ipopt"
    OPTIONS = IPOPT_OPTIONS
    option_names = option_names(IPOPT_OPTIONS)

    def plugin_defaults(self, data: NlpData) -> dict[str, Any]:
        """Return :func:`ipopt_options` for this backend's ``max_iter`` and ``deadline``."""
        return ipopt_options(self.max_iter, self.deadline)


def ipopt_options(max_iter: int | None, deadline: float | None) -> dict[str, Any]:
    """IPOPT with MUMPS, tolerance 1e-8 and warm starts of primal and dual variables.

    With a ``deadline``, IPOPT's own ``max_wall_time`` and ``max_cpu_time`` are set to it
    too (per attempt; the iteration callback enforces what is left of it across attempts).
    """
    limits: dict[str, float] = {}
    if deadline is not None:
        limits = {"ipopt.max_wall_time": deadline, "ipopt.max_cpu_time": deadline}
    return {
        **limits,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.tol": 1e-8,
        "ipopt.max_iter": max_iter or IPOPT_MAX_ITER,
        "ipopt.warm_start_init_point": "yes",
        "ipopt.warm_start_bound_push": 1e-8,
        "ipopt.warm_start_mult_bound_push": 1e-8,
        "ipopt.mu_init": 1e-3,
        "ipopt.linear_solver": "mumps",
    }
