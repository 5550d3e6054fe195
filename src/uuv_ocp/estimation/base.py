"""What every estimator shares: the augmented model, options, the estimate record, the registry.

The model is the controller's own discrete step ``x⁺ = F(x, u, p_stage, p_global)``
(``problem.build().step``: RK4 or the collocation step the NMPC predicts with), with the state
augmented by the ocean current ``c`` (the problem's stagewise parameter named
``options.current_parameter``, ``"current"`` for a :class:`~uuv_ocp.TrackingProblem`: inertial,
``layout.current_dim`` entries) and, if ``options.bias``, a bias ``b`` added to the control
(a generalised-force bias when the controls are forces):

    x⁺ = F(x, u + b, p_stage[current := c], p_global) + w_x
    c⁺ = μ + a (c − μ) + w_c,   a = exp(−dt / τ)   (Gauss–Markov; random walk: a = 1)
    b⁺ = b + w_b

with ``w ~ N(0, Q)``, ``Q = diag(σ_x², q_c² dt | q_c² τ/2 (1 − a²), q_b² dt)``: the current's
noise intensity ``q_c`` (m/s/√s) gives the same discrete variance as the continuous process over
one step, and the Gauss–Markov model tends to the random walk as τ → ∞.  The other stagewise
parameters (a reference, moving obstacles) do not enter a vehicle's dynamics and are held at
zero; an :class:`~uuv_ocp.Ocp`'s own parameters are taken from ``parameters=``.  A problem's
``controller_states`` last states (the path parameter of a
:class:`~uuv_ocp.PathFollowingProblem`) are the controller's own: ``x`` excludes them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.build import Transcribed
from uuv_ocp.estimation.sensors import Measurement, Sensors
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.runtime import compiled_by_default

CURRENT_MODELS = ("random_walk", "gauss_markov", "none")
MHE_MODES = ("full", "rti")

SURVEY_CURRENT_STD = (0.01, 0.01, 1e-4)
"""A survey's current noise intensity per inertial axis (north, east, down; m/s/√s): horizontal.

The vertical entry keeps the EKF from turning sensor noise into a vertical current that the depth
loop chases (REMUS survey: stern-plane activity 45° → 14° over 200 s, docs/benchmarks.md)."""
SURVEY_CURRENT_FILTER = 20.0
"""Time constant of the survey's low-pass on the current told to the NMPC (s); see
``EstimatorOptions.current_filter`` (REMUS survey: fins 185° → 155° at 0.135 → 0.176 m cross-track)."""


def _per_state(name: str, value: object, size: int) -> np.ndarray:
    """Return ``size`` positive floats from one float or ``size`` of them."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = (float(value),) * size
    return np.asarray(check.vector(name, value, size, positive=True))


