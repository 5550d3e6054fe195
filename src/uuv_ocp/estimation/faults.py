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
the steps where it is still commanded, downwards always and upwards only when the loss is
significant, and holds otherwise (an unused thruster's loss is not observable, and the ridge
would pull it back to healthy).  Stuck thrusters (an offset ``s``) are not modelled by the
regression.  The defaults were tuned on 40 seeded closed loops of the BlueROV2 Heavy survey
(EKF ``bias_std = 5``, sqp-rti N = 10, 0.3 m/s current, fault at 5..7 s): every failure and
50 % loss isolated, median delay 1.5 s, one false alarm in 40 runs (20 of them fault-free).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from uuv_ocp import _validation as check

ISOLATIONS = ("single", "joint")


@dataclass(frozen=True)
class FaultDetectorOptions:
    """Tuning of :class:`ThrusterFaultDetector` (module doc: the test).

    Parameters
    ----------
    window : int
        Steps of the regression window (>= 2).  Default 20 (2 s at dt = 0.1 s).
    threshold : float
        Loss estimate ``ℓ_i = 1 − h_i`` a detection needs, in (0, 1].  Default 0.3.
    significance : float
        Residual-normalised statistic ``ℓ_i / se_i`` a detection needs, > 0.  Default 6.
    hold : int
        Consecutive steps the same thruster must pass both tests (>= 1).  Default 10.
    arm_time : float
        Time after the detector's first update before it may declare a detection (s), >= 0:
        the estimator's current and bias settle meanwhile.  Default 5.
    min_force : float
        Window RMS command (N) a thruster needs for its loss to be tested or followed, > 0.
        Default 3.
    ridge : float
        Ridge on the losses (N), >= 0 (:func:`loss_regression`): windows that excite a thruster
        little (near-constant commands) leave its loss near 0 instead of an ill-conditioned
        value.  Default 10.
    intercept : bool
        Fit a constant generalised force per window beside the losses (:func:`loss_regression`):
        a slowly varying disturbance the bias also holds is not blamed on a thruster; a loss is
        then seen through the *variation* of its command.  Default True.
    isolation : {"single", "joint"}
        ``"joint"`` (default): all losses in one regression, the largest the candidate;
        ``"single"``: one hypothesis per thruster (its loss alone, beside those already
        isolated), the candidate the one whose fit leaves the least residual — the classic
        single-fault isolation, well conditioned where thrusters share a direction (the four
        vertical ones) but more false alarms on the survey (its statistic is more overconfident).
    normalise : bool
        Scale each generalised axis of ``T`` and ``T b̂`` by the inverse norm of its row of
        ``T`` (unit thruster authority per axis) before the regression.  Default True: roll and
        pitch (≈ 0.2 N·m per N on the BlueROV2) then weigh as much as heave, and they are what
        tell the four vertical thrusters apart (20/20 isolated against 17/20 on the tuning runs).
    """

    window: int = 20
    threshold: float = 0.3
    significance: float = 6.0
    hold: int = 10
    arm_time: float = 5.0
    min_force: float = 3.0
    ridge: float = 10.0
    intercept: bool = True
    isolation: str = "joint"
    normalise: bool = True

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
        set_field(self, "ridge", check.nonnegative_float("ridge", self.ridge))
        check.boolean("intercept", self.intercept)
        check.choice("isolation", self.isolation, ISOLATIONS)
        check.boolean("normalise", self.normalise)


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


