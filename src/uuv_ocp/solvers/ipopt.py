"""IPOPT backend: the multiple-shooting NLP of :mod:`uuv_ocp.solvers.nlp` solved by ``ipopt``."""

from __future__ import annotations

from typing import Any

from uuv_ocp.solvers.nlp import NlpSolver
from uuv_ocp.transcription.multiple_shooting import NlpData


class IpoptSolver(NlpSolver):
    """Interior-point IPOPT (MUMPS), warm-started with primal and dual shifts."""

    name = "ipopt"
    plugin = "ipopt"

    def plugin_defaults(self, data: NlpData) -> dict[str, Any]:
        """IPOPT with MUMPS, tolerance 1e-8 and warm starts of primal and dual variables.

        With a ``deadline``, IPOPT's own ``max_wall_time`` and ``max_cpu_time`` are set to it
        too (per attempt; the iteration callback enforces what is left of it across attempts).
        """
        limits: dict[str, float] = {}
        if self.deadline is not None:
            limits = {"ipopt.max_wall_time": self.deadline, "ipopt.max_cpu_time": self.deadline}
        return {
            **limits,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.tol": 1e-8,
            "ipopt.max_iter": self.max_iter or 200,
            "ipopt.warm_start_init_point": "yes",
            "ipopt.warm_start_bound_push": 1e-8,
            "ipopt.warm_start_mult_bound_push": 1e-8,
            "ipopt.mu_init": 1e-3,
            "ipopt.linear_solver": "mumps",
        }
