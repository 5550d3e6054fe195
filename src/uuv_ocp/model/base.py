"""What a vehicle model provides: the :class:`VehicleModel` protocol and its :class:`VehicleLayout`.

:class:`~uuv_ocp.TrackingProblem`, :func:`~uuv_ocp.simulate`, the plots and the CLI use a vehicle
only through this protocol, so a vehicle class written outside the package (a 4-DOF vessel, a
craft whose controls are propeller speeds and fin angles) works everywhere the built-in
:class:`~uuv_ocp.model.planar.Vehicle` and :class:`~uuv_ocp.model.fossen6dof.Vehicle6DOF` do.

A vehicle provides

* ``name`` (str) and ``layout`` (:class:`VehicleLayout`): state and control names and units,
  which states are positions, angles (their errors are wrapped) and the heading, the velocity
  block, the length of the current vector and the kind of reference it tracks;
* ``control_bound`` and ``control_rate_bound``: symmetric bounds on each control (its own unit)
  and on its rate (unit per second);
* ``model_function()``: the continuous-time dynamics as a :class:`casadi.Function`
  ``(x[nx], u[nu], current[nc]) -> xdot[nx]``, ``u`` in the vehicle's own control units.

Optionally, a vehicle whose model takes parameters that may change between controller steps
without a rebuild (thruster health, say) provides

* ``model_parameters``: a tuple of :class:`ModelParameter` (name, size, default, bounds, unit);
* ``parametric_model_function()``: the dynamics ``(x, u, current, *values) -> xdot`` with one
  input per declared parameter, in order, equal to ``model_function()`` at the defaults.

:class:`~uuv_ocp.TrackingProblem` declares each one as a global parameter of its Ocp (passed
as ``parameters={name: value}`` to ``NMPC.step``/``prepare``/``uo.solve``; the defaults when
omitted); a vehicle that declares none is used exactly as before.

The state is ordered pose first, then the velocities (the trailing ``layout.velocities`` block):
the tracking cost weighs the pose with ``Weights.pose`` and the velocities with
``Weights.velocity``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import casadi as ca
import numpy as np

from uuv_ocp._concurrency import BUILD_LOCK

REFERENCE_KINDS = ("planar", "spatial")
# the states a Reference gives (Reference.evaluate), by kind; a vehicle state of the same name
# takes that column of the reference, any other state is referenced to zero
REFERENCE_STATE_NAMES: dict[str, tuple[str, ...]] = {
    "planar": ("x", "y", "psi", "u", "v", "r"),
    "spatial": ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r"),
}


def _names(field: str, value: object) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Sequence) or not value:
        raise ValueError(f"{field} must be a non-empty sequence of strings, got {value!r}")
    if not all(isinstance(item, str) and item for item in value):
        raise ValueError(f"{field} must hold non-empty strings, got {value!r}")
    return tuple(value)


def _indices(field: str, value: object, size: int) -> tuple[int, ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise ValueError(f"{field} must be a sequence of state indices, got {value!r}")
    if not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in value):
        raise ValueError(f"{field} must hold integer state indices, got {value!r}")
    indices = tuple(int(i) for i in value)
    if any(not 0 <= i < size for i in indices) or len(set(indices)) != len(indices):
        raise ValueError(f"{field} must be distinct indices in [0, {size}), got {indices!r}")
    return indices


@dataclass(frozen=True)
class VehicleLayout:
    """Names, units and roles of a vehicle's states and controls.

    Parameters
    ----------
    state_names, state_units : sequence of str
        One name and unit per state (m, rad, m/s, rad/s, or the actuator's unit for an
        actuator state).  Names shared with the reference (``x``, ``y``, ``z``, ``phi``,
        ``theta``, ``psi``, ``u``, ``v``, ``w``, ``p``, ``q``, ``r``) take the reference's value;
        the other states are referenced to zero.
    control_names, control_units : sequence of str
        One name and unit per control (N, N·m, or actuator units: rad/s, rad, ...).
    positions : sequence of int
        Indices of the inertial positions, horizontal first: ``(x, y)`` or ``(x, y, z)``.
    angles : sequence of int
        Indices of the Euler angles; their errors enter the cost wrapped as ``2 sin(e/2)``.
    heading : int
        Index of the yaw angle ψ (one of ``angles``): its reference is moved to the vehicle's
        branch of 2π.
    velocities : sequence of int
        Indices of the body velocities: the trailing block of the state (the pose comes first).
    current_dim : int
        Length of the current vector the dynamics take (m/s; 2 horizontal, 3 spatial).
    reference : {"planar", "spatial"}
        Kind of :class:`~uuv_ocp.Reference` the vehicle tracks (``Reference.from_xy``/paper
        references, or ``from_xyz``/``waypoints``/``hold``).
    """

    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    control_names: tuple[str, ...]
    control_units: tuple[str, ...]
    positions: tuple[int, ...]
    angles: tuple[int, ...]
    heading: int
    velocities: tuple[int, ...]
    current_dim: int
    reference: str = "planar"

    def __post_init__(self) -> None:
        """Check the names, units and indices against each other (``ValueError`` names the field)."""
        set_field = object.__setattr__
        for field in ("state_names", "state_units", "control_names", "control_units"):
            set_field(self, field, _names(f"layout.{field}", getattr(self, field)))
        nx, nu = len(self.state_names), len(self.control_names)
        if len(self.state_units) != nx:
            raise ValueError(
                f"layout.state_units must have {nx} entries (one per state), got {self.state_units!r}"
            )
        if len(self.control_units) != nu:
            raise ValueError(
                f"layout.control_units must have {nu} entries (one per control), got {self.control_units!r}"
            )
        for field, names in (("state_names", self.state_names), ("control_names", self.control_names)):
            if len(set(names)) != len(names):
                raise ValueError(f"layout.{field} must be distinct, got {names!r}")
        for field in ("positions", "angles", "velocities"):
            set_field(self, field, _indices(f"layout.{field}", getattr(self, field), nx))
        if len(self.positions) not in (2, 3):
            raise ValueError(f"layout.positions must give (x, y) or (x, y, z), got {self.positions!r}")
        if isinstance(self.heading, bool) or not isinstance(self.heading, (int, np.integer)):
            raise ValueError(f"layout.heading must be a state index, got {self.heading!r}")
        set_field(self, "heading", int(self.heading))
        if self.heading not in self.angles:
            raise ValueError(f"layout.heading must be one of layout.angles {self.angles}, got {self.heading}")
        if self.velocities != tuple(range(nx - len(self.velocities), nx)) or not self.velocities:
            raise ValueError(
                f"layout.velocities must be the trailing block of the state (indices "
                f"{nx - len(self.velocities)}..{nx - 1}), got {self.velocities!r}"
            )
        pose = set(range(self.pose_dim))
        for field in ("positions", "angles"):
            if not set(getattr(self, field)) <= pose:
                raise ValueError(
                    f"layout.{field} must lie in the pose block [0, {self.pose_dim}), "
                    f"got {getattr(self, field)!r}"
                )
        if set(self.positions) & set(self.angles):
            raise ValueError(
                f"layout.positions {self.positions} and layout.angles {self.angles} must not overlap"
            )
        if isinstance(self.current_dim, bool) or not isinstance(self.current_dim, (int, np.integer)):
            raise ValueError(f"layout.current_dim must be an integer >= 1, got {self.current_dim!r}")
        if self.current_dim < 1:
            raise ValueError(f"layout.current_dim must be an integer >= 1, got {self.current_dim!r}")
        set_field(self, "current_dim", int(self.current_dim))
        if self.reference not in REFERENCE_KINDS:
            raise ValueError(f"layout.reference must be one of {REFERENCE_KINDS}, got {self.reference!r}")

    # ------------------------------------------------------------------ sizes
    @property
    def state_dim(self) -> int:
        """Length of the state."""
        return len(self.state_names)

    @property
    def control_dim(self) -> int:
        """Length of the control."""
        return len(self.control_names)

    @property
    def pose_dim(self) -> int:
        """Length of the pose block (the states before the velocities)."""
        return self.state_dim - len(self.velocities)

    # ------------------------------------------------------------- reference
    @functools.cached_property  # read by reference_state on every step of a closed loop (10 µs)
    def reference_columns(self) -> tuple[int | None, ...]:
        """For each state, its column in the reference state (by name), or ``None`` (zero)."""
        names = REFERENCE_STATE_NAMES[self.reference]
        return tuple(names.index(name) if name in names else None for name in self.state_names)

    @property
    def reference_dim(self) -> int:
        """Length of the reference state the vehicle's kind of reference gives (6 or 12)."""
        return len(REFERENCE_STATE_NAMES[self.reference])

    @property
    def state_roles(self) -> tuple[str, ...]:
        """Role of each state, for plots and metrics that do not know the vehicle.

        ``"x"``, ``"y"``, ``"z"`` for the positions (in order), ``"psi"`` for the heading,
        ``"velocity"`` for a body velocity, ``""`` for any other state.
        """
        roles = [""] * self.state_dim
        for role, index in zip(("x", "y", "z"), self.positions, strict=False):
            roles[index] = role
        roles[self.heading] = "psi"
        for index in self.velocities:
            roles[index] = "velocity"
        return tuple(roles)

    def reference_state(self, samples: np.ndarray) -> np.ndarray:
        """Map reference samples (Reference.evaluate) to reference states of this vehicle.

        Parameters
        ----------
        samples : numpy.ndarray, shape (n, reference_dim)
            Rows ``[x_R, y_R, ψ_R, u_R, v_R, r_R]`` (planar) or the 12 spatial states.

        Returns
        -------
        numpy.ndarray, shape (n, state_dim)
            Each state of a reference name takes that column; the others are zero.  When the
            vehicle's state is the reference state itself, ``samples`` is returned as is.
        """
        columns = self.reference_columns
        if columns == tuple(range(samples.shape[1])):
            return samples
        states = np.zeros((samples.shape[0], self.state_dim))
        for index, column in enumerate(columns):
            if column is not None:
                states[:, index] = samples[:, column]
        return states