@dataclass(frozen=True)
class EstimatorOptions:
    """Noise model and tuning of an estimator (module doc: the augmented model).

    Parameters
    ----------
    state_std : float or sequence of float
        Process-noise standard deviation per control step on each state (its unit), > 0:
        what the model misses over one step.  Default 1e-3.
    initial_state_std : float or sequence of float
        Standard deviation of the initial state estimate (its unit), > 0.  Default 0.1.
    current_parameter : str or None
        Name of the problem's stagewise parameter that is the ocean current (a name that is no
        stagewise parameter of the problem is refused); ``None`` (default): ``"current"`` where
        the problem has it, else no current in the state.
    current_model : {"random_walk", "gauss_markov", "none"}
        How the current evolves; ``"none"``: no current in the state (the filter takes its
        effect for process noise and a closed loop's controller is told no current: the naive
        controller, on estimated states).
    current_std : float or sequence of float
        Noise intensity ``q_c`` of the current (m/s/√s), > 0: one for every inertial axis, or
        one per axis (``(north, east, down)`` of a 6-DOF vehicle's current).  Default 0.01: the
        current may drift by ≈ 0.08 m/s in a minute.  An ocean current at survey depth is
        horizontal: a small vertical entry keeps the filter from turning sensor noise into a
        vertical current the depth loop then chases (``benchmarks/bench_path.py``).
    current_time_constant : float
        Correlation time τ of the Gauss–Markov current (s), > 0.  Default 600.
    current_mean : float
        Mean μ of the Gauss–Markov current, each entry (m/s).  Default 0.
    initial_current_std : float
        Standard deviation of the initial current estimate (m/s), > 0.  Default 0.5.
    current_filter : float
        Time constant ``T`` (s, >= 0) of the first-order low-pass filter on the current handed
        to a controller (:attr:`Estimate.current_filtered`, what :func:`~uuv_ocp.simulate`
        tells the NMPC): ``ĉ_f,k = ĉ_f,k−1 + (1 − e^(−dt/T)) (ĉ_k − ĉ_f,k−1)`` from the prior
        mean at :meth:`Estimator.reset`; its bandwidth is ``1/(2πT)`` Hz.  The filter's own
        estimate stays consistent (its noise model unchanged); the controller sees the current's
        slow part without the step-to-step wander a plan would chase with its fins.  Default 0:
        the estimate itself.
    bias : bool
        Also estimate a bias added to the controls (a random walk).
    bias_std : float
        Noise intensity of the bias (control unit/√s), > 0.  Default 1.
    initial_bias_std : float
        Standard deviation of the initial bias (control unit), > 0.  Default 100.
    alpha, beta, kappa : float
        The UKF's Merwe scaled sigma points: spread α ∈ (0, 1], β = 2 optimal for Gaussian
        priors, κ >= 0 secondary scaling; λ = α² (n + κ) − n.  The defaults α = 1, β = 2,
        κ = 0 keep every weight non-negative (the predicted covariance stays positive
        semi-definite; α = 1e-3, the textbook choice, gives a centre weight of −1e6 and loses
        six digits to cancellation).
    horizon : int
        The MHE's window, in control steps (>= 1).  Default 20 (2 s at 10 Hz: two position
        fixes of a 1 Hz USBL in every window).
    mode : {"full", "rti"}
        The MHE's solve: Gauss–Newton to convergence (``"full"``, default) or one Gauss–Newton
        step per control step from the shifted previous solution (``"rti"``).
    max_iterations : int
        The full solve's largest number of Gauss–Newton iterations per step (>= 1).  Default 20.
    tolerance : float
        The full solve stops when the Gauss–Newton decrement ``bᵀδ`` (twice the predicted
        decrease of the cost) is below ``tolerance · max(1, cost)``, > 0.  Default 1e-10.
    compiled : bool or None
        Compile the estimator's step to C when it is built (``uuv_ocp.native.compile``, cached
        on disk by content; CasADi's virtual machine if that fails, with one warning).
        ``None`` (default): the EKF compiles wherever a C compiler exists, unless the
        environment sets ``UUV_OCP_COMPILED=0`` (the first build takes seconds for the RexROV,
        about a minute for a 6-DOF vehicle, then it is read from the cache); the MHE runs on the
        virtual machine (its first build takes 15 s for the RexROV, 5 min for the BlueROV2:
        ask for it with ``True``); the UKF has no compiled step.
    """

    state_std: float | tuple[float, ...] = 1e-3
    initial_state_std: float | tuple[float, ...] = 0.1
    current_parameter: str | None = None
    current_model: str = "random_walk"
    current_std: float | tuple[float, ...] = 0.01
    current_time_constant: float = 600.0
    current_mean: float = 0.0
    initial_current_std: float = 0.5
    current_filter: float = 0.0
    bias: bool = False
    bias_std: float = 1.0
    initial_bias_std: float = 100.0
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    horizon: int = 20
    mode: str = "full"
    max_iterations: int = 20
    tolerance: float = 1e-10
    compiled: bool | None = None

    def __post_init__(self) -> None:
        """Check the scalar fields (``ValueError`` names the field); the per-state ones on use."""
        set_field = object.__setattr__
        check.choice("options.current_model", self.current_model, CURRENT_MODELS)
        if self.current_parameter is not None and not isinstance(self.current_parameter, str):
            raise ValueError(
                f"options.current_parameter must be a str or None, got {check.shown(self.current_parameter)}"
            )
        check.boolean("options.bias", self.bias)
        if self.compiled is not None:
            check.boolean("options.compiled", self.compiled)
        for name in (
            "current_time_constant",
            "initial_current_std",
            "bias_std",
            "initial_bias_std",
        ):
            set_field(self, name, check.positive_float(f"options.{name}", getattr(self, name)))
        set_field(self, "current_mean", check.finite_float("options.current_mean", self.current_mean))
        set_field(
            self, "current_filter", check.nonnegative_float("options.current_filter", self.current_filter)
        )
        alpha = check.positive_float("options.alpha", self.alpha)
        if alpha > 1.0:
            raise ValueError(f"options.alpha must lie in (0, 1], got {alpha}")
        set_field(self, "alpha", alpha)
        set_field(self, "beta", check.nonnegative_float("options.beta", self.beta))
        set_field(self, "kappa", check.nonnegative_float("options.kappa", self.kappa))
        set_field(self, "horizon", check.positive_int("options.horizon", self.horizon))
        check.choice("options.mode", self.mode, MHE_MODES)
        set_field(self, "max_iterations", check.positive_int("options.max_iterations", self.max_iterations))
        set_field(self, "tolerance", check.positive_float("options.tolerance", self.tolerance))
        for name in ("state_std", "initial_state_std", "current_std"):
            set_field(self, name, _std_field(f"options.{name}", getattr(self, name)))


