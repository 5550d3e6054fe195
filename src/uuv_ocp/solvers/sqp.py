"""SQP backend: the multiple-shooting NLP of :mod:`uuv_ocp.solvers.nlp` solved by ``sqpmethod``.

A Gauss–Newton Hessian keeps every QP convex; the last-resort retry is CasADi's ``blocksqp``.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import os
import sys
import threading
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp.solvers.nlp import NlpOptions, NlpSolver
from uuv_ocp.solvers.options import (
    Option,
    among,
    declaration,
    factors,
    mapping,
    nonnegative_float,
    one_of,
    option,
    option_names,
    optional,
    positive_float,
    positive_int,
)
from uuv_ocp.solvers.result import Attempt, Iterate, Stage, Variant
from uuv_ocp.transcription.multiple_shooting import NlpData

_STDOUT_LOCK = threading.Lock()


@contextlib.contextmanager
def _silenced_c_stdout():
    """Discard what C code writes to file descriptor 1 while the context lasts.

    qpOASES prints its licence banner on every solve and has no option to stop it.  No-op
    where the descriptor cannot be swapped.

    Process-wide while it lasts: output of other threads to fd 1 is discarded too.  A lock
    keeps two threads from swapping the descriptor at once.
    """
    with _STDOUT_LOCK:
        try:
            libc = ctypes.CDLL(None)
            sys.stdout.flush()
            libc.fflush(None)  # what C buffered before belongs to the real stdout
            saved = os.dup(1)
        except (OSError, AttributeError, ValueError, TypeError):
            yield
            return
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 1)
            yield
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
            os.close(devnull)


HESSIANS = ("gauss-newton", "exact")
SQP_MAX_ITER = 100
"""``sqpmethod``'s iteration limit when ``max_iter`` is ``None``."""
BLOCKSQP_MAX_ITER = 300
"""The ``blocksqp`` last-resort retry's iteration limit when ``max_iter`` is ``None``."""


# Why these defaults: see the comments in SqpSolver and docs/solvers.md (measured)
@dataclasses.dataclass(frozen=True)
class SqpOptions(NlpOptions):
    """Options of :class:`SqpSolver`: those of :class:`NlpOptions` with its defaults, and its own."""

    penalty_escalation: tuple[float, ...] = option(
        (100.0, 1e4),
        "tuple of factors > 0",
        "factors ρ is multiplied by in turn, warm-started, while the soft solve fails",
        check=factors,
    )
    slack_curvature: float = option(
        1e4,
        "float >= 0",
        "μ of an added (μ/2) Σ s² on the terminal slacks (an L1 + L2 exact penalty)",
        check=nonnegative_float,
    )
    max_iter: int | None = option(
        None,
        "int >= 1 or `None`",
        "iteration limit of one attempt of the plugin",
        meaning=f"{SQP_MAX_ITER} (`blocksqp` retry: {BLOCKSQP_MAX_ITER})",
        check=optional(positive_int),
    )
    objective_scale: float = option(
        1e-3,
        "float > 0",
        "factor on the objective the plugin sees (its absolute tolerances against the weights)",
        check=positive_float,
    )
    hessian: str = option(
        "gauss-newton",
        one_of(HESSIANS),
        "Hessian of the QPs: Gauss–Newton 2JᵣᵀJᵣ (PSD by construction) or CasADi's exact one",
        check=among(HESSIANS),
    )
    levenberg_marquardt: float = option(
        1e-7,
        "float >= 0",
        "multiple of the identity added to the Gauss–Newton Hessian (scaled variables)",
        check=nonnegative_float,
    )
    soft_plugin_options: dict = option(
        {"qpsol": "hpipm", "qpsol_options": {"error_on_fail": False}, "max_iter_ls": 15},
        "dict",
        "plugin options of the soft NLP variants only (before `plugin_options`)",
        check=mapping,
    )


SQP_OPTIONS: tuple[Option, ...] = declaration(SqpOptions)


