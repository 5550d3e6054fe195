"""Improved grey wolf optimiser of the paper (``igwo``): :func:`igwo_update` and :class:`ImprovedGreyWolf`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from uuv_ocp._validation import choice
from uuv_ocp.optimize.gwo import GreyWolf, gwo_update
from uuv_ocp.optimize.schedules import inertia_weight

__all__ = ["ImprovedGreyWolf", "igwo_update"]


def igwo_update(
    positions: np.ndarray,
    pbest: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    delta: np.ndarray,
    gbest: np.ndarray,
    a: float,
    w: float,
    draws: np.ndarray,
    c1: float = 0.5,
    c2: float = 0.5,
    anchor: np.ndarray | None = None,
) -> np.ndarray:
    """Memory-guided IGWO position update (paper §3.3.1).

    Element-wise, with ``G = gwo_update(positions, alpha, beta, delta, a, draws)``::

        X(t+1) = w G + c1 r1 (X_pbest - X) + c2 r2 (X_gbest - X)
               = ((w * G) + ((c1 * r1) * (pbest - X))) + ((c2 * r2) * (gbest - X))

    with ``r1 = draws[6]``, ``r2 = draws[7]`` (the right-hand form fixes the evaluation order).
    No clipping here.

    The inertia ``w < 1`` scales positions toward the *origin*: if all wolves sat on the
    optimum ``x*`` the update would return ``w x*``, so the paper's rule only settles on optima
    at 0 (fine for scaled controls near zero, poor for shifted optima); GWO's ``|C L - X|`` is
    origin-dependent too.  ``anchor`` (not in the paper; ``None`` = paper) evaluates the whole
    update in coordinates centred on ``anchor``: every position argument minus ``anchor``, the
    result plus ``anchor`` (see the ``frame`` option of :class:`ImprovedGreyWolf`).

    Parameters
    ----------
    positions : numpy.ndarray, shape (n, d)
        Current positions ``X``.
    pbest : numpy.ndarray, shape (n, d)
        Personal best position of every wolf.
    alpha, beta, delta : numpy.ndarray, shape (d,)
        The three leaders.
    gbest : numpy.ndarray, shape (d,)
        Global best position so far.
    a, w : float
        Convergence factor ``a(t)`` and inertia weight ``w(t)``.
    draws : numpy.ndarray, shape (8, n, d)
        Uniform numbers in ``[0, 1)``; layout in :mod:`uuv_ocp.optimize.loop`.
    c1, c2 : float
        Individual and global learning factors (paper: 0.5 and 0.5).
    anchor : numpy.ndarray, shape (d,), optional
        Origin of the coordinates the update is computed in; ``None`` (the paper) is 0.

    Returns
    -------
    numpy.ndarray, shape (n, d)
        Unclipped new positions.
    """
    if anchor is not None:
        x, p, l1, l2, l3, g = (v - anchor for v in (positions, pbest, alpha, beta, delta, gbest))
        return anchor + igwo_update(x, p, l1, l2, l3, g, a, w, draws, c1, c2)
    grey = gwo_update(positions, alpha, beta, delta, a, draws)
    return (w * grey + (c1 * draws[6]) * (pbest - positions)) + (c2 * draws[7]) * (gbest - positions)


class ImprovedGreyWolf(GreyWolf):
    """IGWO of the paper (§3.3.1): cosine convergence factor plus a memory-guided update.

    Reading of the garbled text (the equations around the paper's Eqs. 12-18; the extracted PDF
    lost the operators, e.g. ``a = 1 2 a i n i t i a l a f i n a l + c o s π × t M a x i t e r``):

    * convergence factor: ``a(t) = a_final + ½ (a_initial - a_final)(1 + cos(π t/T))`` with
      ``a_initial = 2``, ``a_final = 0`` (so ``a(0) = 2``, ``a(T/2) = 1``, ``a(T) = 0``;
      the surviving tokens "½ ... a_initial a_final + cos(π t / Maxiter)" only make sense with
      ``a_final`` added outside, which reduces to ``1 + cos(π t/T)`` for the paper's values);
    * ``X1, X2, X3`` the usual GWO moves toward α, β, δ (paper's GWO equations);
    * memory update ``X(t+1) = w (X1 + X2 + X3)/3 + c1 r1 (X_pbest - X) + c2 r2 (X_gbest - X)``
      with ``c1 = c2 = 0.5`` and ``r1, r2 ~ U[0, 1]`` drawn per element;
    * inertia ``w(t) = (T - t)/T · (w_initial - w_final) + w_final``, ``w: 0.9 -> 0.1``.

    ``t`` runs over ``0 .. T-1`` for the ``T`` updates.  ``X_pbest`` is each wolf's best
    position so far (kept per wolf), ``X_gbest`` the best point found so far (= α).  Leaders as
    in :class:`GreyWolf`.  The update is the pure function :func:`igwo_update`.

    Options: ``a_initial`` (2), ``a_final`` (0), ``convergence`` (``"cosine"``),
    ``w_initial`` (0.9), ``w_final`` (0.1), ``c1`` (0.5), ``c2`` (0.5), ``frame``
    (``"origin"`` = paper; ``"alpha"`` computes each update in coordinates centred on the
    current α wolf -- an extension, not in the paper, that removes the paper rule's pull toward
    0, see :func:`igwo_update`).
    """

    name = "igwo"
    default_population = 20
    default_iterations = 30
    default_options: ClassVar[Mapping[str, Any]] = {
        "a_initial": 2.0,
        "a_final": 0.0,
        "convergence": "cosine",
        "w_initial": 0.9,
        "w_final": 0.1,
        "c1": 0.5,
        "c2": 0.5,
        "frame": "origin",
    }
    n_draws: ClassVar[int] = 8

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        choice("options['frame']", self.options["frame"], ["alpha", "origin"])

    def _w(self, t: int) -> float:
        return inertia_weight(t, self.iterations, self.options["w_initial"], self.options["w_final"])

    def initialize(self, positions: np.ndarray, costs: np.ndarray, rng: np.random.Generator) -> None:
        """Set the leaders and every wolf's personal best from the initial population."""
        super().initialize(positions, costs, rng)
        self.pbest = positions.copy()
        self.pbest_costs = costs.copy()

    def propose(self, iteration: int, rng: np.random.Generator) -> np.ndarray:
        """Memory-guided move of every wolf (:func:`igwo_update`, draws of the iteration)."""
        draws = self._draws(rng)
        alpha, beta, delta = self.leaders
        return igwo_update(
            self.positions,
            self.pbest,
            alpha,
            beta,
            delta,
            alpha,
            self._a(iteration),
            self._w(iteration),
            draws,
            self.options["c1"],
            self.options["c2"],
            alpha if self.options["frame"] == "alpha" else None,
        )

    def accept(self, positions: np.ndarray, costs: np.ndarray) -> None:
        """Update the leaders and the personal bests that improved."""
        super().accept(positions, costs)
        better = costs < self.pbest_costs
        self.pbest[better] = positions[better]
        self.pbest_costs[better] = costs[better]