def _std_field(name: str, value: object) -> float | tuple[float, ...]:
    """Return a standard deviation option as one positive float or a tuple of positive floats.

    Numpy scalars count as scalars (review F3); the vector's length is checked on use, against
    the model's axes, since the options do not know the model.
    """
    if isinstance(value, (str, bytes)) or np.ndim(value) == 0:  # type: ignore[arg-type]
        return check.positive_float(name, value)
    expected = f"{name} must be a positive float or a 1-D sequence of them, got {check.shown(value)}"
    try:
        raw = np.asarray(value)
        array = raw.astype(float)
    except (TypeError, ValueError):
        raise ValueError(expected) from None
    # Bools and strings convert to floats silently: refuse them like the scalar path does.
    items = value if isinstance(value, list | tuple) else raw.ravel().tolist()
    booleans = any(isinstance(v, bool | np.bool_) for v in items)
    if array.ndim != 1 or array.size == 0 or raw.dtype.kind not in "iuf" or booleans:
        raise ValueError(expected)
    if not np.all(np.isfinite(array)) or not np.all(array > 0.0):
        raise ValueError(f"{name} must hold finite values > 0, got {check.shown(value)}")
    return tuple(float(v) for v in array)


@dataclass(frozen=True)
class Estimate:
    """One estimate, after the measurements of a control step.

    Attributes
    ----------
    step : int
        Control step index.
    state : numpy.ndarray, shape (nx,)
        Estimated state.
    current : numpy.ndarray, shape (nc,)
        Estimated inertial current (m/s); empty without one.
    bias : numpy.ndarray, shape (nb,)
        Estimated control bias; empty unless ``options.bias``.
    covariance : numpy.ndarray, shape (n, n)
        Covariance of the augmented state ``[x, c, b]``.
    sensors : tuple of int
        Sensors whose measurements were used.
    innovations : numpy.ndarray, shape (m,)
        Measurement minus its prediction (angles wrapped), for those sensors' outputs in order.
    innovation_covariance : numpy.ndarray, shape (m, m)
        Its predicted covariance ``S`` (for NIS: ``yᵀ S⁻¹ y``).
    current_filtered : numpy.ndarray, shape (nc,)
        The current low-passed for a controller (``EstimatorOptions.current_filter``; equal to
        :attr:`current` when that is 0), m/s; empty without a current.
    """

    step: int
    state: np.ndarray
    current: np.ndarray
    bias: np.ndarray
    covariance: np.ndarray
    sensors: tuple[int, ...] = ()
    innovations: np.ndarray = field(default_factory=lambda: np.zeros(0))
    innovation_covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    current_filtered: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def augmented(self) -> np.ndarray:
        """The augmented state ``[x, c, b]``."""
        return np.concatenate([self.state, self.current, self.bias])


