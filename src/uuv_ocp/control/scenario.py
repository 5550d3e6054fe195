"""What a closed loop needs of a problem: its time window, plant, current and reference.

:func:`~uuv_ocp.control.simulation.simulate` runs one loop for every kind of problem; what
differs between an :class:`~uuv_ocp.ocp.Ocp` (time-invariant, a plant ``f(x, u)``, its data in
``parameters``) and a :class:`~uuv_ocp.tracking.TrackingProblem` (a reference window, a
vehicle plant under an ocean current) is gathered here in one :class:`Scenario`, made by
:func:`scenario`.  A new kind of problem registers its own maker with
``scenario.register(MyProblem)`` (:func:`functools.singledispatch`), so the loop never asks
what kind of problem it runs.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import serialised
from uuv_ocp.integrators import rk4_path
from uuv_ocp.model.base import check_vehicle, model_function
from uuv_ocp.ocp import Ocp
from uuv_ocp.tracking import TrackingProblem, vehicle_dimensions, warn_if_reference_too_fast
from uuv_ocp.transcription.multiple_shooting import parameter_blocks


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run's view of its problem (built by :func:`scenario`).

    Attributes
    ----------
    t0 : float
        Start time (s).
    steps : int
        Control intervals to run, >= 1.
    plant_step : casadi.Function
        ``(x, u, current) -> path`` of shape ``(nx, substeps)``: the plant over one interval
        (``current`` has ``current_dim`` entries, none for an Ocp).
    current_dim : int
        Entries of the ocean current the plant and the controller's model take (m/s).
    time_varying : bool
        Whether an instance depends on the time: if not, the controller is given ``t = 0``.
    name : str
        Label of the run (progress bar).
    state_names : tuple of str
        Names of the states, in order.
    state_units : tuple of str
        Their units (empty strings where unknown).
    state_roles : tuple of str
        Their roles (:attr:`VehicleLayout.state_roles <uuv_ocp.model.base.VehicleLayout.state_roles>`;
        empty strings for an Ocp's states).
    reference : callable
        ``reference(times) -> (len(times), nx)`` reference states (NaN where there is none).
    """

    t0: float
    steps: int
    plant_step: ca.Function
    current_dim: int
    time_varying: bool
    name: str
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    state_roles: tuple[str, ...]
    reference: Callable[[np.ndarray], np.ndarray]


@functools.singledispatch
def scenario(
    problem: Any,
    *,
    t0: float | None,
    duration: float,
    plant: Any,
    parameters: Mapping[str, Any] | None,
    current: Any,
    substeps: int,
) -> Scenario:
    """Return the :class:`Scenario` of a closed loop of ``duration`` s on ``problem``.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
        The controller's problem (another kind registers its own maker).
    t0 : float or None
        Start time (s); the problem's natural start when ``None``.
    duration : float
        Requested simulated time (s), > 0 (checked by the caller).
    plant : object
        The plant (``None``: the problem's own model), as :func:`simulate` documents.
    parameters : dict or None
        An Ocp's parameter values for the run.
    current : Current or None
        The ocean current on the plant.
    substeps : int
        RK4 steps of the plant per control interval.
    """
    raise ValueError(
        f"controller.problem must be an Ocp or a TrackingProblem (or a kind registered with "
        f"uuv_ocp.control.scenario.scenario.register), got {type(problem).__name__}"
    )


@scenario.register
def _tracking(
    problem: TrackingProblem,
    *,
    t0: float | None,
    duration: float,
    plant: Any,
    parameters: Mapping[str, Any] | None,
    current: Any,
    substeps: int,
) -> Scenario:
    if parameters is not None:  # it was ignored without a word
        raise ValueError(
            "parameters is for an Ocp; a TrackingProblem takes its parameters from the reference "
            f"(t0) and current=, got parameters={check.shown(parameters)}"
        )
    reference, dt = problem.reference, problem.dt
    start = reference.t_start if t0 is None else problem.check_time(t0)
    available = problem.latest_start() - start
    if duration > available + 1e-9:
        warnings.warn(
            f"duration shortened from {duration} s to {available:.6g} s: the horizon must stay inside "
            f"the reference window [{reference.t_start}, {reference.t_end}] s",
            RuntimeWarning,
            stacklevel=4,
        )
    steps = int(np.floor(min(duration, available) / dt + 1e-9))
    if steps < 1:
        raise ValueError(
            f"duration {duration} s from t0 = {start} s leaves no full control interval inside "
            f"the reference window [{reference.t_start}, {reference.t_end}] s"
        )
    plant_step, current_dim = vehicle_plant(problem, plant, dt, substeps)
    window = np.minimum(start + dt * np.arange(steps + problem.horizon + 1), reference.t_end)
    warn_if_reference_too_fast(reference, problem.vehicle if plant is None else plant, window, stacklevel=5)
    layout = problem.vehicle.layout
    return Scenario(
        t0=start,
        steps=steps,
        plant_step=plant_step,
        current_dim=current_dim,
        time_varying=True,
        name=reference.name,
        state_names=tuple(layout.state_names),
        state_units=tuple(layout.state_units),
        state_roles=layout.state_roles,
        reference=lambda times: layout.reference_state(reference.evaluate(times)),
    )