#: Parameter names a TrackingProblem uses itself (a vehicle's model parameters must not take them).
RESERVED_PARAMETER_NAMES = ("reference", "current")


@dataclass(frozen=True)
class ModelParameter:
    """A parameter of a vehicle's dynamics that a controller may change at every step.

    Parameters
    ----------
    name : str
        Its name in ``parameters={name: value}`` (not ``reference``, ``current`` or
        ``obstacle<i>``).
    size : int
        Number of entries, >= 1.
    default : sequence of float
        The value when none is given (``size`` finite numbers inside the bounds).
    lower, upper : sequence of float
        Bounds of each entry (finite, ``lower <= upper``); a value outside is refused.
    unit : str
        Unit of the entries (``"1"`` for a dimensionless one).
    """

    name: str
    size: int
    default: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    unit: str = "1"

    def __post_init__(self) -> None:
        """Check name, size, bounds and default (``ValueError`` names the field)."""
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"model parameter name must be an identifier, got {self.name!r}")
        if self.name in RESERVED_PARAMETER_NAMES or self.name.startswith("obstacle"):
            raise ValueError(
                f"model parameter name must not be one of {RESERVED_PARAMETER_NAMES} or obstacle<i> "
                f"(a TrackingProblem's own parameters), got {self.name!r}"
            )
        if isinstance(self.size, bool) or not isinstance(self.size, (int, np.integer)) or self.size < 1:
            raise ValueError(
                f"model parameter {self.name!r}: size must be an integer >= 1, got {self.size!r}"
            )
        object.__setattr__(self, "size", int(self.size))
        for field in ("default", "lower", "upper"):
            try:
                value = np.array(getattr(self, field), dtype=float)
            except (TypeError, ValueError) as error:
                raise ValueError(
                    f"model parameter {self.name!r}: {field} must be {self.size} numbers, got "
                    f"{getattr(self, field)!r}"
                ) from error
            if value.shape != (self.size,) or not np.all(np.isfinite(value)):
                raise ValueError(
                    f"model parameter {self.name!r}: {field} must be {self.size} finite numbers, got "
                    f"{getattr(self, field)!r}"
                )
            object.__setattr__(self, field, tuple(float(v) for v in value))
        lower, upper, default = (np.array(v) for v in (self.lower, self.upper, self.default))
        if np.any(lower > upper):
            raise ValueError(
                f"model parameter {self.name!r}: lower must be <= upper, got {self.lower} and {self.upper}"
            )
        if np.any(default < lower) or np.any(default > upper):
            raise ValueError(
                f"model parameter {self.name!r}: default must lie in [lower, upper], got {self.default}"
            )
        if not isinstance(self.unit, str):
            raise ValueError(f"model parameter {self.name!r}: unit must be a string, got {self.unit!r}")

    def check(self, value: object) -> np.ndarray:
        """Return ``value`` as a float array of shape (size,) inside the bounds, else ``ValueError``."""
        try:
            array = np.array(value, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"parameters[{self.name!r}] must be {self.size} numbers ({self.unit}), got {value!r}"
            ) from error
        if array.shape == () and self.size == 1:
            array = array.reshape(1)
        if array.shape != (self.size,) or not np.all(np.isfinite(array)):
            raise ValueError(
                f"parameters[{self.name!r}] must be {self.size} finite numbers ({self.unit}), got "
                f"shape {array.shape}: {value!r}"
            )
        lower, upper = np.array(self.lower), np.array(self.upper)
        bad = np.flatnonzero((array < lower) | (array > upper))
        if bad.size:
            i = int(bad[0])
            unit = "" if self.unit == "1" else f" {self.unit}"
            raise ValueError(
                f"parameters[{self.name!r}][{i}] must lie in [{lower[i]:g}, {upper[i]:g}]{unit}, "
                f"got {float(array[i])!r}"
            )
        return array


