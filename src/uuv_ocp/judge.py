"""The one judge of every solver: exact objective and largest violation of a control sequence."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from uuv_ocp.native.buffered import BufferedFunction

if TYPE_CHECKING:
    from uuv_ocp.build import Transcribed

FEASIBILITY_TOLERANCE = 1e-6
"""Largest judged violation (:func:`score`: its own units; box and rate: scaled) of a plan that
counts as feasible: a swarm's ``success``, ``compare``'s feasible rows, fatrop's stall test."""


def instance_parameters(
    problem: Transcribed,
    x0: object,
    t0: float = 0.0,
    *,
    u_prev: object | None = None,
    current: object | None = None,
    parameters: Mapping[str, object] | None = None,
) -> np.ndarray:
    """Parameter vector of one instance of any problem (its ``instance_parameters``)."""
    return problem.instance_parameters(x0, t0, u_prev=u_prev, current=current, parameters=parameters)


def score(
    problem: Transcribed,
    controls: object,
    x0: object,
    t0: float = 0.0,
    *,
    u_prev: object | None = None,
    current: object | None = None,
    parameters: Mapping[str, object] | None = None,
) -> tuple[float, float]:
    """Exact objective and largest constraint violation of a control sequence: the one judge.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    controls : array_like, shape (N, nu)
        Physical controls (for the UUV presets N, N, N·m).
    x0, t0, u_prev, current, parameters
        The instance, as in :func:`uuv_ocp.solve`.

    Returns
    -------
    cost : float
        The NLP objective at the rollout of ``controls`` through the prediction model (soft
        constraints included as their exact L1 penalty).
    max_violation : float
        Largest violation among: hard terminal equality residuals (their units), control-box
        and rate-bound excess (scaled: fractions of the box half-width), and every other hard
        constraint (its units).
    """
    p = instance_parameters(problem, x0, t0, u_prev=u_prev, current=current, parameters=parameters)
    return score_parameters(problem, problem.scaled_from_controls(controls), p)


def score_terms(
    problem: Transcribed, scaled: np.ndarray, p: np.ndarray, terms: BufferedFunction | None = None
) -> tuple[float, dict[str, float]]:
    """Objective and the largest violation per kind (``terminal``, ``rate``, ``bound``, ``constraint``)."""
    objective, terminal, rate, bound, other = (terms or problem.buffered("score_terms"))(scaled, p)
    # ndarray methods, not np.max: the same maxima (NaN included) without numpy's dispatch per call
    kinds = {
        "terminal": float(np.abs(terminal).max()),
        "rate": float(rate.max()),
        "bound": float(bound.max()),
        "constraint": float(other.max()),
    }
    return float(objective[0]), kinds


def score_parameters(
    problem: Transcribed,
    scaled: np.ndarray,
    p: np.ndarray,
    terms: BufferedFunction | None = None,
) -> tuple[float, float]:
    """:func:`score` on a flat scaled control vector and a ready parameter vector.

    ``terms`` is a caller of a Function equal to the built ``score_terms`` (e.g. its compiled,
    verified twin); default: the built one on CasADi's virtual machine.
    """
    objective, kinds = score_terms(problem, scaled, p, terms)
    return objective, max(kinds.values())