def loss_regression(
    allocation: np.ndarray,
    forces: np.ndarray,
    bias: np.ndarray,
    *,
    ridge: float = 0.0,
    intercept: bool = False,
    columns: Sequence[int] | None = None,
) -> LossFit:
    """Least-squares thruster losses of one window (module doc).

    Solves ``min ‖y − X ℓ − 1 ⊗ c‖² + ridge² ‖ℓ‖²`` by ``numpy.linalg.lstsq`` on the stacked
    system (the ridge rows ``ridge · I`` pull an unexcited loss to 0, i.e. healthy; ``c`` is the
    window's constant generalised force, only with ``intercept``).

    Parameters
    ----------
    allocation : numpy.ndarray, shape (6, n)
        Healthy allocation matrix ``T``.
    forces : numpy.ndarray, shape (W, n)
        Commanded thruster forces (N), row ``k`` the command the bias of row ``k`` followed.
    bias : numpy.ndarray, shape (W, 6)
        Estimated generalised-force bias ``T b̂`` (N, N·m).
    ridge : float
        Ridge on the losses (N: a column of that norm counts as much as the prior ℓ = 0), >= 0.
    intercept : bool
        Also fit a constant generalised force over the window (a disturbance the commands do not
        scale: a current the estimator has not yet settled, a heave offset).
    columns : sequence of int, optional
        Fit only these thrusters' losses (a fault hypothesis); the others are held at 0 (their
        loss 0, standard error ``inf`` in the result).  Default: all.
    """
    full = loss_regressors(allocation, forces)
    count = full.shape[1]
    keep = list(range(count)) if columns is None else sorted({int(i) for i in columns})
    X = full[:, keep]
    n = X.shape[1]
    y = np.asarray(bias, dtype=float).ravel()
    design = np.hstack([X, np.tile(np.eye(6), (X.shape[0] // 6, 1))]) if intercept else X
    extra = design.shape[1] - n
    stacked = np.vstack([design, np.hstack([ridge * np.eye(n), np.zeros((n, extra))])]) if ridge else design
    target = np.concatenate([y, np.zeros(n)]) if ridge else y
    solution, _, rank, _ = np.linalg.lstsq(stacked, target, rcond=None)
    loss = solution[:n]
    residual = y - design @ solution
    dof = max(1, y.size - int(rank))
    residual_std = float(np.sqrt(residual @ residual / dof))
    variance = np.diag(np.linalg.pinv(stacked.T @ stacked))[:n]
    # a thruster the window never commands has a zero column: no information, not certainty
    excited = np.linalg.norm(X, axis=0) > 0.0
    standard_error = np.where(excited, residual_std * np.sqrt(np.maximum(variance, 0.0)), np.inf)
    standard_error = np.where(standard_error > 0.0, standard_error, np.finfo(float).tiny)
    losses, errors = np.zeros(count), np.full(count, np.inf)
    losses[keep], errors[keep] = loss, standard_error
    return LossFit(losses, errors, residual_std, int(rank))


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
        # each generalised axis scaled to unit thruster authority: roll and pitch (≈ 0.2 N·m per
        # N) otherwise weigh little beside heave, and they are what tell vertical thrusters apart
        norms = np.linalg.norm(matrix, axis=1)
        unit = 1.0 / np.where(norms > 0.0, norms, 1.0)
        self._weights = unit if options.normalise else np.ones(6)
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

    def _fits(self, F: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Loss (unclipped), statistic and hypothesis residual of every thruster on this window."""
        options = self.options
        fit = partial(
            loss_regression,
            self.allocation * self._weights[:, None],
            F,
            G * self._weights,
            ridge=options.ridge,
            intercept=options.intercept,
        )
        if options.isolation == "joint":
            joint = fit()
            return joint.loss, joint.statistic, np.full(self.count, joint.residual_std)
        loss, statistic, residual = np.zeros(self.count), np.zeros(self.count), np.zeros(self.count)
        isolated = list(self.isolated)
        for i in range(self.count):  # hypothesis i: thruster i faulty beside those isolated
            hypothesis = fit(columns=isolated if i in isolated else [*isolated, i])
            loss[i], statistic[i] = hypothesis.loss[i], hypothesis.statistic[i]
            residual[i] = hypothesis.residual_std
        return loss, statistic, residual

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
        F, G = np.array(self._forces), np.array(self._bias)
        commanded = np.sqrt(np.mean(F**2, axis=0)) >= options.min_force
        raw, statistic, residual = self._fits(F, G)
        loss = np.clip(raw, 0.0, 1.0)
        self.estimate = 1.0 - loss
        significant = statistic >= options.significance
        for i in self.isolated:  # the told health follows the estimate while it is observable:
            # lower on any commanded window, higher only on a significant loss (a thruster the
            # controller stops using gives windows the ridge pulls to "healthy")
            if commanded[i] and (significant[i] or self.estimate[i] < self.health[i]):
                self.health[i] = self.estimate[i]
        if time - self._start < options.arm_time - 1e-9:
            return None
        open_ = commanded.copy()
        open_[list(self.isolated)] = False
        if not open_.any():
            self._streak = 0
            return None
        if options.isolation == "single":
            candidate = int(np.argmin(np.where(open_, residual, np.inf)))
        else:
            # ranked unclipped: two losses clipped at 1 would tie and the candidate flip
            candidate = int(np.argmax(np.where(open_, raw, -np.inf)))
        passed = loss[candidate] >= options.threshold and statistic[candidate] >= options.significance
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