def model_parameters(vehicle: object) -> tuple[ModelParameter, ...]:
    """Return the :class:`ModelParameter` s a vehicle declares (``()`` for one that declares none).

    Raises
    ------
    ValueError
        If ``model_parameters`` is not a tuple of distinct ModelParameter, or the vehicle lacks
        ``parametric_model_function``.
    """
    declared = getattr(vehicle, "model_parameters", ())
    if declared is None or declared == ():
        return ()
    if not isinstance(declared, tuple) or not all(isinstance(item, ModelParameter) for item in declared):
        raise ValueError(
            f"vehicle.model_parameters must be a tuple of uuv_ocp.model.base.ModelParameter, got {declared!r}"
        )
    names = [item.name for item in declared]
    if len(set(names)) != len(names):
        raise ValueError(f"vehicle.model_parameters must have distinct names, got {names}")
    if not callable(getattr(vehicle, "parametric_model_function", None)):
        raise ValueError(
            "a vehicle that declares model_parameters must provide parametric_model_function() "
            "(x, u, current, *values) -> xdot"
        )
    return declared


@runtime_checkable
class VehicleModel(Protocol):
    """What :class:`~uuv_ocp.TrackingProblem`, :func:`~uuv_ocp.simulate`, plots and the CLI need.

    ``isinstance(vehicle, VehicleModel)`` checks that the members exist (not their types).
    """

    name: str

    @property
    def layout(self) -> VehicleLayout:
        """Names, units and roles of the states and controls."""
        ...

    @property
    def control_bound(self) -> tuple[float, ...]:
        """Symmetric bound on each control (its unit in ``layout.control_units``), > 0."""
        ...

    @property
    def control_rate_bound(self) -> tuple[float, ...]:
        """Bound on each control's rate of change (its unit per second), > 0."""
        ...

    def model_function(self) -> ca.Function:
        """Dynamics ``(x[nx], u[nu], current[nc]) -> xdot[nx]`` (continuous time)."""
        ...