def wrap(angles: np.ndarray) -> np.ndarray:
    """Angles wrapped into (−π, π]."""
    return np.pi - np.mod(np.pi - angles, 2.0 * np.pi)


class AugmentedModel:
    """The augmented discrete model of a problem (module doc), as CasADi expressions."""

    def __init__(
        self,
        problem: Transcribed,
        sensors: Sensors,
        options: EstimatorOptions,
        parameters: Mapping[str, Any] | None,
    ) -> None:
        spec = problem.spec()
        self.spec = spec
        # the controller's own trailing states (a path parameter) are known to it exactly: the
        # estimator estimates the others, and the step reads zeros in their place (a vehicle's
        # rows do not depend on them)
        own = int(getattr(problem, "controller_states", 0))
        nx, nu = spec.state_dim - own, spec.control_size
        self.own = own
        if sensors.state_dim != nx:
            mine = f" (not the {own} last, the controller's own: a path parameter)" if own else ""
            raise ValueError(
                f"sensors must measure the problem's {nx} states{mine}, got sensors on {sensors.state_dim}"
            )
        stagewise_names = [name for name, (_, _, stagewise) in spec.layout.entries.items() if stagewise]
        wanted = options.current_parameter
        if wanted is not None and wanted not in stagewise_names:
            raise ValueError(
                f"options.current_parameter must name a stagewise parameter of the problem "
                f"{stagewise_names}, got {wanted!r}"
            )
        wanted = wanted or "current"
        offset, nc = 0, 0
        for name, (_, size, stagewise) in spec.layout.entries.items():
            if not stagewise or options.current_model == "none":
                continue
            if name == wanted:
                nc = size
                break
            offset += size
        nb = nu if options.bias else 0
        self.nx, self.nu, self.nc, self.nb = nx, nu, nc, nb
        self.size = nx + nc + nb
        self.dt = spec.dt
        # the problem's own parameters (an Ocp's, its first node); a tracking problem's
        # reference does not enter the dynamics and its current is a state here: zeros
        from uuv_ocp.ocp import Ocp

        if isinstance(problem, Ocp) and spec.layout.entries:
            p = problem.parameters(np.zeros(nx), parameters)
        elif parameters is not None:
            raise ValueError(f"parameters is for an Ocp with parameters, got {check.shown(parameters)}")
        else:
            p = np.zeros(spec.layout.size)
            # a vehicle's model parameters (thruster health) at their defaults, not zero
            for name, value in getattr(problem, "_default_model_values", ()):
                p[spec.layout.entries[name][0]] = value
        self.p_global = np.concatenate(
            [p[part] for part, _, stagewise in spec.layout.entries.values() if not stagewise] or [np.zeros(0)]
        )
        self.p_stage = np.concatenate(
            [
                p[part.start : part.start + size]
                for part, size, stagewise in spec.layout.entries.values()
                if stagewise
            ]
            or [np.zeros(0)]
        )
        state_std = _per_state("options.state_std", options.state_std, nx)
        initial_std = _per_state("options.initial_state_std", options.initial_state_std, nx)
        dt = spec.dt
        # per axis: the vertical intensity may differ from the horizontal ones (options doc)
        current_std = _per_state("options.current_std", options.current_std, nc) if nc else np.zeros(0)
        if options.current_model == "gauss_markov":
            tau = options.current_time_constant
            self.decay = math.exp(-dt / tau)
            current_variance = current_std**2 * tau / 2.0 * (1.0 - self.decay**2)
        else:
            self.decay = 1.0
            current_variance = current_std**2 * dt
        self.mean = options.current_mean
        self.Q = np.diag(
            np.concatenate([state_std**2, current_variance, np.full(nb, options.bias_std**2 * dt)])
        )
        self.P0 = np.diag(
            np.concatenate(
                [
                    initial_std**2,
                    np.full(nc, options.initial_current_std**2),
                    np.full(nb, options.initial_bias_std**2),
                ]
            )
        )
        with BUILD_LOCK:  # CasADi expressions are built here (uuv_ocp._concurrency)
            self.xa = ca.SX.sym("xa", self.size)
            self.u = ca.SX.sym("u", nu)
            self.ps = ca.SX.sym("p_stage", spec.stage_dim)
            self.pg = ca.SX.sym("p_global", spec.global_dim)
            x, c, b = self.xa[:nx], self.xa[nx : nx + nc], self.xa[nx + nc :]
            # empty slices of an SX are 1-by-0 rows, which vertcat does not skip: leave them out
            parts = (self.ps[:offset], c, self.ps[offset + nc :])
            stage = ca.vertcat(*[part for part in parts if part.numel()]) if nc else self.ps
            step = problem.build().step
            full = ca.vertcat(x, ca.SX.zeros(own)) if own else x
            moved = step(full, self.u + b if nb else self.u, stage, self.pg)
            pieces = [moved[:nx] if own else moved]
            if nc:
                pieces.append(self.mean + self.decay * (c - self.mean) if self.decay != 1.0 else c)
            if nb:
                pieces.append(b)
            self.f = ca.vertcat(*pieces)
            self.h = sensors.stacked()(x)
            self.inputs = [self.xa, self.u, self.ps, self.pg]


