"""IPOPT backend: the multiple-shooting NLP of :mod:`uuv_ocp.solvers.nlp` solved by ``ipopt``."""

from __future__ import annotations

import dataclasses
from typing import Any

from uuv_ocp.solvers.nlp import NlpOptions, NlpSolver
from uuv_ocp.solvers.options import Option, declaration, option, option_names, optional, positive_int
from uuv_ocp.transcription.multiple_shooting import NlpData

IPOPT_MAX_ITER = 200
"""IPOPT's iteration limit when ``max_iter`` is ``None``."""


@dataclasses.dataclass(frozen=True)
class IpoptOptions(NlpOptions):
    """Options of :class:`IpoptSolver`: those of :class:`NlpOptions`, ``max_iter`` defaulting to IPOPT's."""

    max_iter: int | None = option(
        None,
        "int >= 1 or `None`",
        "iteration limit of one attempt of the plugin",
        meaning=f"{IPOPT_MAX_ITER} (`ipopt.max_iter`)",
        check=optional(positive_int),
    )


IPOPT_OPTIONS: tuple[Option, ...] = declaration(IpoptOptions)


class IpoptSolver(NlpSolver):
    """Interior-point IPOPT (MUMPS), warm-started with primal and dual shifts."""

    name = "ipopt"
    plugin = "ipopt"
    Options = IpoptOptions
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
