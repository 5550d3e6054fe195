"""Parameter schedules of the population optimisers: convergence factor ``a(t)``, inertia ``w(t)``.

Both are functions of the 0-based iteration ``t`` and the iteration budget ``T``; the grey-wolf
optimisers evaluate them at ``t = 0 .. T-1`` (see :mod:`uuv_ocp.optimize.gwo` and
:mod:`uuv_ocp.optimize.igwo`).  The C step of the NMPC is fed the same values, tabulated.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from uuv_ocp._validation import positive_int

__all__ = [
    "CONVERGENCE_FACTORS",
    "PAPER_CONVERGENCE_LABELS",
    "convergence_factor",
    "inertia_weight",
]

# --------------------------------------------------------------------------------------------
# Convergence factor a(t) of the grey-wolf family (paper Figure 5)
# --------------------------------------------------------------------------------------------


def _linear(s: np.ndarray) -> np.ndarray:
    return 1.0 - s


def _cosine(s: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.cos(np.pi * s))


def _faster(s: np.ndarray) -> np.ndarray:
    return 1.0 - s * s


def _slower(s: np.ndarray) -> np.ndarray:
    return (1.0 - s) * (1.0 - s)


#: Normalised decay shapes ``g(s)``, ``s = t/T``, with ``g(0) = 1`` and ``g(1) = 0``; the factor
#: is ``a = a_final + (a_initial - a_final) g(t/T)``.
CONVERGENCE_FACTORS: Mapping[str, Callable[[np.ndarray], np.ndarray]] = {
    "linear": _linear,  # GWO: a = 2 - 2 t/T
    "cosine": _cosine,  # IGWO (paper): a = a_f + (a_i - a_f)(1 + cos(pi t/T))/2
    "faster": _faster,  # decays gradually faster: a = 2 (1 - (t/T)^2)
    "slower": _slower,  # decays gradually slower: a = 2 (1 - t/T)^2
}

#: Curve names used in the paper's Figure 5 for each ``kind``.
PAPER_CONVERGENCE_LABELS: Mapping[str, str] = {
    "linear": "linear_a",
    "faster": "non_linear_a_1",
    "slower": "non_linear_a_2",
    "cosine": "non_linear_a_3",
}


def convergence_factor(
    iteration: float | np.ndarray,
    iterations: int,
    kind: str = "linear",
    *,
    a_initial: float = 2.0,
    a_final: float = 0.0,
) -> float | np.ndarray:
    """Convergence factor ``a(t)`` of the grey-wolf optimisers.

    Parameters
    ----------
    iteration : float or numpy.ndarray
        Current iteration ``t`` (0-based); arrays are evaluated element-wise.
    iterations : int
        Iteration budget ``T`` (>= 1).
    kind : {"linear", "cosine", "faster", "slower"}
        ``"linear"``: ``a = a_i - (a_i - a_f) t/T`` (GWO, Mirjalili et al. 2014);
        ``"cosine"``: ``a = a_f + ½ (a_i - a_f)(1 + cos(π t/T))`` (IGWO, the paper's §3.3.1);
        ``"faster"``: ``a = a_f + (a_i - a_f)(1 - (t/T)²)`` (the paper's ``non_linear_a_1``);
        ``"slower"``: ``a = a_f + (a_i - a_f)(1 - t/T)²`` (the paper's ``non_linear_a_2``).
    a_initial, a_final : float
        Values at ``t = 0`` and ``t = T`` (paper: 2 and 0).

    Returns
    -------
    float or numpy.ndarray
        ``a(t)``; a float for scalar ``iteration``.
    """
    iterations = positive_int("iterations", iterations, 1)
    if kind not in CONVERGENCE_FACTORS:
        raise ValueError(f"kind must be one of {sorted(CONVERGENCE_FACTORS)}, got {kind!r}")
    s = np.asarray(iteration, dtype=float) / float(iterations)
    value = a_final + (a_initial - a_final) * CONVERGENCE_FACTORS[kind](s)
    return float(value) if np.ndim(value) == 0 else value


# --------------------------------------------------------------------------------------------
# Inertia weight w(t)
# --------------------------------------------------------------------------------------------


def inertia_weight(iteration: int, iterations: int, w_initial: float = 0.9, w_final: float = 0.1) -> float:
    """Linearly decreasing inertia weight ``w(t) = (T - t)/T · (w_initial - w_final) + w_final``.

    Evaluated in exactly this operation order (``((T - t) / T) * (w_i - w_f) + w_f``), which the
    C port reproduces.  Inputs are not validated (the caller holds a validated budget).

    Parameters
    ----------
    iteration : int
        Current iteration ``t`` (0-based).
    iterations : int
        Iteration budget ``T`` (>= 1).
    w_initial, w_final : float
        Values at ``t = 0`` and ``t = T`` (paper's IGWO: 0.9 and 0.1).

    Returns
    -------
    float
        ``w(t)``.
    """
    return (iterations - iteration) / iterations * (w_initial - w_final) + w_final