def check_vehicle(name: str, vehicle: object) -> VehicleModel:
    """Return ``vehicle`` if it implements :class:`VehicleModel` with a consistent layout.

    Raises
    ------
    ValueError
        Naming ``name``, the missing member or the inconsistent size.
    """
    if not isinstance(vehicle, VehicleModel):
        missing = [
            member
            for member in ("name", "layout", "control_bound", "control_rate_bound", "model_function")
            if not hasattr(vehicle, member)
        ]
        raise ValueError(
            f"{name} must implement uuv_ocp.VehicleModel (a Vehicle, Vehicle6DOF or your own class with "
            f"name, layout, control_bound, control_rate_bound, model_function()), got "
            f"{type(vehicle).__name__} without {', '.join(missing)}"
        )
    layout = vehicle.layout
    if not isinstance(layout, VehicleLayout):
        raise ValueError(f"{name}.layout must be a uuv_ocp.VehicleLayout, got {type(layout).__name__}")
    for member in ("control_bound", "control_rate_bound"):
        bound = np.asarray(getattr(vehicle, member), dtype=float)
        if bound.shape != (layout.control_dim,) or not np.all(np.isfinite(bound)) or np.any(bound <= 0):
            raise ValueError(
                f"{name}.{member} must be {layout.control_dim} finite numbers > 0 (one per control), "
                f"got {getattr(vehicle, member)!r}"
            )
    return vehicle


