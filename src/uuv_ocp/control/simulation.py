"""Closed-loop simulation: an NMPC controller against a finely integrated plant.

The plant is the vehicle model (possibly with different parameters: model mismatch) integrated
with RK4 at ``plant_substeps`` steps per control interval (default 10, i.e. 10 ms for
dt = 0.1 s), under a Gauss–Markov current; the controller sees the state plus optional
measurement noise.  A :class:`KeyboardInterrupt` stops the loop early and returns everything
computed so far (``interrupted=True``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.control.disturbances import Current, MeasurementNoise
from uuv_ocp.integrators import rk4_step
from uuv_ocp.control.metrics import tracking_metrics
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.progress import ProgressBar
from uuv_ocp.model.planar import Vehicle


@dataclass(frozen=True)
class ClosedLoopResult:
    """Everything a closed-loop run produced.

    Parameters
    ----------
    t : numpy.ndarray, shape (n+1,)
        Sample times (s).
    states : numpy.ndarray, shape (n+1, 6)
        True plant states.
    controls : numpy.ndarray, shape (n, 3)
        Applied controls (N, N, N·m).
    reference : numpy.ndarray, shape (n+1, 6)
        Reference states at ``t`` (continuous heading).
    solve_times : numpy.ndarray, shape (n,)
        Wall-clock time of each controller step (s).
    iterations : numpy.ndarray, shape (n,)
        Solver iterations per step.
    fallback_steps : numpy.ndarray of bool, shape (n,)
        Steps where the fallback control was applied.
    relaxed_steps : numpy.ndarray of bool, shape (n,)
        Steps solved with the soft terminal constraint.
    currents : numpy.ndarray, shape (n+1, 2)
        Inertial current velocity (m/s).
    statuses : tuple of str
        Solver status per step.
    solver : str
        Solver name.
    interrupted : bool
        Whether the run was stopped early by the user.
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
    info: dict = field(default_factory=dict, compare=False)

    @property
    def failures(self) -> int:
        """Number of steps where the solver failed and the fallback was applied."""
        return int(np.sum(self.fallback_steps))

    @property
    def errors(self) -> np.ndarray:
        """Position errors ``[x − x_R, y − y_R]`` (m), shape (n+1, 2)."""
        return self.states[:, :2] - self.reference[:, :2]

    def metrics(self, settle_time: float = 5.0) -> dict[str, float]:
        """Tracking and timing metrics (see :func:`uuv_ocp.control.metrics.tracking_metrics`)."""
        return tracking_metrics(self, settle_time=settle_time)

    def save(self, path: str) -> None:
        """Write all arrays to a compressed ``.npz`` file."""
        np.savez_compressed(
            path,
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
        )

    @classmethod
    def load(cls, path: str) -> ClosedLoopResult:
        """Read a result written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
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
    plant: Vehicle | None = None,
    plant_substeps: int = 10,
    seed: int | None = None,
    progress: bool = False,
    label: str = "",
) -> ClosedLoopResult:
    """Run ``controller`` in closed loop for ``duration`` seconds.

    Parameters
    ----------
    controller : NMPC
        The controller (reset before the run).
    x0 : array_like, shape (6,)
        Initial plant state.
    duration : float
        Simulated time (s), > 0; shortened to stay inside the reference window.
    t0 : float, optional
        Start time on the reference (s); the reference's ``t_start`` by default.
    current : Current, optional
        Ocean current acting on the plant.
    current_known : bool
        Whether the controller's model is told the current measured at each step.
    noise : MeasurementNoise, optional
        Noise on the state the controller sees.
    plant : Vehicle, optional
        Plant parameters (default: the controller's own model, i.e. no mismatch).
    plant_substeps : int
        RK4 steps of the plant per control interval, >= 1.
    seed : int, optional
        Seed for current and noise.
    progress : bool
        Show a progress bar.
    label : str
        Progress-bar label.
    """
    if not isinstance(controller, NMPC):
        raise ValueError(f"controller must be a uuv_ocp.NMPC, got {type(controller).__name__}")
    problem = controller.problem
    reference = problem.reference
    x0 = problem.check_state(x0)
    duration = check.positive_float("duration", duration)
    t0 = reference.t_start if t0 is None else problem.check_time(t0)
    plant_substeps = check.positive_int("plant_substeps", plant_substeps)
    if plant is not None and not isinstance(plant, Vehicle):
        raise ValueError(f"plant must be a uuv_ocp.Vehicle or None, got {type(plant).__name__}")
    plant = plant or problem.vehicle
    dt = problem.dt
    steps = int(np.floor(min(duration, problem.latest_start() - t0) / dt + 1e-9))
    if steps < 1:
        raise ValueError(
            f"duration {duration} s from t0 = {t0} s leaves no full control interval inside "
            f"the reference window [{reference.t_start}, {reference.t_end}] s"
        )
    rng = np.random.default_rng(seed)
    plant_step = rk4_step(plant.dynamics_function(), dt, plant_substeps, name="plant_step")
    currents = (current or Current()).sample(steps, dt, rng)
    times = t0 + dt * np.arange(steps + 1)

    states = np.empty((steps + 1, 6))
    states[0] = x0
    controls = np.zeros((steps, 3))
    solve_times = np.zeros(steps)
    iterations = np.zeros(steps, dtype=int)
    fallback = np.zeros(steps, dtype=bool)
    relaxed = np.zeros(steps, dtype=bool)
    statuses: list[str] = []
    controller.reset()
    u_prev = np.zeros(3)
    completed = 0
    interrupted = False
    with ProgressBar(steps, label or f"{problem.reference.name}/{controller.solver_name}", progress) as bar:
        try:
            for k in range(steps):
                measured = states[k] + (noise.sample(rng) if noise is not None else 0.0)
                model_current = currents[k] if current_known else np.zeros(2)
                start = time.perf_counter()
                output = controller.step(measured, times[k], u_prev, model_current)
                solve_times[k] = time.perf_counter() - start
                result = output.result
                controls[k] = output.control
                fallback[k] = output.fallback
                if result is not None:
                    iterations[k] = result.iterations
                    relaxed[k] = result.terminal_relaxed
                    statuses.append(result.status)
                else:
                    statuses.append("exception")
                next_state = plant_step(states[k], controls[k], currents[k])
                states[k + 1] = np.array(next_state, dtype=float).ravel()
                u_prev = controls[k]
                completed = k + 1
                bar.update(1, postfix=f"fail={int(fallback[: k + 1].sum())}")
        except KeyboardInterrupt:
            interrupted = True
    n = completed
    return ClosedLoopResult(
        t=times[: n + 1],
        states=states[: n + 1],
        controls=controls[:n],
        reference=reference.evaluate(times[: n + 1]),
        solve_times=solve_times[:n],
        iterations=iterations[:n],
        fallback_steps=fallback[:n],
        relaxed_steps=relaxed[:n],
        currents=currents[: n + 1],
        statuses=tuple(statuses[:n]),
        solver=controller.solver_name,
        interrupted=interrupted,
    )
