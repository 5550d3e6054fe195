"""Persistent excitation in the thrust allocation's null space (issue 27, fault detection).

A thruster held at a constant command (often saturated at its bound) after a 50 % loss leaves a
*constant* force deficit, which the fault detector's per-window intercept cannot tell from a
change of the current (:mod:`uuv_ocp.estimation.faults`): the loss is unobservable until the
command varies.  The allocation matrix ``T`` (6 × n) of a vehicle with more thrusters than
axes has a null space: commands ``d`` with ``T d = 0`` move every thruster but produce no net
wrench while the thrusters are healthy.  Added to the applied commands, such a dither ``d(t)``
makes a loss show as a wrench residual ``−ℓ_i T_i d_i(t)`` that varies within one window.

The dither is ``d_k = s_k a N z(t_k)``: ``N`` an orthonormal basis of the null space of the
*health-weighted* matrix ``T diag(h)`` (h: the health the controller is told; a thruster with
``h_i = 0`` gets no dither, so ``T diag(h) d = 0`` still holds after a reallocation), ``a`` the
amplitude (N), ``z_j(t) = sin(2π φ_j (t − t_0))`` one sinusoid per basis vector at the
frequencies ``φ_j`` (Hz; incommensurate so the components do not lock together), and ``s_k ∈
[0, 1]`` the largest scale that keeps the applied command ``u_k + d_k`` within every
thruster's box ``|·| ≤ f_max`` and rate bound ``|· − a_{k−1}| ≤ ṙ dt`` around the last applied
command ``a_{k−1}``.  The *whole* vector is scaled (never clipped per thruster): a clipped
dither would leave the null space and push the vehicle.  ``s = 0`` is always admissible when
the plan ``u_k`` is (the NMPC projects its control on the box and on the rate bound around the
last applied command), so the bounds hold by construction.

The basis is made canonical (independent of the SVD's arbitrary rotation): the null-space
projector ``P = N Nᵀ`` is unique, and its columns are orthonormalised in a fixed greedy order
(the largest remaining column first, lowest index on ties).  For the BlueROV2 Heavy this gives
the two physical modes: the four horizontal thrusters pushing equally "inwards", and the four
vertical ones likewise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uuv_ocp import _validation as check

#: Singular values below this fraction of the largest count as zero (the null space's rank).
RANK_TOLERANCE = 1e-10
#: Basis entries below this magnitude are rounding, set to exactly zero.
NEGLIGIBLE = 1e-12


@dataclass(frozen=True)
class DitherOptions:
    """The null-space dither of the fault-tolerant NMPC (module doc).

    Parameters
    ----------
    amplitude : float
        Amplitude ``a`` of each sinusoid along its unit null-space vector (N), >= 0; 0 (the
        default) is no dither at all: the loop runs exactly as without it.
    frequencies : tuple of float
        Frequency of the sinusoid along each null-space basis vector (Hz), each > 0; a null
        space of more dimensions than frequencies uses only the first ``len(frequencies)``
        vectors.  Default (0.3, 0.3 √2): slow enough for the estimator's random-walk bias to
        follow, fast enough to vary within the detector's 2-s window.
    """

    amplitude: float = 0.0
    frequencies: tuple[float, ...] = (0.3, 0.3 * float(np.sqrt(2.0)))

    def __post_init__(self) -> None:
        """Check every field (``ValueError`` names it)."""
        set_field = object.__setattr__
        set_field(self, "amplitude", check.nonnegative_float("amplitude", self.amplitude))
        frequencies = self.frequencies
        if not isinstance(frequencies, Sequence) or isinstance(frequencies, str) or not frequencies:
            raise ValueError(
                f"frequencies must be a non-empty tuple of frequencies (Hz), got {frequencies!r}"
            )
        set_field(
            self,
            "frequencies",
            tuple(check.positive_float(f"frequencies[{i}]", item) for i, item in enumerate(frequencies)),
        )

    @property
    def active(self) -> bool:
        """Whether there is a dither (``amplitude > 0``)."""
        return self.amplitude > 0.0


def null_space_basis(allocation: object, health: object = None) -> np.ndarray:
    """Return a canonical orthonormal basis of the null space of ``T diag(h)`` over working thrusters.

    Parameters
    ----------
    allocation : array_like, shape (6, n)
        Allocation matrix ``T`` (N, N·m per N of thrust).
    health : array_like, shape (n,), optional
        Effectiveness ``h`` in [0, 1] (default: all 1).  Thrusters with ``h_i = 0`` get zero
        rows (no dither on a dead or stuck thruster: it would not move it).

    Returns
    -------
    numpy.ndarray, shape (n, r)
        Orthonormal columns ``N`` with ``T diag(h) N = 0`` (``r`` may be 0).  Canonical: the
        columns are the null-space projector's columns orthonormalised greedily (module doc),
        so the basis does not depend on the SVD's rotation.
    """
    matrix = np.asarray(allocation, dtype=float)
    count = matrix.shape[1]
    h = np.ones(count) if health is None else np.asarray(health, dtype=float).reshape(count)
    alive = np.flatnonzero(h > 0.0)
    basis = np.zeros((count, 0))
    if alive.size == 0:
        return basis
    weighted = matrix[:, alive] * h[alive]
    _, singular, vt = np.linalg.svd(weighted)
    largest = singular[0] if singular.size else 0.0
    rank = int(np.sum(singular > RANK_TOLERANCE * max(largest, np.finfo(float).tiny)))
    null = vt[rank:].T  # (alive, r)
    if null.shape[1] == 0:
        return basis
    projector = null @ null.T
    columns: list[np.ndarray] = []
    remaining = projector.copy()
    for _ in range(null.shape[1]):
        norms = np.linalg.norm(remaining, axis=0)
        pick = int(np.argmax(norms > (1.0 - 1e-9) * norms.max()))  # the first of the largest
        column = remaining[:, pick] / norms[pick]
        columns.append(column)
        remaining = remaining - np.outer(column, column @ remaining)
    full = np.zeros((count, len(columns)))
    # rounding leaves ~1e-17 on thrusters outside a mode; as "dither" it would let a thruster at
    # its bound scale the whole vector to zero, so entries that small are exactly zero
    chosen = np.array(columns).T
    full[alive] = np.where(np.abs(chosen) > NEGLIGIBLE, chosen, 0.0)
    return full


def dither_scale(
    direction: np.ndarray,
    control: np.ndarray,
    previous: np.ndarray,
    bounds: np.ndarray,
    rate_step: np.ndarray,
) -> float:
    """Return the largest ``s ∈ [0, 1]`` keeping ``control + s · direction`` admissible.

    Admissible: ``|control + s d| ≤ bounds`` and ``|control + s d − previous| ≤ rate_step``
    entry by entry (N; ``rate_step`` is the rate bound times dt).  Each entry bounds ``s`` on
    one side; ``s = 0`` is admissible whenever ``control`` is, and where it is not (a plan
    outside its bounds by rounding) the answer is 0.
    """
    d = np.asarray(direction, dtype=float)
    u = np.asarray(control, dtype=float)
    upper = np.minimum(bounds - u, previous + rate_step - u)  # s d_i <= upper_i
    lower = np.maximum(-bounds - u, previous - rate_step - u)  # s d_i >= lower_i
    scale = 1.0
    for d_i, hi, lo in zip(d, upper, lower, strict=True):
        if d_i > 0.0:
            scale = min(scale, hi / d_i)
        elif d_i < 0.0:
            scale = min(scale, lo / d_i)
    return float(min(max(scale, 0.0), 1.0))


class NullSpaceDither:
    """The dither of one run (module doc): :meth:`applied` adds it to each step's command.

    Parameters
    ----------
    allocation : array_like, shape (6, n)
        Healthy allocation matrix ``T``.
    options : DitherOptions
        Amplitude and frequencies.
    bounds : array_like, shape (n,)
        Each thruster's force bound (N).
    rate_bounds : array_like, shape (n,)
        Each thruster's rate bound (N/s).
    dt : float
        Control interval (s).
    t0 : float
        Time of the sinusoids' zero phase (s).
    """

    def __init__(
        self,
        allocation: object,
        options: DitherOptions,
        bounds: object,
        rate_bounds: object,
        dt: float,
        t0: float = 0.0,
    ) -> None:
        self.allocation = np.asarray(allocation, dtype=float)
        count = self.allocation.shape[1]
        self.options = options
        self.bounds = np.array(check.vector("bounds", bounds, count, nonnegative=True))
        self.rate_step = np.array(check.vector("rate_bounds", rate_bounds, count, nonnegative=True)) * dt
        self.t0 = float(t0)
        self._health: tuple[float, ...] | None = None
        self._basis = np.zeros((count, 0))

    def basis(self, health: np.ndarray | None = None) -> np.ndarray:
        """Return the null-space basis for the told health (cached while it does not change)."""
        key = tuple(np.ones(self.allocation.shape[1]) if health is None else np.asarray(health, dtype=float))
        if key != self._health:
            self._health, self._basis = key, null_space_basis(self.allocation, key)
        return self._basis

    def direction(self, time: float, health: np.ndarray | None = None) -> np.ndarray:
        """Return the unscaled dither ``a N z(t)`` (N) at ``time`` (s) for the told health."""
        basis = self.basis(health)
        used = min(basis.shape[1], len(self.options.frequencies))
        phases = 2.0 * np.pi * np.array(self.options.frequencies[:used]) * (time - self.t0)
        return self.options.amplitude * (basis[:, :used] @ np.sin(phases))

    def applied(
        self, time: float, control: np.ndarray, previous: np.ndarray, health: np.ndarray | None = None
    ) -> np.ndarray:
        """Return ``control + s · a N z(t)``: the command the thrusters get (module doc)."""
        direction = self.direction(time, health)
        scale = dither_scale(direction, control, previous, self.bounds, self.rate_step)
        return control + scale * direction
