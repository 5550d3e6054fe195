"""Closed-loop simulation: a controller (an NMPC, a guidance law) against a finely integrated plant.

The plant is the vehicle model (possibly with different parameters: model mismatch) integrated
with RK4 at ``plant_substeps`` steps per control interval (default 10, i.e. 10 ms for
dt = 0.1 s), under a Gauss–Markov current; the controller sees the state plus optional
measurement noise.  A :class:`KeyboardInterrupt` (Ctrl-C, CasADi's included) stops the loop
and reaches the caller as :class:`SimulationInterrupted`, a ``KeyboardInterrupt`` that carries
everything computed so far (``error.result``, with ``interrupted=True``): nothing is lost, and
nothing that was not finished is passed off as a finished run.

A *fault* ends the run early without losing it: a measurement that is not finite (before the
controller sees it), a plant state that is not finite or whose magnitude exceeds
:data:`BLOW_UP` (the plant blew up), or an exception of the plant's integrator.  The result
then holds the run up to the last finite state and says why in ``fault``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.control.disturbances import Current, MeasurementNoise
from uuv_ocp.control.dither import NullSpaceDither
from uuv_ocp.control.faults import FaultSchedule, ThrusterFault, fault_schedule
from uuv_ocp.control.metrics import position_errors, tracking_metrics
from uuv_ocp.control.scenario import scenario
from uuv_ocp.estimation.base import Estimate, Estimator
from uuv_ocp.estimation.faults import FaultDetectorOptions, ThrusterFaultDetector
from uuv_ocp.estimation.sensors import Measurement, Sensors
from uuv_ocp.interrupts import check_interrupt, interrupt_handled, remember_interrupts
from uuv_ocp.model.thrusters import ThrusterConfiguration
from uuv_ocp.progress import ProgressBar
from uuv_ocp.solvers.base import reraise_interrupt

#: A plant state entry larger than this in magnitude (SI units) counts as a blow-up fault; below the
#: plausibility bound (``_validation.PLAUSIBLE_MAGNITUDE``) past which the controller refuses a state.
BLOW_UP = 1e8
#: the fields of a run with faults, an allocation or a fault detector (saved only when filled)
FAULT_FIELDS = ("thruster_health", "thruster_forces", "detections", "estimated_health", "dither")


@runtime_checkable
class Controller(Protocol):
    """What :func:`simulate` needs of a controller: NMPC, LosGuidance or a class of your own.

    ``problem`` gives the loop its plant, window and reference (:mod:`uuv_ocp.control.scenario`);
    ``solver_name`` labels the run; ``warm_up`` builds what the steps need and is called once
    (while ``warmed_up`` is false), ``reset`` before every later run.  ``step`` returns a
    record with ``control`` (the command to apply), ``result`` (a :class:`~uuv_ocp.SolveResult`
    or ``None``), ``fallback`` and ``deadline_hit`` (bools) and ``message`` (why the fallback
    was taken, or the status of a step with no result).
    """

    problem: Any
    solver_name: str
    warmed_up: bool

    def reset(self) -> None:
        """Forget the last run's state (warm starts, integrators)."""

    def warm_up(
        self, x: Any, t: float = ..., u_prev: Any = ..., current: Any = ..., parameters: Any = ...
    ) -> None:
        """Build what the steps need at state ``x`` and time ``t``, then reset."""

    def step(
        self, x: Any, t: float = ..., u_prev: Any = ..., current: Any = ..., parameters: Any = ...
    ) -> Any:
        """Return the record of one step at the measured state ``x`` and time ``t`` (s)."""


class SimulationInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`simulate`; ``result`` holds the run up to the interrupt."""

    def __init__(self, result: ClosedLoopResult) -> None:
        super().__init__(f"simulation interrupted after {result.controls.shape[0]} steps")
        self.result = result


@dataclass(frozen=True)
class EstimateLog:
    """What the estimator gave the controller at each step of a run (``run.estimates``).

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Times of the controller steps (s).
    states : numpy.ndarray, shape (n, nx)
        Estimated states (the controller's input).
    currents : numpy.ndarray, shape (n, nc)
        Estimated inertial currents (m/s).
    variances : numpy.ndarray, shape (n, na)
        Diagonal of the augmented covariance ``[x, c, b]`` (for ±2σ bands).
    innovations : numpy.ndarray, shape (n, m)
        Innovations of the stacked sensor outputs; NaN where a sensor did not report.
    times : numpy.ndarray, shape (n,)
        Wall-clock time of each estimator step (s).
    innovation_variances : numpy.ndarray, shape (n, m)
        Diagonal of each innovation's predicted covariance ``S`` (the outputs' units squared;
        ``innovations / sqrt(innovation_variances)`` is N(0, 1) for a consistent filter); NaN
        where a sensor did not report, or for a run saved before it was recorded.
    """

    t: np.ndarray
    states: np.ndarray
    currents: np.ndarray
    variances: np.ndarray
    innovations: np.ndarray
    times: np.ndarray
    innovation_variances: np.ndarray


@dataclass(frozen=True)
class MeasurementLog:
    """What the sensors reported at each step of a run (``run.measurements``).

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Times of the controller steps (s).
    values : numpy.ndarray, shape (n, m)
        The stacked outputs of all sensors; NaN where a sensor was not due or dropped out.
    dropped : numpy.ndarray of bool, shape (n, number of sensors)
        Which sensors were due but did not report (dropouts).
    sensors : tuple of str
        The sensors' names, in order.
    sizes : tuple of int
        Their numbers of outputs (the column blocks of ``values``).
    """

    t: np.ndarray
    values: np.ndarray
    dropped: np.ndarray
    sensors: tuple[str, ...]
    sizes: tuple[int, ...]


@dataclass(frozen=True)
class ClosedLoopResult:
    """Everything a closed-loop run produced.

    Parameters
    ----------
    t : numpy.ndarray, shape (n+1,)
        Sample times (s).
    states : numpy.ndarray, shape (n+1, nx)
        True plant states.
    controls : numpy.ndarray, shape (n, nu)
        Applied controls (3-DOF: N, N, N·m).
    reference : numpy.ndarray, shape (n+1, nx)
        Reference states at ``t`` (continuous heading); NaN for a problem without a reference.
    solve_times : numpy.ndarray, shape (n,)
        Wall-clock time of each controller step (s).
    iterations : numpy.ndarray, shape (n,)
        Solver iterations per step.
    fallback_steps : numpy.ndarray of bool, shape (n,)
        Steps where the fallback control was applied.
    relaxed_steps : numpy.ndarray of bool, shape (n,)
        Steps solved with the soft terminal constraint.
    currents : numpy.ndarray, shape (n+1, nc)
        Inertial current velocity (m/s); zero columns for a problem without a current.
    statuses : tuple of str
        Solver status per step; on a fallback step why the fresh plan was refused
        (:attr:`StepRecord.message <uuv_ocp.control.mpc.StepRecord>`: the backend's status, its
        exception, ``"non-finite controls (...)"``, ``"path constraint violated by ..."``).
    solver : str
        Solver name.
    interrupted : bool
        Whether the run was stopped early by the user.
    deadline_steps : numpy.ndarray of bool, shape (n,), optional
        Steps whose solve the backend's ``deadline`` option stopped or outlasted
        (:attr:`StepRecord.deadline_hit <uuv_ocp.control.mpc.StepRecord>`); all False when
        omitted.
    fault : str or None
        Why the run stopped early (non-finite measurement, plant blow-up, plant exception), with
        the time; ``None`` for a run that reached its end.  The arrays end at the last finite
        state.
    substep_t : numpy.ndarray, shape (n·s+1,), optional
        Times (s) of every plant integration step (``s = plant_substeps``), recorded with
        ``simulate(..., record_substeps=True)``; empty otherwise.
    substep_states : numpy.ndarray, shape (n·s+1, nx), optional
        Plant states at ``substep_t``: what the vehicle did between control instants (collision
        checks, :func:`uuv_ocp.obstacles.closest_approach`); ``substep_states[::s]`` equals ``states``.
    state_names : tuple of str, optional
        Names of the state columns (the vehicle's ``layout.state_names`` for a tracking run;
        the Ocp's declared names for an Ocp's run).
    state_units : tuple of str, optional
        Units of the state columns (the vehicle's ``layout.state_units``; empty strings for
        an Ocp's run).
    state_roles : tuple of str, optional
        Role of each state column (``"x"``, ``"y"``, ``"z"``, ``"psi"``, ``"velocity"`` or
        ``""``; the vehicle's ``layout.state_roles``): plots and metrics find the positions,
        the heading and the velocities by role, whatever the vehicle names them.
    estimated_states, estimated_currents, estimate_variances, innovations, estimate_times : optional
    innovation_variances : optional
        Arrays of a run with an estimator: :attr:`estimates` (:class:`EstimateLog`); empty otherwise.
    measurement_values, measurement_dropped, sensor_names, sensor_sizes : optional
        A run with an estimator: :attr:`measurements` (:class:`MeasurementLog`); empty otherwise.
    thruster_health : numpy.ndarray, shape (n, thrusters), optional
        A run with thruster faults or a plant-side allocation (:mod:`uuv_ocp.control.faults`):
        the plant's true effectiveness of each thruster on each interval; empty otherwise.
    thruster_forces : numpy.ndarray, shape (n, thrusters), optional
        Such a run's force each thruster delivered on each interval (N, ``h ∘ f + s``).
    detections : numpy.ndarray, shape (m, 4), optional
        A run with ``fault_detector``: one row per detection, ``(time s, thruster, estimated
        health, stuck force N)`` (:mod:`uuv_ocp.estimation.faults`; the force is 0 for a loss,
        non-zero for a thruster declared stuck); empty otherwise.  Records saved before the
        fourth column have three.
    estimated_health : numpy.ndarray, shape (n, thrusters), optional
        Such a run's regression health ``1 − clip(ℓ)`` of every thruster per step (NaN until
        a full window); empty otherwise.
    dither : numpy.ndarray, shape (n, thrusters), optional
        A run with a null-space dither (``FaultDetectorOptions(dither=...)``,
        :mod:`uuv_ocp.control.dither`): the dither added to each step's planned command (N);
        ``controls`` are the applied commands, ``controls − dither`` the NMPC's plan.  Empty
        otherwise.
    """

    t: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    reference: np.ndarray
    solve_times: np.ndarray
    iterations: np.ndarray
    fallback_steps: np.ndarray
    relaxed_steps: np.ndarray
    currents: np.ndarray
    statuses: tuple[str, ...]
    solver: str
    interrupted: bool = False
    deadline_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    fault: str | None = None
    substep_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    substep_states: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    state_names: tuple[str, ...] = ()
    state_units: tuple[str, ...] = ()
    state_roles: tuple[str, ...] = ()
    estimated_states: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    estimated_currents: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    estimate_variances: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    innovations: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    estimate_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    innovation_variances: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    measurement_values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    measurement_dropped: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    sensor_names: tuple[str, ...] = ()
    sensor_sizes: tuple[int, ...] = ()
    thruster_health: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    thruster_forces: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    detections: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    estimated_health: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    dither: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    #: the fields of a run with an estimator (saved only when there was one)
    ESTIMATION_FIELDS: ClassVar[tuple[str, ...]] = (
        "estimated_states",
        "estimated_currents",
        "estimate_variances",
        "innovations",
        "estimate_times",
        "innovation_variances",
        "measurement_values",
        "measurement_dropped",
    )

    @property
    def estimates(self) -> EstimateLog | None:
        """The estimator's output per step, or ``None`` for a run without an estimator."""
        if not self.sensor_names:
            return None
        n = self.estimated_states.shape[0]
        # runs saved before S was recorded: NaN (unknown), of the innovations' shape
        variances = self.innovation_variances
        if variances.shape != self.innovations.shape:
            variances = np.full(self.innovations.shape, np.nan)
        return EstimateLog(
            self.t[:n],
            self.estimated_states,
            self.estimated_currents,
            self.estimate_variances,
            self.innovations,
            self.estimate_times,
            variances,
        )

    @property
    def measurements(self) -> MeasurementLog | None:
        """The sensors' reports per step, or ``None`` for a run without an estimator."""
        if not self.sensor_names:
            return None
        n = self.measurement_values.shape[0]
        return MeasurementLog(
            self.t[:n],
            self.measurement_values,
            self.measurement_dropped,
            self.sensor_names,
            self.sensor_sizes,
        )

    def __post_init__(self) -> None:
        """Fill ``deadline_steps`` (all False) when omitted."""
        if np.size(self.deadline_steps) == 0 and len(self.fallback_steps):
            object.__setattr__(self, "deadline_steps", np.zeros(len(self.fallback_steps), dtype=bool))

    @property
    def failures(self) -> int:
        """Number of steps where the solver failed and the fallback was applied."""
        return int(np.sum(self.fallback_steps))

    @property
    def deadline_misses(self) -> int:
        """Number of steps whose solve missed the backend's deadline (see ``deadline_steps``)."""
        return int(np.sum(self.deadline_steps))

    @property
    def errors(self) -> np.ndarray:
        """Horizontal position errors ``[x − x_R, y − y_R]`` (m), shape (n+1, 2)."""
        return position_errors(self)[:, :2]

    def metrics(self, settle_time: float = 5.0) -> dict[str, float | int]:
        """Tracking and timing metrics (see :func:`uuv_ocp.control.metrics.tracking_metrics`)."""
        return tracking_metrics(self, settle_time=settle_time)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every field as a numpy array, by field name: what :meth:`save` writes.

        The plant sub-steps only when recorded, so that runs without them keep their files.
        """
        recorded = {"substep_t": self.substep_t, "substep_states": self.substep_states}
        estimation: dict[str, np.ndarray] = {}
        if self.sensor_names:
            estimation = {key: getattr(self, key) for key in self.ESTIMATION_FIELDS}
            estimation["sensor_names"] = np.array(self.sensor_names, dtype=str)
            estimation["sensor_sizes"] = np.array(self.sensor_sizes, dtype=int)
        named = {
            key: np.array(getattr(self, key), dtype=str)
            for key in ("state_names", "state_units", "state_roles")
            if getattr(self, key)
        }
        faults = {key: getattr(self, key) for key in FAULT_FIELDS if getattr(self, key).size}
        return dict(
            **(recorded if self.substep_t.size else {}),
            **faults,
            **named,
            **estimation,
            t=self.t,
            states=self.states,
            controls=self.controls,
            reference=self.reference,
            solve_times=self.solve_times,
            iterations=self.iterations,
            fallback_steps=self.fallback_steps,
            relaxed_steps=self.relaxed_steps,
            currents=self.currents,
            statuses=np.array(self.statuses, dtype=str),
            solver=np.array(self.solver),
            interrupted=np.array(self.interrupted),
            deadline_steps=self.deadline_steps,
            fault=np.array(self.fault or ""),
        )

    def save(self, path: Any) -> None:
        """Write all arrays (:meth:`arrays`) to a compressed ``.npz`` file (a path or a binary file)."""
        arrays: dict[str, Any] = self.arrays()
        np.savez_compressed(path, **arrays)

    @classmethod
    def load(cls, path: Any) -> ClosedLoopResult:
        """Read a result written by :meth:`save` (a path or a binary file)."""
        with np.load(path, allow_pickle=False) as data:
            return cls.from_arrays({name: data[name] for name in data.files})

    @classmethod
    def from_arrays(cls, data: dict[str, np.ndarray]) -> ClosedLoopResult:
        """Rebuild a result from :meth:`arrays` (files of older versions lack some fields)."""
        return cls(
            t=data["t"],
            states=data["states"],
            controls=data["controls"],
            reference=data["reference"],
            solve_times=data["solve_times"],
            iterations=data["iterations"],
            fallback_steps=data["fallback_steps"],
            relaxed_steps=data["relaxed_steps"],
            currents=data["currents"],
            statuses=tuple(str(s) for s in data["statuses"]),
            solver=str(data["solver"]),
            interrupted=bool(data["interrupted"]),
            # files written before deadlines existed have no deadline_steps
            deadline_steps=(data["deadline_steps"] if "deadline_steps" in data else np.zeros(0, dtype=bool)),
            fault=(str(data["fault"]) or None) if "fault" in data else None,
            substep_t=data["substep_t"] if "substep_t" in data else np.zeros(0),
            substep_states=data["substep_states"] if "substep_states" in data else np.zeros((0, 0)),
            **cls._optional_fields(data),
        )

    @classmethod
    def _optional_fields(cls, data: dict[str, np.ndarray]) -> dict[str, Any]:
        """Return the named-state and estimation fields that ``data`` holds (older files lack them)."""
        fields: dict[str, Any] = {
            key: tuple(str(name) for name in data[key])
            for key in ("state_names", "state_units", "state_roles")
            if key in data
        }
        # a run with an estimator (files of runs without one have none of these)
        fields.update({key: data[key] for key in cls.ESTIMATION_FIELDS if key in data})
        fields.update({key: data[key] for key in FAULT_FIELDS if key in data})
        if "sensor_names" in data:
            fields["sensor_names"] = tuple(str(name) for name in data["sensor_names"])
            fields["sensor_sizes"] = tuple(int(size) for size in data["sensor_sizes"])
        return fields


def simulate(
    controller: Controller,
    x0: object,
    duration: float,
    *,
    t0: float | None = None,
    current: Current | None = None,
    current_known: bool | None = None,
    noise: MeasurementNoise | None = None,
    estimator: Estimator | None = None,
    sensors: Sensors | None = None,
    plant: Any = None,
    plant_substeps: int = 10,
    seed: int | None = None,
    progress: bool = False,
    label: str = "",
    parameters: dict[str, Any] | None = None,
    record_substeps: bool = False,
    faults: tuple[ThrusterFault, ...] = (),
    health_known: bool = False,
    allocation: ThrusterConfiguration | None = None,
    fault_detector: FaultDetectorOptions | None = None,
) -> ClosedLoopResult:
    """Run ``controller`` in closed loop for ``duration`` seconds.

    Parameters
    ----------
    controller : Controller
        The controller (an :class:`~uuv_ocp.NMPC`, a :class:`~uuv_ocp.LosGuidance`, anything of
        the :class:`Controller` protocol): warmed up unless it was already (:meth:`NMPC.warm_up
        <uuv_ocp.control.mpc.NMPC.warm_up>`: what its steps build and compile is built before
        the loop, so no timed step compiles), and reset before the run.
    x0 : array_like, shape (nx,)
        Initial plant state.
    duration : float
        Simulated time (s), > 0; for a tracking problem shortened to stay inside the
        reference window (a ``RuntimeWarning`` says so).
    t0 : float, optional
        Start time on the reference (s); the reference's ``t_start`` by default.
    current : Current, optional
        Ocean current acting on the plant (tracking problems; horizontal).
    current_known : bool, optional
        Whether the controller's model is told the true current at each step (the oracle).
        Default: ``True`` without an estimator, ``False`` with one (the controller is then
        told the estimated current); ``False`` without an estimator, or with one that models
        no current (``EstimatorOptions(current_model="none")``): told no current (the naive
        controller).
    noise : MeasurementNoise, optional
        Noise on the state the controller sees (one standard deviation per state); not with
        an estimator (its sensors have their own noise).
    estimator : Estimator, optional
        Estimate the state (and the current) from ``sensors``: at each step only the sensors
        due measure the true state (their noise, dropouts and outliers), the estimator takes
        them (after predicting over the last interval with the applied control), and the
        controller gets the estimated state and, unless ``current_known``, the estimated
        current.  It is reset to ``x0`` (and zero current) with its prior covariance.
        ``run.estimates`` and ``run.measurements`` record what it did.
    sensors : Sensors, optional
        The sensors (default and only choice: the estimator's own, ``estimator.sensors``).
    plant : VehicleModel or casadi.Function, optional
        Tracking problems: plant vehicle (a ``VehicleModel``) of the same state (default:
        the controller's own model, i.e. no mismatch).  An :class:`~uuv_ocp.ocp.Ocp`: a Function
        ``f(x, u) -> xdot`` (default: the Ocp's own dynamics with ``parameters``).
    plant_substeps : int
        RK4 steps of the plant per control interval, >= 1.
    seed : int, optional
        Seed for current and noise.
    progress : bool
        Show a progress bar.
    label : str
        Progress-bar label.
    parameters : dict, optional
        An Ocp's parameter values, held for the whole run (a tracking problem refuses them:
        its reference and current are its parameters).
    record_substeps : bool
        Also record the plant state after every one of its ``plant_substeps`` integration
        steps (``substep_t``, ``substep_states``): what happens between control instants, e.g.
        an obstacle's corner cut between two nodes.
    faults : tuple of ThrusterFault
        Thruster faults of the plant (:mod:`uuv_ocp.control.faults`): from its time on, a
        thruster delivers ``h ∘ f + s`` for its command ``f``.  Needs a vehicle whose controls
        are thruster forces, or ``allocation``.  ``run.thruster_health`` records the plant's
        true health per interval.
    health_known : bool
        Tell the controller the true health and stuck forces at each step (the oracle; its
        vehicle's ``health`` and ``thrust_offset`` model parameters); otherwise its model
        keeps them healthy.
    allocation : ThrusterConfiguration, optional
        The pseudo-inverse baseline: the controller plans the generalised force (a force
        vehicle) and the plant maps it to these thrusters by the pseudo-inverse of their
        healthy allocation matrix, clipped to their bounds (:mod:`uuv_ocp.control.faults`).
    fault_detector : FaultDetectorOptions, optional
        The fault-tolerant NMPC: detect and isolate thruster faults from the estimator's bias
        (:mod:`uuv_ocp.estimation.faults`; needs ``estimator`` with ``EstimatorOptions(bias=True)``
        and a vehicle with thrusters) and, from a detection on, tell the controller the
        *estimated* health.  ``run.detections`` (rows ``time s, thruster, estimated health, stuck
        force N``) and
        ``run.estimated_health`` (the regression's health per step, NaN before a full window)
        record it.  With ``FaultDetectorOptions(dither=DitherOptions(amplitude=...))`` the
        thrusters get the plan plus a null-space dither (:mod:`uuv_ocp.control.dither`; the
        controls recorded are the applied ones, ``run.dither`` the part added).

    Returns
    -------
    ClosedLoopResult
        The whole run; shorter, with the reason in ``fault``, when a measurement was not
        finite or the plant blew up (module doc).

    Raises
    ------
    SimulationInterrupted
        On Ctrl-C, carrying the run up to the interrupt.
    """
    _check_arguments(controller, current, noise, seed, current_known, progress, record_substeps)
    sensors = _check_estimation(controller, estimator, sensors, noise)
    if current_known is None:
        current_known = estimator is None
    problem = controller.problem
    spec = problem.spec()
    x0 = check.finite_array("x0", x0, (spec.state_dim,))
    plant_substeps = check.positive_int("plant_substeps", plant_substeps)
    run = scenario(
        problem,
        t0=t0,
        duration=check.positive_float("duration", duration),
        plant=plant,
        parameters=parameters,
        current=current,
        substeps=plant_substeps,
    )
    steps, nc, dt = run.steps, run.current_dim, spec.dt
    _check_noise(noise, spec.state_dim)
    rng = np.random.default_rng(seed)
    currents = _sampled_currents(current, steps, nc, dt, rng)
    times = run.t0 + dt * np.arange(steps + 1)
    schedule = fault_schedule(
        faults, problem, steps=steps, t0=run.t0, health_known=health_known, allocation=allocation
    )
    detector = _fault_detector(fault_detector, problem, estimator, health_known, allocation)
    dither = _dither(detector, problem, dt, run.t0)
    loop = _Loop(
        controller=controller,
        run=run,
        dt=dt,
        times=times,
        currents=currents,
        # what the controller's model is told: the measured current, or none (the instance's
        # current is then zero); a time-invariant problem is always asked at t = 0
        told=currents if current_known else np.zeros_like(currents),
        clock=times if run.time_varying else np.zeros_like(times),
        known={"parameters": parameters} if parameters is not None else {},
        rng=rng,
        noise=noise,
        estimator=estimator,
        sensors=sensors,
        estimated=_current_estimated(estimator, current_known, nc),
        schedule=schedule,
        detector=detector,
        dither=dither,
    )
    log = _Log(x0, steps, spec.control_size, plant_substeps if record_substeps else 0, dt)
    if detector is not None:
        detector.reset()
        log.estimated_health = np.full((steps, detector.count), np.nan)
    if dither is not None:
        log.dither = np.zeros((steps, spec.control_size))
    if estimator is not None and sensors is not None:
        log.track_estimates(estimator, sensors)
        estimator.reset(x0[: estimator.model.nx])
    u_prev = np.clip(np.zeros(spec.control_size), spec.lower, spec.upper)
    interrupted = False
    with (
        ProgressBar(steps, label or f"{run.name}/{controller.solver_name}", progress) as bar,
        remember_interrupts(),
    ):
        try:
            loop.warm_up(x0, u_prev)
            loop.run_steps(log, u_prev, bar)
        except KeyboardInterrupt:
            interrupted = True
            interrupt_handled()
    closed_loop = schedule.recorded(log.result(times, currents, run, controller.solver_name, interrupted))
    if detector is not None:
        closed_loop = _detected(closed_loop, detector, log.estimated_health, log.dither)
    if interrupted:
        raise SimulationInterrupted(closed_loop)
    return closed_loop


def _fault_detector(
    options: object, problem: Any, estimator: Estimator | None, health_known: bool, allocation: object
) -> ThrusterFaultDetector | None:
    """Return the run's fault detector (``None`` without options); ``ValueError`` names what is missing."""
    if options is None:
        return None
    if not isinstance(options, FaultDetectorOptions):
        raise ValueError(
            f"fault_detector must be a uuv_ocp.FaultDetectorOptions or None, got {type(options).__name__}"
        )
    if health_known or allocation is not None:
        raise ValueError(
            "fault_detector tells the controller the estimated health: not with health_known=True "
            "(the oracle) nor allocation= (the pseudo-inverse baseline)"
        )
    thrusters = getattr(getattr(problem, "vehicle", None), "thrusters", None)
    if thrusters is None:
        raise ValueError(
            "fault_detector needs a TrackingProblem whose vehicle has thrusters (thrusters=True)"
        )
    if estimator is None or estimator.model.nb != thrusters.allocation.shape[1]:
        raise ValueError(
            "fault_detector needs estimator= with EstimatorOptions(bias=True): the detector regresses "
            "its thruster-force bias"
        )
    return ThrusterFaultDetector(np.array(thrusters.allocation), options, bounds=thrusters.max_thrust)


def _dither(
    detector: ThrusterFaultDetector | None, problem: Any, dt: float, t0: float
) -> NullSpaceDither | None:
    """Return the run's null-space dither (``None`` without a detector or with amplitude 0)."""
    if detector is None or not detector.options.dither.active:
        return None
    vehicle = problem.vehicle
    return NullSpaceDither(
        detector.allocation,
        detector.options.dither,
        bounds=vehicle.control_bound,
        rate_bounds=vehicle.control_rate_bound,
        dt=dt,
        t0=t0,
    )


def _detected(
    result: ClosedLoopResult, detector: ThrusterFaultDetector, health: np.ndarray, dither: np.ndarray
) -> ClosedLoopResult:
    """Return ``result`` with the detector's detections, per-step estimated health and dither."""
    n = result.controls.shape[0]
    rows = [
        (item.time, item.thruster, item.health, item.offset) for item in detector.detections if item.step < n
    ]
    detections = np.array(rows, dtype=float).reshape(-1, 4)
    return dataclasses.replace(
        result, detections=detections, estimated_health=health[:n].copy(), dither=dither[:n].copy()
    )


def _check_noise(noise: MeasurementNoise | None, state_dim: int) -> None:
    """Refuse full-state noise whose size is not the state's (``ValueError`` naming ``noise.std``)."""
    if noise is not None and len(noise.std) != state_dim:
        raise ValueError(f"noise.std must have {state_dim} entries (one per state), got {len(noise.std)}")


def _sampled_currents(
    current: Current | None, steps: int, nc: int, dt: float, rng: np.random.Generator
) -> np.ndarray:
    """Return the true current at every control instant, shape (steps + 1, nc) (m/s; zeros if nc = 0)."""
    currents = np.zeros((steps + 1, nc))
    if nc:
        sampled = (current or Current()).sample(steps, dt, rng)
        currents[:, : sampled.shape[1]] = sampled
    return currents


def _current_estimated(estimator: Estimator | None, current_known: bool, nc: int) -> bool:
    """Whether the controller is told the estimated current; ``ValueError`` if the loop cannot pass it."""
    # an estimator that models no current (current_model="none") leaves the controller naive
    estimating = estimator is not None and not current_known and estimator.model.nc > 0
    if estimating and estimator is not None and estimator.model.nc != nc:
        # e.g. an Ocp whose "current" parameter the estimator estimates: the loop has no channel
        # to hand it to the controller (its current is in parameters=), so say so
        raise ValueError(
            f"estimator estimates a current of {estimator.model.nc} entries but this closed loop "
            f"passes the controller a current of {nc} (an Ocp takes its data in parameters=); "
            "set options.current_parameter to a stagewise parameter the loop hands over, or "
            "current_known=True"
        )
    return estimating and nc > 0


@dataclass(frozen=True)
class _Loop:
    """What every step of one :func:`simulate` run reads; its steps write into a :class:`_Log`.

    ``times`` are the control instants (s); ``clock`` the times the controller is asked at
    (zeros for a time-invariant problem); ``currents`` the true current per instant and
    ``told`` what the controller's model is told of it (m/s); ``estimated``: the controller
    gets the estimator's current instead.
    """

    controller: Controller
    run: Any
    dt: float
    times: np.ndarray
    currents: np.ndarray
    told: np.ndarray
    clock: np.ndarray
    known: dict[str, Any]
    rng: np.random.Generator
    noise: MeasurementNoise | None
    estimator: Estimator | None
    sensors: Sensors | None
    estimated: bool
    schedule: FaultSchedule
    detector: ThrusterFaultDetector | None = None
    dither: NullSpaceDither | None = None

    def warm_up(self, x0: np.ndarray, u_prev: np.ndarray) -> None:
        """Build what the controller's steps build (once per controller), or reset it if built."""
        # everything the steps build (sqp-rti's C step, the cold start's NLP) is built here,
        # not in the first timed steps (once per controller: builds stay with its backend)
        controller = self.controller
        if controller.warmed_up:
            controller.reset()
        else:
            told = self.told[0] if self.run.current_dim else None
            controller.warm_up(x0, self.clock[0], u_prev, told, **self.known)

    def run_steps(self, log: _Log, u_prev: np.ndarray, bar: ProgressBar) -> None:
        """Run the steps one after the other until the end, a fault or an interrupt."""
        for k in range(self.run.steps):
            check_interrupt()  # a Ctrl-C CasADi swallowed (uuv_ocp.interrupts) stops here
            if not self.step(log, k, u_prev):
                break
            u_prev = log.controls[k]
            bar.update(1, postfix=f"fail={int(log.fallback[: k + 1].sum())}")

    def step(self, log: _Log, k: int, u_prev: np.ndarray) -> bool:
        """Measure, control and move the plant over step ``k``; ``False`` (``log.fault`` set) ends the run."""
        measured, told_k = self.measure(log, k, u_prev)
        # the controller would fail on it (an estimator that diverged gives finite but absurd
        # states, 1e74 on a two-fault pseudo-inverse run): a fault that ends the run, no exception
        if not np.all(np.isfinite(measured)):
            log.fault = f"non-finite measurement at t = {self.times[k]:.6g} s (step {k})"
            return False
        if np.max(np.abs(measured)) > BLOW_UP:
            log.fault = f"measurement beyond {BLOW_UP:g} at t = {self.times[k]:.6g} s (step {k})"
            return False
        told = self.schedule.told(k, self.known)
        if self.detector is not None and self.detector.detections:  # the estimated health
            detector = self.detector
            told = {"parameters": {"health": detector.health.copy(), "thrust_offset": detector.offset.copy()}}
        start = time.perf_counter()  # the controller's step alone, not the loop's bookkeeping
        output = self.controller.step(measured, self.clock[k], u_prev, told_k, **told)
        log.controller_step(k, output, time.perf_counter() - start)
        if self.dither is not None:  # the thrusters get the plan plus the null-space dither
            self.dithered(log, k, u_prev)
        plant_step = self.schedule.plant_step(self.run.plant_step, k)
        return log.plant_step(k, plant_step, self.currents[k], self.times)

    def dithered(self, log: _Log, k: int, u_prev: np.ndarray) -> None:
        """Add the null-space dither to step ``k``'s control (scaled within the box and rate bound).

        ``u_prev`` is the last *applied* command: the NMPC's rate bound is around it, and so is the
        dither's (:mod:`uuv_ocp.control.dither`); the estimator and the detector see the applied
        commands too (what the plant got), the NMPC's plan is ``controls − dither``.
        """
        assert self.dither is not None
        detector = self.detector
        # reallocated around isolated faults: the null space of T diag(ĥ), so it stays wrench-free
        health = detector.health.copy() if detector is not None and detector.detections else None
        planned = log.controls[k].copy()
        log.controls[k] = self.dither.applied(self.times[k], planned, u_prev, health)
        log.dither[k] = log.controls[k] - planned

    def measure(self, log: _Log, k: int, u_prev: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Return what the controller gets at step ``k``: the measured (or estimated) state and current."""
        told_k = self.told[k] if self.run.current_dim else None
        if self.estimator is None or self.sensors is None:
            noise = self.noise.sample(self.rng) if self.noise is not None else 0.0
            return log.states[k] + noise, told_k
        estimator = self.estimator
        nx = estimator.model.nx  # the controller's own states after these (a path parameter)
        measurement = self.sensors.measure(k, self.dt, log.states[k, :nx], self.rng)
        start = time.perf_counter()
        estimate = estimator.correct(measurement) if k == 0 else estimator.step(u_prev, measurement)
        log.estimate(k, measurement, estimate, time.perf_counter() - start)
        if self.detector is not None and k > 0:  # the bias after the interval u_prev moved it
            self.detector.update(k, self.times[k], u_prev, estimate.bias)
            log.estimated_health[k] = self.detector.estimate
        state = estimate.state if estimator.model.own == 0 else np.r_[estimate.state, log.states[k, nx:]]
        # the controller is told the low-passed current (EstimatorOptions.current_filter; the
        # estimate itself by default): the filter's step-to-step wander would move the fins
        return state, (estimate.current_filtered if self.estimated else told_k)


def _check_arguments(
    controller: object,
    current: object,
    noise: object,
    seed: object,
    current_known: object,
    progress: object,
    record_substeps: object,
) -> None:
    """Refuse a bad argument of :func:`simulate` by name, before anything is built."""
    if not isinstance(controller, Controller):  # the protocol's members, not a class
        raise ValueError(
            "controller must be a uuv_ocp.NMPC, a uuv_ocp.LosGuidance or another Controller "
            f"(problem, solver_name, warmed_up, reset, warm_up, step), got {type(controller).__name__}"
        )
    if current_known is not None:
        check.boolean("current_known", current_known)
    check.boolean("progress", progress)
    check.boolean("record_substeps", record_substeps)
    if seed is not None:
        check.positive_int("seed", seed, minimum=0)
    if current is not None and not isinstance(current, Current):
        raise ValueError(f"current must be a uuv_ocp.Current or None, got {current!r}")
    if noise is not None and not isinstance(noise, MeasurementNoise):
        raise ValueError(f"noise must be a uuv_ocp.MeasurementNoise or None, got {noise!r}")


def _check_estimation(
    controller: Controller, estimator: object, sensors: object, noise: object
) -> Sensors | None:
    """Return the sensors of a run with an estimator (``None`` without); ``ValueError`` names the argument."""
    if estimator is None:
        if sensors is not None:
            raise ValueError(
                "sensors needs an estimator: pass estimator=uo.Estimator(problem, 'ekf', sensors=...)"
            )
        return None
    if not isinstance(estimator, Estimator):
        raise ValueError(f"estimator must be a uuv_ocp.Estimator or None, got {type(estimator).__name__}")
    if estimator.problem.spec().key != controller.problem.spec().key:
        raise ValueError(
            "estimator must be built on the controller's problem (its model is the controller's)"
        )
    if noise is not None:
        raise ValueError(
            "noise is the full-state noise of a run without an estimator; the sensors carry theirs"
        )
    if sensors is not None and sensors != estimator.sensors:
        raise ValueError("sensors must be the estimator's own (estimator.sensors), or None")
    return estimator.sensors


class _Log:
    """What a closed loop records, step by step; ``completed`` steps of it are the run."""

    def __init__(self, x0: np.ndarray, steps: int, control_size: int, substeps: int, dt: float) -> None:
        nx = x0.size
        self.dt = dt
        self.states = np.empty((steps + 1, nx))
        self.states[0] = x0
        self.controls = np.zeros((steps, control_size))
        self.solve_times = np.zeros(steps)
        self.iterations = np.zeros(steps, dtype=int)
        self.fallback = np.zeros(steps, dtype=bool)
        self.relaxed = np.zeros(steps, dtype=bool)
        self.deadline = np.zeros(steps, dtype=bool)
        self.statuses: list[str] = []
        self.substeps = substeps  # plant steps recorded per interval (0: none)
        self.path = np.empty((steps * substeps + 1, nx) if substeps else (0, nx))
        if substeps:
            self.path[0] = x0
        self.completed = 0
        self.fault: str | None = None
        self.estimation: dict[str, Any] = {}
        self.estimated_health = np.zeros((steps, 0))
        self.dither = np.zeros((steps, 0))

    def track_estimates(self, estimator: Estimator, sensors: Sensors) -> None:
        """Make room for the estimates and measurements of every step."""
        steps, model = len(self.controls), estimator.model
        m = int(sum(sensors.sizes))
        self.estimation = {
            "estimated_states": np.full((steps, model.nx), np.nan),
            "estimated_currents": np.full((steps, model.nc), np.nan),
            "estimate_variances": np.full((steps, model.size), np.nan),
            "innovations": np.full((steps, m), np.nan),
            "estimate_times": np.zeros(steps),
            "innovation_variances": np.full((steps, m), np.nan),
            "measurement_values": np.full((steps, m), np.nan),
            "measurement_dropped": np.zeros((steps, len(sensors)), dtype=bool),
        }
        self.sensors = sensors

    def estimate(self, k: int, measurement: Measurement, estimate: Estimate, elapsed: float) -> None:
        """Record step ``k``'s measurements and the estimate the controller gets."""
        log = self.estimation
        rows = self.sensors.rows(measurement.sensors)
        log["estimated_states"][k] = estimate.state
        log["estimated_currents"][k] = estimate.current
        log["estimate_variances"][k] = np.diag(estimate.covariance)
        log["innovations"][k, rows] = estimate.innovations
        if estimate.innovation_covariance.shape == (rows.size, rows.size):  # else unknown: NaN
            log["innovation_variances"][k, rows] = np.diag(estimate.innovation_covariance)
        log["estimate_times"][k] = elapsed
        log["measurement_values"][k, rows] = measurement.values
        log["measurement_dropped"][k, list(measurement.dropped)] = True

    def controller_step(self, k: int, output: Any, elapsed: float) -> None:
        """Record step ``k``'s control and how it was obtained (an NMPC step record)."""
        result = output.result
        self.solve_times[k] = elapsed
        self.controls[k] = output.control
        self.fallback[k] = output.fallback
        self.deadline[k] = output.deadline_hit
        if result is not None:
            self.iterations[k] = result.iterations
            self.relaxed[k] = result.terminal_relaxed
        # a refused plan's reason (a NaN plan's "success" is no success), else the status
        self.statuses.append(
            (output.message or "fallback") if output.fallback or result is None else result.status
        )

    def plant_step(self, k: int, plant_step: Any, current: np.ndarray, times: np.ndarray) -> bool:
        """Move the plant over interval ``k``; ``False`` (with ``fault`` set) if it failed or blew up."""
        try:
            path = plant_step(self.states[k], self.controls[k], current)
        except Exception as error:  # CasADi's evaluation errors: a fault, not a lost run
            # ... except Ctrl-C, which CasADi reports from inside a call as a RuntimeError
            reraise_interrupt(error)
            self.fault = (
                f"plant exception at t = {times[k]:.6g} s (step {k}): {type(error).__name__}: {error}"
            )
            return False
        path = np.array(path, dtype=float).T  # (plant_substeps, nx)
        next_state = path[-1]
        if not np.all(np.isfinite(next_state)) or np.max(np.abs(next_state)) > BLOW_UP:
            self.fault = (
                f"plant blew up at t = {times[k + 1]:.6g} s (step {k}): state not finite or "
                f"beyond {BLOW_UP:g} in magnitude"
            )
            return False
        self.states[k + 1] = next_state
        if self.substeps:
            self.path[k * self.substeps + 1 : (k + 1) * self.substeps + 1] = path
        self.completed = k + 1
        return True

    def result(
        self, times: np.ndarray, currents: np.ndarray, run: Any, solver: str, interrupted: bool
    ) -> ClosedLoopResult:
        """Return the run up to its last completed step."""
        n, s = self.completed, self.substeps
        recorded: dict[str, Any] = {}
        if self.estimation:
            recorded = {key: value[:n] for key, value in self.estimation.items()}
            recorded["sensor_names"] = self.sensors.names
            recorded["sensor_sizes"] = self.sensors.sizes
        if s:
            recorded.update(
                {
                    # built from the control instants, so that substep_t[::s] is t exactly
                    "substep_t": np.append((times[:n, None] + self.dt / s * np.arange(s)).ravel(), times[n]),
                    "substep_states": self.path[: n * s + 1],
                }
            )
        return ClosedLoopResult(
            t=times[: n + 1],
            states=self.states[: n + 1],
            controls=self.controls[:n],
            reference=run.reference(times[: n + 1]),
            solve_times=self.solve_times[:n],
            iterations=self.iterations[:n],
            fallback_steps=self.fallback[:n],
            relaxed_steps=self.relaxed[:n],
            currents=currents[: n + 1],
            statuses=tuple(self.statuses[:n]),
            solver=solver,
            interrupted=interrupted,
            deadline_steps=self.deadline[:n],
            fault=self.fault,
            state_names=run.state_names,
            state_units=run.state_units,
            state_roles=run.state_roles,
            **recorded,
        )