class SqpSolver(NlpSolver):
    """CasADi ``sqpmethod`` with a Gauss–Newton Hessian and the QRQP active-set QP solver.

    Measured on the closed loop from rest (s2, RexROV, N = 20): with the exact Hessian the QP
    subproblems become indefinite while thrust saturates, QRQP returns zero steps
    (``Search_Direction_Becomes_Too_Small``) and ``regularize`` convexification slows
    convergence to a crawl; ``eigen-clip`` crashes CasADi 3.8's stats.  The Gauss–Newton
    Hessian of the least-squares objective is PSD by construction, so every QP is convex.
    The objective is scaled by ``objective_scale = 1e-3`` so that QRQP's absolute tolerances
    match the 1e4 weights.  Options: ``hessian="gauss-newton"`` (default) or ``"exact"``,
    ``levenberg_marquardt`` and ``soft_plugin_options`` (merged into the plugin options of the
    soft variants only; default HPIPM QPs and ``max_iter_ls=15``).  The hard NLP (all that the
    trackable references s1–s7, s10 need after the first second) is unchanged.

    Last resort (``robust_options``, after every other attempt failed): the same NLP variant
    with CasADi's ``blocksqp`` — block-wise BFGS of the Hessian of the Lagrangian, filter line
    search, qpOASES (``schur=False``, ``restore_feas=False``: both otherwise need the HSL MA27
    library, absent from the CasADi wheels), at most ``max_iter`` or 300 iterations.  On the
    untrackable s8 / s9 Gauss–Newton cycles (see below) on 24 / 27 of 300 steps; the retry
    solves every failing step it met (27 / 30 in the 30 s closed loops, 0.6 s median per such
    step, objective within 5e-8 of IPOPT's on the captured steps): zero failures on all ten
    references.  Exact Hessian + ``regularize`` (max 300 iterations), Levenberg–Marquardt
    1e-2 / 1 and ``feasiblesqpmethod`` solved none of the 24 captured steps.
    """

    name = "sqp"
    plugin = "sqpmethod"
    # On references the vehicle cannot follow (s8, s9) the soft problem is solved at every
    # step; a small ρ lets sqpmethod cycle between two points (failed line searches), a large
    # one from the start costs failures on the trackable references.  So ρ = 1e4 first,
    # escalated only on failure.  Soft variants only (docs/solvers.md, the SQP table):
    # QRQP declares "Converged" on degenerate soft QPs with |pr| > 1 (steps outside the
    # thrust bounds), so the soft QPs go to HPIPM; a longer line search, ρ escalated ×100
    # then ×1e4, and (μ/2) Σ s² with μ = 1e4 on the slacks halve the failures there.
    # The rest is genuine SQP cycling: the Gauss–Newton Hessian omits the dynamics' curvature
    # weighted by multipliers of size ρ, which dominates once the terminal penalty is active.
    # (defaults in SQP_OPTIONS: penalty_escalation (100, 1e4), slack_curvature 1e4,
    # soft_plugin_options with HPIPM and max_iter_ls 15)
    Options = SqpOptions
    OPTIONS = SQP_OPTIONS
    option_names = option_names(SQP_OPTIONS)
    hessian: str  # these three are set from SqpOptions
    soft_plugin_options: dict[str, Any]

    def plugin_defaults(self, data: NlpData) -> dict[str, Any]:
        """``sqpmethod`` on QRQP with the Gauss–Newton Hessian; the soft variants' own options."""
        defaults: dict[str, Any] = {
            "qpsol": "qrqp",
            # QRQP's own default (1000 active-set iterations) let an infeasible QP from rest
            # take seconds; 100 bounds the worst step (docs/solvers.md, the SQP table)
            "qpsol_options": {
                "print_iter": False,
                "print_header": False,
                "error_on_fail": False,
                "max_iter": 100,
            },
            "max_iter": self.max_iter or SQP_MAX_ITER,
            "tol_pr": 1e-8,
            "tol_du": 1e-6,
            "print_header": False,
            "print_iteration": False,
            "print_status": False,
        }
        if self.hessian == "gauss-newton":
            defaults["hess_lag"] = self.gauss_newton_hessian(data)
        if data.terminal_slack_index.size:  # the soft variants
            defaults.update(self.soft_plugin_options)
        return defaults

    def robust_options(self) -> dict[str, Any]:
        """``blocksqp`` with BFGS updates and no MA27 (``{}`` where CasADi lacks the plugin)."""
        # blockSQP (still an SQP method): block-wise BFGS updates of the Hessian of the
        # Lagrangian, so it learns the dynamics' curvature that Gauss–Newton omits, with a
        # filter line search and qpOASES (full-space, ``schur=False``: the Schur-complement
        # variant needs the MA27 linear solver, absent from the CasADi wheels).
        if not ca.has_nlpsol("blocksqp"):
            return {}
        return {
            "plugin": "blocksqp",
            "hess_update": 2,  # BFGS (SR1, its default, requires the Schur variant)
            "schur": False,
            # its feasibility restoration builds an inner blockSQP on MA27 as well: without it
            # a failed line search is a failure, not a missing-library exception (cold starts)
            "restore_feas": False,
            "max_iter": self.max_iter or BLOCKSQP_MAX_ITER,
            "print_header": False,
            "print_iteration": False,
            "print_maxit_reached": False,
        }

    def _attempt(
        self, variant: Variant, p: np.ndarray, warm_start: Iterate | None, stage: Stage = Stage.PLAIN
    ) -> Attempt:
        if stage is not Stage.ROBUST:
            return super()._attempt(variant, p, warm_start, stage)
        with _silenced_c_stdout():  # qpOASES' licence banner, printed on every blockSQP solve
            return super()._attempt(variant, p, warm_start, stage)
