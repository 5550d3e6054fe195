"""Fatrop backend: the multiple-shooting NLP of :mod:`uuv_ocp.solvers.nlp` solved by ``fatrop``."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from uuv_ocp.judge import FEASIBILITY_TOLERANCE
from uuv_ocp.solvers import watchdog
from uuv_ocp.solvers.ipopt import IPOPT_MAX_ITER, ipopt_options
from uuv_ocp.solvers.nlp import NlpOptions, NlpSolver
from uuv_ocp.solvers.options import (
    Option,
    declaration,
    mapping,
    option,
    option_names,
    optional,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Attempt
from uuv_ocp.transcription.multiple_shooting import NlpData

FATROP_MAX_ITER = 200
"""Fatrop's iteration limit when ``max_iter`` is ``None``."""

FATROP_STALL_TIME = 10.0
"""Default ``stall_time`` (s): a fatrop iteration takes milliseconds on these NLPs."""


@dataclasses.dataclass(frozen=True)
class FatropOptions(NlpOptions):
    """Options of :class:`FatropSolver`: those of :class:`NlpOptions` and ``stall_time``."""

    max_iter: int | None = option(
        None,
        "int >= 1 or `None`",
        "iteration limit of one attempt of the plugin",
        meaning=f"{FATROP_MAX_ITER} (`fatrop.max_iter`, and the watchdog's limit on all "
        f"iterations, restoration included; its IPOPT rescue: {IPOPT_MAX_ITER})",
        check=optional(positive_int),
    )
    plugin_options: dict = option(
        {},
        "dict",
        "merged into the CasADi `nlpsol` options of every fatrop attempt (robust retry too)",
        check=mapping,
    )
    stall_time: float | None = option(
        FATROP_STALL_TIME,
        "float > 0 or `None`",
        "longest wait for one fatrop iteration before the watchdog stops the attempt as stalled",
        unit="s",
        meaning="no limit",
        check=optional(positive_float),
    )


FATROP_OPTIONS: tuple[Option, ...] = declaration(FatropOptions)


class FatropSolver(NlpSolver):
    """Fatrop: interior point with a Riccati-based linear solver exploiting the OCP structure.

    ``mu_init = 1e-4``: a warm-started NMPC step starts close to the solution, and the smaller
    initial barrier saves one of the six median iterations (s2 closed loop, measured); the two
    steps of that loop it does not solve (the cold start from rest, one saturated step) are
    solved by the last-resort retry with fatrop's conservative ``mu_init = 1e-3``.

    Watchdog: CasADi 3.8's fatrop interface has no time limit among its options and calls no
    iteration callback, and fatrop can loop for good inside one iteration (BlueROV2 Heavy with
    8 thrusters holding station in a 1.5 m/s current: the restoration phase's search direction
    never returned; ``max_iter`` is checked only between iterations).  So every fatrop attempt
    runs in the worker process of :mod:`~uuv_ocp.solvers.watchdog`, which reads fatrop's own
    iteration lines (``print_level`` 5) and kills the attempt at the ``deadline``, past
    ``max_iter`` iterations counting the restoration phase's, or after ``stall_time`` seconds
    without an iteration; the fallback chain then goes on (robust retry, IPOPT rescue).
    """

    name = "fatrop"
    plugin = "fatrop"
    Options = FatropOptions
    OPTIONS = FATROP_OPTIONS
    option_names = option_names(FATROP_OPTIONS)
    stall_time: float | None  # set from FatropOptions

    def watched(self, plugin: str) -> bool:
        """Fatrop always runs in the watchdog's worker (it can loop for good; see module doc)."""
        return watchdog.CAN_WATCH and (plugin == "fatrop" or super().watched(plugin))

    def progress_lines(self, plugin: str) -> dict[str, Any]:
        """Return ``fatrop.print_level = 5``, the lowest that prints one line per iteration.

        Restoration iterations are numbered on and marked ``r``.
        """
        return {"fatrop.print_level": 5} if plugin == "fatrop" else {}

    def stall_limit(self, plugin: str) -> float | None:
        """Return the ``stall_time`` option for fatrop's attempts."""
        return self.stall_time if plugin == "fatrop" else None

    def iteration_limit(self, plugin: str) -> int | None:
        """``max_iter`` (or 200) counting restoration iterations, which fatrop's own limit does not."""
        # fatrop's own stop at max_iter prints one more line (its final iterate, numbered max_iter + 1)
        return (self.max_iter or FATROP_MAX_ITER) + 1 if plugin == "fatrop" else None

    def plugin_defaults(self, data: NlpData) -> dict[str, Any]:
        """Fatrop on the detected stage structure, tolerance 1e-8, ``mu_init = 1e-4``."""
        return {
            "structure_detection": "auto",
            "equality": data.equality,
            "expand": True,
            "fatrop.print_level": 0,
            "fatrop.tol": 1e-8,
            "fatrop.max_iter": self.max_iter or FATROP_MAX_ITER,
            "fatrop.mu_init": 1e-4,
        }

    def robust_options(self) -> dict[str, Any]:
        """Fatrop's conservative initial barrier, ``mu_init = 1e-3``."""
        return {"fatrop.mu_init": 1e-3}

    def stalled(self, attempt: Attempt, p: np.ndarray) -> bool:
        """At fatrop's iteration limit with a plan the judge finds feasible (``FEASIBILITY_TOLERANCE``).

        That is the inertia-correction stall described in :meth:`rescue_options`: the robust
        retry (another ``mu_init``) stalled the same way there, 201 more iterations per step
        (docs/benchmarks.md, the BlueROV2 obstacle course), so the rescue runs at once.
        """
        limit = self.max_iter or FATROP_MAX_ITER
        if attempt.success or attempt.iterations < limit:
            return False
        return self._judged(attempt, p)[2] <= FEASIBILITY_TOLERANCE

    def rescue_options(self) -> dict[str, Any]:
        """IPOPT (this package's settings) from fatrop's last iterate, duals included.

        On non-convex path constraints (circular obstacles) fatrop reaches the optimum but its
        inertia correction keeps a large Hessian regularisation (~1e2), so the dual
        infeasibility stalls near 4e-4 and it stops at ``max_iter`` (measured: RexROV course of
        ``examples/obstacles.py``, cost equal to IPOPT's to 3e-9); IPOPT warm-started there
        converges in a few iterations.
        """
        return {"plugin": "ipopt", **ipopt_options(self.max_iter, self.deadline)}