def model_function(name: str, vehicle: VehicleModel) -> ca.Function:
    """Return ``vehicle.model_function()`` after checking its inputs and output against the layout.

    Raises
    ------
    ValueError
        Naming ``name`` and the expected and actual sizes.
    """
    with BUILD_LOCK:  # a user's class builds CasADi graphs here, which threads must not do at once
        function = vehicle.model_function()
    layout = vehicle.layout
    expected = ((layout.state_dim, 1), (layout.control_dim, 1), (layout.current_dim, 1))
    if not isinstance(function, ca.Function) or function.n_in() != 3 or function.n_out() != 1:
        raise ValueError(
            f"{name}.model_function() must return a casadi.Function (x, u, current) -> xdot, got {function!r}"
        )
    sizes = tuple(function.size_in(i) for i in range(3))
    if sizes != expected or function.size_out(0) != (layout.state_dim, 1):
        raise ValueError(
            f"{name}.model_function() must map column vectors of sizes {[s[0] for s in expected]} "
            f"(state, control, current) to {layout.state_dim} derivatives, got inputs "
            f"{[s for s in sizes]} and output {function.size_out(0)}"
        )
    return function


def parametric_model_function(name: str, vehicle: VehicleModel) -> ca.Function:
    """Return the dynamics ``(x, u, current, *values) -> xdot`` of a vehicle's model parameters.

    ``vehicle.parametric_model_function()`` checked against the layout and
    ``model_parameters`` (one input per parameter, of its size); for a vehicle that declares
    none, :func:`model_function`.

    Raises
    ------
    ValueError
        Naming ``name`` and the expected and actual sizes.
    """
    declared = model_parameters(vehicle)
    if not declared:
        return model_function(name, vehicle)
    with BUILD_LOCK:  # a user's class builds CasADi graphs here
        function = vehicle.parametric_model_function()  # type: ignore[attr-defined]
    layout = vehicle.layout
    expected = [(layout.state_dim, 1), (layout.control_dim, 1), (layout.current_dim, 1)]
    expected += [(item.size, 1) for item in declared]
    if not isinstance(function, ca.Function) or function.n_out() != 1:
        raise ValueError(
            f"{name}.parametric_model_function() must return a casadi.Function, got {function!r}"
        )
    sizes = [function.size_in(i) for i in range(function.n_in())]
    if sizes != expected or function.size_out(0) != (layout.state_dim, 1):
        raise ValueError(
            f"{name}.parametric_model_function() must map column vectors of sizes "
            f"{[s[0] for s in expected]} (state, control, current, then "
            f"{', '.join(item.name for item in declared)}) to {layout.state_dim} derivatives, got "
            f"inputs {sizes} and output {function.size_out(0)}"
        )
    return function