class Estimator:
    """A state and current estimator on a problem's own model, chosen by name.

    ``Estimator(problem, "ekf", sensors=...)`` returns the registered class of that name
    (:func:`available_estimators`): ``"ekf"``
    (:class:`~uuv_ocp.estimation.ekf.ExtendedKalmanFilter`), ``"ukf"``
    (:class:`~uuv_ocp.estimation.ukf.UnscentedKalmanFilter`) or ``"mhe"``
    (:class:`~uuv_ocp.estimation.mhe.MovingHorizonEstimator`).

    Parameters
    ----------
    problem : Ocp or TrackingProblem
        The controller's problem: its built step is the model.
    method : str
        Registered estimator name.
    sensors : Sensors
        What is measured (their ``h`` are on the problem's state; on a
        :class:`~uuv_ocp.PathFollowingProblem`, on the vehicle's state: the path parameter is
        the controller's own, neither measured nor estimated).
    options : EstimatorOptions, optional
        Noise model and tuning.
    parameters : dict, optional
        An Ocp's parameter values (as :meth:`Ocp.parameters <uuv_ocp.Ocp.parameters>`); the
        first node's stagewise values are the model's.

    Notes
    -----
    An estimator holds its mean and covariance (it is mutable, like an NMPC): :meth:`reset`
    starts it, :meth:`correct` takes the measurements of a step, :meth:`predict` moves it
    over one control interval, :meth:`step` does both.
    """

    name = "estimator"
    #: whether the class has a step it compiles to C (``options.compiled``; the EKF)
    compiles = False

    def __new__(cls, problem: Any = None, method: str = "ekf", **_: Any) -> Any:
        """Dispatch ``Estimator(problem, name, ...)`` to the class registered as ``name``."""
        if cls is Estimator:
            cls = _resolve(method)
        return object.__new__(cls)

    def __init__(
        self,
        problem: Transcribed,
        method: str | None = None,
        *,
        sensors: Sensors,
        options: EstimatorOptions | None = None,
        parameters: Mapping[str, Any] | None = None,
    ) -> None:
        if not isinstance(problem, Transcribed):
            raise ValueError(
                f"problem must be a uuv_ocp.Ocp or TrackingProblem, got {type(problem).__name__}"
            )
        if not isinstance(sensors, Sensors):
            raise ValueError(f"sensors must be a uuv_ocp.Sensors, got {type(sensors).__name__}")
        options = EstimatorOptions() if options is None else options
        if not isinstance(options, EstimatorOptions):
            raise ValueError(
                f"options must be a uuv_ocp.EstimatorOptions or None, got {type(options).__name__}"
            )
        if method is not None and _resolve(method) is not type(self):
            raise ValueError(
                f"method {method!r} names {_resolve(method).__name__}, not this class {type(self).__name__}; "
                f"call uo.Estimator(problem, {method!r}, ...)"
            )
        self.problem, self.sensors, self.options = problem, sensors, options
        with BUILD_LOCK:  # CasADi Functions are built here (uuv_ocp._concurrency)
            self.model = AugmentedModel(problem, sensors, options, parameters)
        self.R = sensors.std**2
        self.angular = sensors.angular
        self._rows: dict[tuple[int, ...], np.ndarray] = {}
        self._angular_rows: dict[bytes, np.ndarray] = {}
        self.x = np.zeros(self.model.size)
        self.P = self.model.P0.copy()
        self.steps = 0
        # the controller's low-passed current (options.current_filter) and the last step it took
        self._current_filtered = np.zeros(self.model.nc)
        self._filtered_step: int | None = None
        self.compiled = self.compiles and (
            compiled_by_default("the estimator runs on CasADi's virtual machine", stacklevel=4)
            if options.compiled is None
            else options.compiled
        )
        with BUILD_LOCK:
            self._build()

    # ------------------------------------------------------------ subclasses
    def _build(self) -> None:
        raise NotImplementedError

    def predict(self, u: object) -> None:
        """Move the estimate over one control interval under the applied control ``u``."""
        raise NotImplementedError

    def _update(self, rows: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correct with outputs ``rows`` of the stacked sensors measured as ``z``; (innovations, S)."""
        raise NotImplementedError

    # ---------------------------------------------------------------- shared
    def rows(self, sensors: tuple[int, ...]) -> np.ndarray:
        """Rows of the stacked sensor output of ``sensors`` (cached per combination)."""
        rows = self._rows.get(sensors)
        if rows is None:
            rows = self._rows[sensors] = self.sensors.rows(sensors)
        return rows

    def reset(self, x0: object, current: object | None = None, covariance: object | None = None) -> None:
        """Start from state ``x0`` (and ``current``, m/s; zero by default) with the prior covariance.

        ``covariance`` (n × n, the augmented state's) replaces the options' initial one.
        """
        m = self.model
        x = check.finite_array("x0", x0, (m.nx,))
        c = np.zeros(m.nc) if current is None else check.finite_array("current", current, (m.nc,))
        if covariance is None:
            P = m.P0.copy()
        else:
            P = check.finite_array("covariance", covariance, (m.size, m.size))
            eigenvalues = np.linalg.eigvalsh(0.5 * (P + P.T))
            # rounding-level negative eigenvalues (a covariance read back from an Estimate) pass
            if not np.allclose(P, P.T) or eigenvalues.min() < -1e-12 * max(1.0, eigenvalues.max()):
                raise ValueError("covariance must be symmetric positive semi-definite")
            P = P.copy()
        # every check before the first assignment: a refused reset leaves the estimator as it was
        self._check_prior(P)
        self.x = np.concatenate([x, c, np.zeros(m.nb)])
        self.P = P
        self.steps = 0
        self._current_filtered = c.copy()
        self._filtered_step = None
        self._reset_hook()

    def _check_prior(self, P: np.ndarray) -> None:
        """Refuse (``ValueError``) a prior covariance this estimator cannot start from (none set yet)."""

    def _reset_hook(self) -> None:
        pass

    def measured_rows(self, measurement: object) -> np.ndarray:
        """Return the rows of the stacked outputs ``measurement`` fills; ``ValueError`` if it does not fit."""
        if not isinstance(measurement, Measurement):
            raise ValueError(f"measurement must be a uuv_ocp Measurement, got {type(measurement).__name__}")
        rows = self.rows(measurement.sensors)
        if measurement.values.shape != rows.shape:
            raise ValueError(
                f"measurement.values must have {rows.size} entries (the reporting sensors' outputs), "
                f"got shape {measurement.values.shape}"
            )
        return rows

    def correct(self, measurement: Measurement) -> Estimate:
        """Use the measurements of one step (only the sensors that reported) and return the estimate."""
        rows = self.measured_rows(measurement)
        if rows.size:
            innovations, S = self._update(rows, measurement.values)
        else:
            innovations, S = np.zeros(0), np.zeros((0, 0))
        return self.estimate(measurement.step, measurement.sensors, innovations, S)

    def step(self, u: object, measurement: Measurement) -> Estimate:
        """:meth:`predict` under ``u``, then :meth:`correct` with ``measurement``.

        A measurement that does not fit is refused before the prediction: a refused step leaves
        the estimator as it was.
        """
        self.measured_rows(measurement)
        self.predict(u)
        return self.correct(measurement)

    def estimate(
        self,
        step: int | None = None,
        sensors: tuple[int, ...] = (),
        innovations: np.ndarray | None = None,
        S: np.ndarray | None = None,
    ) -> Estimate:
        """Return the current estimate as a record (copies).

        The low-passed current (``options.current_filter``) moves only forward in ``step``: a
        later step advances it over the steps between (``step − last`` control intervals); the
        same or an earlier step, or ``step=None`` (a plain read: a log, a plot), leaves it as it is.
        """
        m = self.model
        current = self.x[m.nx : m.nx + m.nc].copy()
        T = self.options.current_filter
        last = self._filtered_step
        if step is None:
            # A read must not move the filter the closed loop hands to the controller (review F2).
            step = 0 if last is None else last
        elif T > 0.0 and m.nc and (last is None or step > last):
            elapsed = m.dt * (1 if last is None else step - last)  # step > last here
            self._current_filtered += -math.expm1(-elapsed / T) * (current - self._current_filtered)
            self._filtered_step = step
        filtered = self._current_filtered.copy() if T > 0.0 else current.copy()
        return Estimate(
            step,
            self.x[: m.nx].copy(),
            current,
            self.x[m.nx + m.nc :].copy(),
            self.P.copy(),
            sensors,
            np.zeros(0) if innovations is None else innovations,
            np.zeros((0, 0)) if S is None else S,
            filtered,
        )

    def _control(self, u: object) -> np.ndarray:
        value = np.asarray(u, dtype=float) if not isinstance(u, np.ndarray) else u
        if value.shape == (self.model.nu,) and np.isfinite(value).all():  # the hot path
            return value
        return check.finite_array("u", u, (self.model.nu,))

    def _residual(self, rows: np.ndarray, z: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        y = z - predicted
        angular = self._angular_rows.get(rows.tobytes())
        if angular is None:
            angular = self._angular_rows[rows.tobytes()] = np.flatnonzero(self.angular[rows])
        if angular.size:
            y[angular] = wrap(y[angular])
        return y


def buffered(name: str, inputs: list[ca.SX], outputs: list[ca.SX]) -> BufferedFunction:
    """Return a zero-copy caller of a Function of ``outputs`` (one CasADi call per estimator step)."""
    with BUILD_LOCK:  # dense outputs: a sparse one would make BufferedFunction wrap it in MX
        function = ca.Function(name, inputs, [ca.densify(o) for o in outputs])
    return BufferedFunction(function)


# ------------------------------------------------------------------- registry
_ESTIMATORS: dict[str, Callable[..., Any]] = {}


def register_estimator(name: str, cls: type[Estimator], *, overwrite: bool = False) -> None:
    """Register an :class:`Estimator` subclass under ``name`` (``Estimator(problem, name, ...)``)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty str, got {check.shown(name)}")
    if not (isinstance(cls, type) and issubclass(cls, Estimator)):
        raise ValueError(f"cls must be a subclass of uuv_ocp.Estimator, got {cls!r}")
    if name.lower() in _ESTIMATORS and not overwrite:
        raise ValueError(f"estimator {name!r} is registered already (pass overwrite=True)")
    _ESTIMATORS[name.lower()] = cls


def available_estimators() -> list[str]:
    """Names accepted by :class:`Estimator`, sorted."""
    return sorted(_ESTIMATORS)


def _resolve(method: object) -> Any:
    if not isinstance(method, str) or method.lower() not in _ESTIMATORS:
        raise ValueError(f"method must be one of {available_estimators()}, got {check.shown(method)}")
    return _ESTIMATORS[method.lower()]