@scenario.register
def _ocp(
    problem: Ocp,
    *,
    t0: float | None,
    duration: float,
    plant: Any,
    parameters: Mapping[str, Any] | None,
    current: Any,
    substeps: int,
) -> Scenario:
    if current is not None:
        raise ValueError("current is for tracking problems; an Ocp's plant is a Function f(x, u)")
    spec = problem.spec()
    nx = spec.state_dim
    return Scenario(
        t0=0.0 if t0 is None else check.finite_float("t0", t0),
        steps=max(1, int(np.floor(duration / spec.dt + 1e-9))),
        plant_step=ocp_plant(problem, plant, parameters, spec.dt, substeps),
        current_dim=0,
        time_varying=False,
        name=spec.name,
        state_names=problem.state_names,
        state_units=("",) * nx,
        state_roles=("",) * nx,
        reference=lambda times: np.full((len(times), nx), np.nan),
    )


def vehicle_plant(problem: TrackingProblem, plant: Any, dt: float, substeps: int) -> tuple[ca.Function, int]:
    """RK4 plant path ``(x, u, current) -> (nx, substeps)`` of a vehicle with the problem's state."""
    dynamics = plant_dynamics(problem.vehicle, plant)
    return rk4_path(dynamics, dt, substeps, name="plant_step"), vehicle_dimensions(problem.vehicle)[2]


def plant_dynamics(model: Any, plant: Any) -> ca.Function:
    """Dynamics Function of the plant vehicle (``None``: the controller's ``model``), checked against it."""
    vehicle = model if plant is None else plant
    check_vehicle("plant", vehicle)
    if vehicle_dimensions(vehicle) != vehicle_dimensions(model):
        raise ValueError(
            f"plant must have the controller model's dimensions {vehicle_dimensions(model)} "
            f"(states, controls, current), got {vehicle_dimensions(vehicle)}"
        )
    return model_function("plant", vehicle)


@serialised
def ocp_plant(problem: Ocp, plant: Any, parameters: Any, dt: float, substeps: int) -> ca.Function:
    """RK4 plant path ``(x, u, current) -> (nx, substeps)`` of an Ocp (``current`` is empty).

    ``plant`` is a Function ``f(x, u) -> xdot``; ``None`` takes the Ocp's own dynamics at
    ``parameters``.
    """
    spec = problem.spec()
    x, u = ca.SX.sym("x", spec.state_dim), ca.SX.sym("u", spec.control_size)
    if plant is None:
        p = problem.parameters(np.zeros(spec.state_dim), parameters, None)
        _, _, pg, nodes = parameter_blocks(spec, ca.SX(ca.DM(p)))
        plant = ca.Function("plant", [x, u], [spec.dynamics(x, u, nodes[0], pg)], ["x", "u"], ["xdot"])
    if not isinstance(plant, ca.Function) or plant.n_in() != 2:
        raise ValueError(f"plant must be a casadi.Function f(x, u) -> xdot for an Ocp, got {plant!r}")
    # one signature for every plant: (x, u, current), the current empty here (MX: a user's
    # plant may be an MX Function)
    path = rk4_path(plant, dt, substeps, name="plant_path")
    xm, um = ca.MX.sym("x", spec.state_dim), ca.MX.sym("u", spec.control_size)
    c = ca.MX.sym("current", 0)
    return ca.Function("plant_step", [xm, um, c], [path(xm, um)], ["x", "u", "current"], ["path"])
