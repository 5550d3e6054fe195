"""Closed-loop simulation: an NMPC controller against a finely integrated plant.

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

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import serialised
from uuv_ocp.control.disturbances import Current, MeasurementNoise
from uuv_ocp.control.metrics import tracking_metrics
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.integrators import rk4_path
from uuv_ocp.interrupts import check_interrupt, interrupt_handled, remember_interrupts
from uuv_ocp.model.base import check_vehicle, model_function
from uuv_ocp.progress import ProgressBar
from uuv_ocp.solvers.base import reraise_interrupt
from uuv_ocp.tracking import TrackingProblem, vehicle_dimensions, warn_if_reference_too_fast
from uuv_ocp.transcription.multiple_shooting import parameter_blocks

#: A plant state entry larger than this in magnitude (SI units) counts as a blow-up fault; below the
#: plausibility bound (``_validation.PLAUSIBLE_MAGNITUDE``) past which the controller refuses a state.
BLOW_UP = 1e8


class SimulationInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`simulate`; ``result`` holds the run up to the interrupt."""

    def __init__(self, result: ClosedLoopResult) -> None:
        super().__init__(f"simulation interrupted after {result.controls.shape[0]} steps")
        self.result = result


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
        empty for an Ocp's run): plots find x, y, ψ, u, ... by name.
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
        """Position errors ``[x − x_R, y − y_R]`` (m), shape (n+1, 2)."""
        return self.states[:, :2] - self.reference[:, :2]

    def metrics(self, settle_time: float = 5.0) -> dict[str, float | int]:
        """Tracking and timing metrics (see :func:`uuv_ocp.control.metrics.tracking_metrics`)."""
        return tracking_metrics(self, settle_time=settle_time)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every field as a numpy array, by field name: what :meth:`save` writes.

        The plant sub-steps only when recorded, so that runs without them keep their files.
        """
        recorded = {"substep_t": self.substep_t, "substep_states": self.substep_states}
        named = {"state_names": np.array(self.state_names, dtype=str)} if self.state_names else {}
        return dict(
            **(recorded if self.substep_t.size else {}),
            **named,
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
            state_names=tuple(str(name) for name in data["state_names"]) if "state_names" in data else (),
        )


def simulate(
    controller: NMPC,
    x0: object,
    duration: float,
    *,
    t0: float | None = None,
    current: Current | None = None,
    current_known: bool = True,
    noise: MeasurementNoise | None = None,
    plant: Any = None,
    plant_substeps: int = 10,
    seed: int | None = None,
    progress: bool = False,
    label: str = "",
    parameters: dict[str, Any] | None = None,
    record_substeps: bool = False,
) -> ClosedLoopResult:
    """Run ``controller`` in closed loop for ``duration`` seconds.

    Parameters
    ----------
    controller : NMPC
        The controller: warmed up unless it was already (:meth:`NMPC.warm_up
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
    current_known : bool
        Whether the controller's model is told the current measured at each step.
    noise : MeasurementNoise, optional
        Noise on the state the controller sees (one standard deviation per state).
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
    if not isinstance(controller, NMPC):
        raise ValueError(f"controller must be a uuv_ocp.NMPC, got {type(controller).__name__}")
    problem = controller.problem
    spec = problem.spec()
    nx, nu = spec.state_dim, spec.control_size
    tracking = isinstance(problem, TrackingProblem)
    x0 = check.finite_array("x0", x0, (nx,))
    duration = check.positive_float("duration", duration)
    plant_substeps = check.positive_int("plant_substeps", plant_substeps)
    check.boolean("current_known", current_known)
    check.boolean("progress", progress)
    check.boolean("record_substeps", record_substeps)
    if seed is not None:
        seed = check.positive_int("seed", seed, minimum=0)
    if current is not None and not isinstance(current, Current):
        raise ValueError(f"current must be a uuv_ocp.Current or None, got {current!r}")
    if noise is not None and not isinstance(noise, MeasurementNoise):
        raise ValueError(f"noise must be a uuv_ocp.MeasurementNoise or None, got {noise!r}")
    dt = spec.dt
    if isinstance(problem, TrackingProblem):  # `tracking`, spelt so that type checkers narrow
        if parameters is not None:  # it was ignored without a word
            raise ValueError(
                "parameters is for an Ocp; a TrackingProblem takes its parameters from the reference "
                f"(t0) and current=, got parameters={check.shown(parameters)}"
            )
        reference = problem.reference
        t0 = reference.t_start if t0 is None else problem.check_time(t0)
        available = problem.latest_start() - t0
        if duration > available + 1e-9:
            warnings.warn(
                f"duration shortened from {duration} s to {available:.6g} s: the horizon must stay inside "
                f"the reference window [{reference.t_start}, {reference.t_end}] s",
                RuntimeWarning,
                stacklevel=2,
            )
        steps = int(np.floor(min(duration, available) / dt + 1e-9))
        if steps < 1:
            raise ValueError(
                f"duration {duration} s from t0 = {t0} s leaves no full control interval inside "
                f"the reference window [{reference.t_start}, {reference.t_end}] s"
            )
        plant_step, nc = _vehicle_plant(problem, plant, dt, plant_substeps)
        window = np.minimum(t0 + dt * np.arange(steps + problem.horizon + 1), reference.t_end)
        warn_if_reference_too_fast(reference, problem.vehicle if plant is None else plant, window)
    else:
        if current is not None:
            raise ValueError("current is for tracking problems; an Ocp's plant is a Function f(x, u)")
        t0 = 0.0 if t0 is None else check.finite_float("t0", t0)
        steps = max(1, int(np.floor(duration / dt + 1e-9)))
        plant_step, nc = _ocp_plant(problem, plant, parameters, dt, plant_substeps), 0
    if noise is not None and len(noise.std) != nx:
        raise ValueError(f"noise.std must have {nx} entries (one per state), got {len(noise.std)}")
    rng = np.random.default_rng(seed)
    currents = np.zeros((steps + 1, nc))
    if tracking and nc:
        sampled = (current or Current()).sample(steps, dt, rng)
        currents[:, : sampled.shape[1]] = sampled
    times = t0 + dt * np.arange(steps + 1)

    states = np.empty((steps + 1, nx))
    states[0] = x0
    controls = np.zeros((steps, nu))
    solve_times = np.zeros(steps)
    iterations = np.zeros(steps, dtype=int)
    substeps = np.empty((steps * plant_substeps + 1, nx) if record_substeps else (0, nx))
    if record_substeps:
        substeps[0] = x0
    fallback = np.zeros(steps, dtype=bool)
    relaxed = np.zeros(steps, dtype=bool)
    deadline_steps = np.zeros(steps, dtype=bool)
    statuses: list[str] = []
    u_prev = np.clip(np.zeros(nu), spec.lower, spec.upper)
    completed = 0
    interrupted = False
    fault: str | None = None
    name = problem.reference.name if isinstance(problem, TrackingProblem) else spec.name
    with (
        ProgressBar(steps, label or f"{name}/{controller.solver_name}", progress) as bar,
        remember_interrupts(),
    ):
        try:
            # everything the steps build (sqp-rti's C step, the cold start's NLP) is built here,
            # not in the first timed steps (once per controller: builds stay with its backend)
            if controller.warmed_up:
                controller.reset()
            elif tracking:
                controller.warm_up(x0, t0, u_prev, currents[0] if current_known else np.zeros(nc))
            else:
                controller.warm_up(x0, 0.0, u_prev, parameters=parameters)
            for k in range(steps):
                check_interrupt()  # a Ctrl-C CasADi swallowed (uuv_ocp.interrupts) stops here
                measured = states[k] + (noise.sample(rng) if noise is not None else 0.0)
                if not np.all(np.isfinite(measured)):  # the controller would fail on it: stop here
                    fault = f"non-finite measurement at t = {times[k]:.6g} s (step {k})"
                    break
                start = time.perf_counter()
                if tracking:
                    model_current = currents[k] if current_known else np.zeros(nc)
                    output = controller.step(measured, times[k], u_prev, model_current)
                else:
                    output = controller.step(measured, 0.0, u_prev, parameters=parameters)
                solve_times[k] = time.perf_counter() - start
                result = output.result
                controls[k] = output.control
                fallback[k] = output.fallback
                deadline_steps[k] = output.deadline_hit
                if result is not None:
                    iterations[k] = result.iterations
                    relaxed[k] = result.terminal_relaxed
                # a refused plan's reason (a NaN plan's "success" is no success), else the status
                statuses.append(
                    (output.message or "fallback") if output.fallback or result is None else result.status
                )
                try:
                    if tracking:
                        path = plant_step(states[k], controls[k], currents[k])
                    else:
                        path = plant_step(states[k], controls[k])
                except Exception as error:  # CasADi's evaluation errors: a fault, not a lost run
                    # ... except Ctrl-C, which CasADi reports from inside a call as a RuntimeError
                    reraise_interrupt(error)
                    fault = (
                        f"plant exception at t = {times[k]:.6g} s (step {k}): {type(error).__name__}: {error}"
                    )
                    break
                path = np.array(path, dtype=float).T  # (plant_substeps, nx)
                next_state = path[-1]
                if not np.all(np.isfinite(next_state)) or np.max(np.abs(next_state)) > BLOW_UP:
                    fault = (
                        f"plant blew up at t = {times[k + 1]:.6g} s (step {k}): state not finite or "
                        f"beyond {BLOW_UP:g} in magnitude"
                    )
                    break
                states[k + 1] = next_state
                if record_substeps:
                    substeps[k * plant_substeps + 1 : (k + 1) * plant_substeps + 1] = path
                u_prev = controls[k]
                completed = k + 1
                bar.update(1, postfix=f"fail={int(fallback[: k + 1].sum())}")
        except KeyboardInterrupt:
            interrupted = True
            interrupt_handled()
    n = completed
    run = ClosedLoopResult(
        t=times[: n + 1],
        states=states[: n + 1],
        controls=controls[:n],
        reference=(
            problem.vehicle.layout.reference_state(problem.reference.evaluate(times[: n + 1]))
            if isinstance(problem, TrackingProblem)
            else np.full((n + 1, nx), np.nan)
        ),
        solve_times=solve_times[:n],
        iterations=iterations[:n],
        fallback_steps=fallback[:n],
        relaxed_steps=relaxed[:n],
        currents=currents[: n + 1],
        statuses=tuple(statuses[:n]),
        solver=controller.solver_name,
        interrupted=interrupted,
        deadline_steps=deadline_steps[:n],
        fault=fault,
        state_names=tuple(problem.vehicle.layout.state_names) if isinstance(problem, TrackingProblem) else (),
        **(
            {
                # built from the control instants, so that substep_t[::s] is t exactly
                "substep_t": np.append(
                    (times[:n, None] + dt / plant_substeps * np.arange(plant_substeps)).ravel(), times[n]
                ),
                "substep_states": substeps[: n * plant_substeps + 1],
            }
            if record_substeps
            else {}
        ),
    )
    if interrupted:
        raise SimulationInterrupted(run)
    return run


def _vehicle_plant(problem: TrackingProblem, plant: Any, dt: float, substeps: int) -> tuple[ca.Function, int]:
    """RK4 plant path ``(x, u, current) -> (nx, substeps)`` of a vehicle with the problem's state."""
    vehicle = problem.vehicle if plant is None else plant
    check_vehicle("plant", vehicle)
    if vehicle_dimensions(vehicle) != vehicle_dimensions(problem.vehicle):
        raise ValueError(
            f"plant must have the controller model's dimensions {vehicle_dimensions(problem.vehicle)} "
            f"(states, controls, current), got {vehicle_dimensions(vehicle)}"
        )
    dynamics = model_function("plant", vehicle)
    return rk4_path(dynamics, dt, substeps, name="plant_step"), vehicle_dimensions(vehicle)[2]


@serialised
def _ocp_plant(problem: Any, plant: Any, parameters: Any, dt: float, substeps: int) -> ca.Function:
    """RK4 plant path ``(x, u) -> (nx, substeps)``: ``plant`` or the Ocp's dynamics at ``parameters``."""
    spec = problem.spec()
    if plant is None:
        p = problem.parameters(np.zeros(spec.state_dim), parameters, None)
        x, u = ca.SX.sym("x", spec.state_dim), ca.SX.sym("u", spec.control_size)
        _, _, pg, nodes = parameter_blocks(spec, ca.SX(ca.DM(p)))
        plant = ca.Function("plant", [x, u], [spec.dynamics(x, u, nodes[0], pg)], ["x", "u"], ["xdot"])
    if not isinstance(plant, ca.Function) or plant.n_in() != 2:
        raise ValueError(f"plant must be a casadi.Function f(x, u) -> xdot for an Ocp, got {plant!r}")
    return rk4_path(plant, dt, substeps, name="plant_step")
