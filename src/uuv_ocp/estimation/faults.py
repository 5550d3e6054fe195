"""Thruster fault detection and isolation from an estimator's control bias (issue 27).

Choice: a residual regression on the estimator's bias, not a health-augmented filter.  The
estimator (:class:`~uuv_ocp.estimation.base.Estimator` with ``EstimatorOptions(bias=True)``)
predicts with healthy thrusters and adds a random-walk bias ``b`` to the commanded thruster
forces ``f``; the plant delivers ``τ = T (h ∘ f)``, so the bias it estimates obeys, in
generalised forces (the part of ``b`` the measurements see: ``T`` has a null space),

    T b̂_k ≈ T ((h − 1) ∘ f_{k−1}) = − Σ_i ℓ_i T_i f_{i,k−1},    ℓ = 1 − h  (the loss),

with ``T_i`` the i-th column of the allocation matrix and ``f_{k−1}`` the commands applied over
the interval before the estimate.  Over a sliding window of ``W`` steps this is a linear
least-squares problem in the eight losses (``6 W`` equations): :func:`loss_regression` solves it
(``numpy.linalg.lstsq``) and gives each loss a residual-normalised statistic
``z_i = ℓ_i / se_i``, ``se_i² = σ̂² [(XᵀX)⁺]_ii``, ``σ̂²`` the residual variance.  Why this rather
than ``h`` in the filter's state: the loss of thruster ``i`` is observable only while it is
commanded (``ℓ_i f_i`` is what acts), a random walk on ``h`` would drift whenever a thruster
idles and make the filter's other states pay for it, and the bias augmentation already exists
and is shared by every estimator (EKF, UKF, MHE).

Decision (:class:`ThrusterFaultDetector`): after ``arm_time`` (the estimator's current and bias
settle), the thruster with the largest loss estimate among those commanded (window RMS force
>= ``min_force``) is the candidate; a detection is declared when the same candidate's loss is
>= ``threshold`` *and* its statistic >= ``significance`` for ``hold`` consecutive steps, and is
isolated to that thruster.  The statistic overstates confidence (the bias estimate is a smooth,
autocorrelated series, so the residuals are not independent): ``significance`` is set high and
the false-alarm rate is *measured* (tests, ``benchmarks/bench_faults.py``) rather than derived.
Once isolated, the thruster's health follows its estimate ``1 − ℓ_i`` (clipped to [0, 1]) on
every step where it is still commanded, and holds otherwise (an unused thruster's loss is not
observable).  Stuck thrusters (an offset ``s``) are not modelled by the regression.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from uuv_ocp import _validation as check


@dataclass(frozen=True)
class FaultDetectorOptions:
    """Tuning of :class:`ThrusterFaultDetector` (module doc: the test).

    Parameters
    ----------
    window : int
        Steps of the regression window (>= 2).  Default 20 (2 s at dt = 0.1 s).
    threshold : float
        Loss estimate ``ℓ_i = 1 − h_i`` a detection needs, in (0, 1].  Default 0.4.
    significance : float
        Residual-normalised statistic ``ℓ_i / se_i`` a detection needs, > 0.  Default 10.
    hold : int
        Consecutive steps the same thruster must pass both tests (>= 1).  Default 5.
    arm_time : float
        Time after the detector's first update before it may declare a detection (s), >= 0:
        the estimator's current and bias settle meanwhile.  Default 5.
    min_force : float
        Window RMS command (N) a thruster needs for its loss to be tested or followed, > 0.
        Default 3.
    """

    window: int = 20
    threshold: float = 0.4
    significance: float = 10.0
    hold: int = 5
    arm_time: float = 5.0
    min_force: float = 3.0

    def __post_init__(self) -> None:
        """Check every field (``ValueError`` names it)."""
        set_field = object.__setattr__
        set_field(self, "window", check.positive_int("window", self.window, minimum=2))
        threshold = check.positive_float("threshold", self.threshold)
        if threshold > 1.0:
            raise ValueError(f"threshold must lie in (0, 1] (a loss), got {threshold!r}")
        set_field(self, "threshold", threshold)
        set_field(self, "significance", check.positive_float("significance", self.significance))
        set_field(self, "hold", check.positive_int("hold", self.hold))
        set_field(self, "arm_time", check.nonnegative_float("arm_time", self.arm_time))
        set_field(self, "min_force", check.positive_float("min_force", self.min_force))


@dataclass(frozen=True)
class LossFit:
    """One window's regression (:func:`loss_regression`).

    Attributes
    ----------
    loss : numpy.ndarray, shape (n,)
        Least-squares loss of each thruster (unbounded; clip to [0, 1] for a health).
    standard_error : numpy.ndarray, shape (n,)
        ``σ̂ sqrt([(XᵀX)⁺]_ii)`` (``inf`` where the window does not excite the thruster).
    residual_std : float
        ``σ̂``: RMS of the residual over the degrees of freedom (N or N·m).
    rank : int
        Rank of the regressor matrix.
    """

    loss: np.ndarray
    standard_error: np.ndarray
    residual_std: float
    rank: int

    @property
    def statistic(self) -> np.ndarray:
        """``loss / standard_error`` per thruster (0 where not excited)."""
        return np.where(np.isfinite(self.standard_error), self.loss / self.standard_error, 0.0)


def loss_regressors(allocation: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """Return the regressor matrix ``X`` (6 W, n): block ``k`` is ``−T diag(f_k)``.

    Parameters
    ----------
    allocation : numpy.ndarray, shape (6, n)
        Healthy allocation matrix ``T`` (N, N·m per N).
    forces : numpy.ndarray, shape (W, n)
        Commanded thruster forces of the window (N).
    """
    allocation, forces = np.asarray(allocation, dtype=float), np.asarray(forces, dtype=float)
    return -(forces[:, None, :] * allocation[None, :, :]).reshape(-1, allocation.shape[1])


def loss_regression(allocation: np.ndarray, forces: np.ndarray, bias: np.ndarray) -> LossFit:
    """Least-squares thruster losses of one window (module doc).

    Parameters
    ----------
    allocation : numpy.ndarray, shape (6, n)
        Healthy allocation matrix ``T``.
    forces : numpy.ndarray, shape (W, n)
        Commanded thruster forces (N), row ``k`` the command the bias of row ``k`` followed.
    bias : numpy.ndarray, shape (W, 6)
        Estimated generalised-force bias ``T b̂`` (N, N·m).
    """
    X = loss_regressors(allocation, forces)
    y = np.asarray(bias, dtype=float).ravel()
    loss, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
    residual = y - X @ loss
    dof = max(1, y.size - int(rank))
    residual_std = float(np.sqrt(residual @ residual / dof))
    gram = np.linalg.pinv(X.T @ X)
    variance = np.diag(gram)
    # a thruster the window never commands has a zero column: no information, not certainty
    excited = np.linalg.norm(X, axis=0) > 0.0
    standard_error = np.where(excited, residual_std * np.sqrt(np.maximum(variance, 0.0)), np.inf)
    standard_error = np.where(standard_error > 0.0, standard_error, np.finfo(float).tiny)
    return LossFit(loss, standard_error, residual_std, int(rank))


@dataclass(frozen=True)
class Detection:
    """A thruster fault declared by :class:`ThrusterFaultDetector`.

    Attributes
    ----------
    time : float
        When it was declared (s, on the run's clock).
    step : int
        Control step of the declaration.
    thruster : int
        Isolated thruster (0-based column of the allocation matrix).
    health : float
        Its estimated effectiveness at the declaration, in [0, 1].
    """

    time: float
    step: int
    thruster: int
    health: float


class ThrusterFaultDetector:
    """Sliding-window loss regression and detection test on an estimator's bias (module doc).

    Mutable, like an estimator: :meth:`reset` starts it, :meth:`update` takes one step.

    Parameters
    ----------
    allocation : array_like, shape (6, n)
        Healthy allocation matrix ``T`` of the thrusters.
    options : FaultDetectorOptions, optional
        Tuning.
    """

    def __init__(self, allocation: object, options: FaultDetectorOptions | None = None) -> None:
        matrix = np.asarray(allocation, dtype=float)
        if matrix.ndim != 2 or matrix.shape[0] != 6 or not np.all(np.isfinite(matrix)):
            raise ValueError(f"allocation must be a finite (6, n) matrix, got shape {matrix.shape}")
        options = FaultDetectorOptions() if options is None else options
        if not isinstance(options, FaultDetectorOptions):
            raise ValueError(
                f"options must be a uuv_ocp.FaultDetectorOptions or None, got {type(options).__name__}"
            )
        self.allocation, self.options = matrix, options
        self.reset()

    @property
    def count(self) -> int:
        """Number of thrusters."""
        return int(self.allocation.shape[1])

    def reset(self) -> None:
        """Forget every window, estimate and detection."""
        window = self.options.window
        self._forces: deque[np.ndarray] = deque(maxlen=window)
        self._bias: deque[np.ndarray] = deque(maxlen=window)
        self._start: float | None = None
        self._candidate, self._streak = -1, 0
        self.health = np.ones(self.count)  # what the controller is told (isolated thrusters only)
        self.estimate = np.full(self.count, np.nan)  # the last window's 1 − clip(ℓ), all thrusters
        self.detections: list[Detection] = []

    @property
    def isolated(self) -> tuple[int, ...]:
        """Thrusters declared faulty so far, in order."""
        return tuple(item.thruster for item in self.detections)

    def update(self, step: int, time: float, forces: object, bias: object) -> Detection | None:
        """Take one step: the commands ``forces`` (N, shape (n,)) and the thruster-space bias.

        ``bias`` is the estimator's control bias (shape (n,), N): the detector regresses ``T b``.
        Returns the detection declared at this step, if any.
        """
        f = np.asarray(forces, dtype=float).reshape(self.count)
        b = np.asarray(bias, dtype=float).reshape(self.count)
        if self._start is None:
            self._start = time
        self._forces.append(f)
        self._bias.append(self.allocation @ b)
        options = self.options
        if len(self._forces) < options.window:
            return None
        F = np.array(self._forces)
        fit = loss_regression(self.allocation, F, np.array(self._bias))
        loss = np.clip(fit.loss, 0.0, 1.0)
        self.estimate = 1.0 - loss
        commanded = np.sqrt(np.mean(F**2, axis=0)) >= options.min_force
        for i in self.isolated:  # the told health follows the estimate while it is observable
            if commanded[i]:
                self.health[i] = self.estimate[i]
        if time - self._start < options.arm_time - 1e-9:
            return None
        open_ = commanded.copy()
        open_[list(self.isolated)] = False
        if not open_.any():
            self._streak = 0
            return None
        candidate = int(np.argmax(np.where(open_, loss, -np.inf)))
        passed = loss[candidate] >= options.threshold and fit.statistic[candidate] >= options.significance
        if not passed:
            self._streak = 0
            return None
        self._streak = self._streak + 1 if candidate == self._candidate else 1
        self._candidate = candidate
        if self._streak < options.hold:
            return None
        self._streak = 0
        self.health[candidate] = self.estimate[candidate]
        detection = Detection(float(time), int(step), candidate, float(self.estimate[candidate]))
        self.detections.append(detection)
        return detection
