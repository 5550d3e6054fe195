"""Thruster faults injected into a closed loop, and the plant-side pseudo-inverse allocation.

A :class:`ThrusterFault` says that thruster ``i`` loses effectiveness, sticks or fails at a
time.  :func:`~uuv_ocp.simulate` takes a tuple of them (``faults=``) and turns it into a
:class:`FaultSchedule`: the true health ``h`` and known force offset ``s`` of every thruster
on every control interval.  The plant then delivers the thruster forces ``h ∘ f + s`` for the
commanded ``f`` (a stuck thruster: ``h_i = 0``, ``s_i`` its frozen force; a failed one:
``h_i = 0``, ``s_i = 0``), i.e. the generalised force ``τ = T (h ∘ f + s)``, the same model a
thruster :class:`~uuv_ocp.model.fossen6dof.Vehicle6DOF` declares through its ``health`` and
``thrust_offset`` model parameters.  The controller is told the true values only in the
oracle mode (``health_known=True``); otherwise its model keeps the defaults (healthy).

Time grid: a fault acts from the first control instant ``t0 + k dt`` at or after its time
(to 1e-9 of an interval), and the plant's health is held over each interval: the schedule
is indexed by the integer step ``k``, never by comparing floating-point times.

The pseudo-inverse baseline (``allocation=`` of :func:`~uuv_ocp.simulate`) is a plant-side
option: an NMPC planning the generalised force τ on the 6-DOF force model, whose τ is mapped
to thruster forces by the pseudo-inverse of the *healthy* allocation matrix, clipped to each
thruster's bound, ``f = clip(T⁺ τ)``; the faults then act on ``f`` and the plant (a force
model) receives ``T (h ∘ f + s)``.  This is the fixed allocation most stacks use: it does not
react to a fault.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.model.thrusters import GENERALISED_FORCE_NAMES, ThrusterConfiguration

FAULT_KINDS = ("loss", "stuck", "failed")
#: A fault whose time is within this fraction of an interval after a control instant acts
#: from that instant (the times ``k dt`` are not exact in floating point).
GRID_TOLERANCE = 1e-9


@dataclass(frozen=True)
class ThrusterFault:
    """One thruster's fault from a time on.

    Parameters
    ----------
    thruster : int
        Index of the thruster (0-based: the column of the allocation matrix, the control
        ``f_{thruster + 1}`` of a thruster vehicle).
    time : float
        When the fault starts (s, on the run's clock ``run.t``), finite and >= 0.
    kind : {"loss", "stuck", "failed"}
        ``"loss"``: the thruster delivers ``effectiveness`` times its command; ``"stuck"``: it
        delivers ``value`` (N) whatever its command; ``"failed"``: it delivers nothing.
    effectiveness : float, optional
        For ``"loss"`` only (required): the remaining effectiveness in [0, 1].
    value : float, optional
        For ``"stuck"`` only (required): the frozen force (N), finite; it must lie within the
        thruster's bound (checked by :func:`fault_schedule`).
    """

    thruster: int
    time: float
    kind: str = "failed"
    effectiveness: float | None = None
    value: float | None = None

    def __post_init__(self) -> None:
        """Check each field and that the kind has exactly its own argument (``ValueError``)."""
        set_field = object.__setattr__
        set_field(self, "thruster", check.positive_int("thruster", self.thruster, minimum=0))
        set_field(self, "time", check.nonnegative_float("time", self.time))
        check.choice("kind", self.kind, FAULT_KINDS)
        needs = {"loss": "effectiveness", "stuck": "value", "failed": None}[self.kind]
        for name in ("effectiveness", "value"):
            given = getattr(self, name) is not None
            if name == needs and not given:
                raise ValueError(f"{name} is required for kind={self.kind!r}, got None")
            if name != needs and given:
                raise ValueError(
                    f"{name} is for kind={'loss' if name == 'effectiveness' else 'stuck'!r} only, got "
                    f"{name}={getattr(self, name)!r} with kind={self.kind!r}"
                )
        if self.effectiveness is not None:
            effectiveness = check.finite_float("effectiveness", self.effectiveness)
            if not 0.0 <= effectiveness <= 1.0:
                raise ValueError(f"effectiveness must lie in [0, 1], got {effectiveness!r}")
            set_field(self, "effectiveness", effectiveness)
        if self.value is not None:
            set_field(self, "value", check.finite_float("value", self.value))

    @property
    def health(self) -> float:
        """Effectiveness of the thruster once the fault acts (1 means none lost)."""
        return self.effectiveness if self.effectiveness is not None else 0.0

    @property
    def offset(self) -> float:
        """Force (N) the thruster delivers whatever its command once the fault acts."""
        return self.value if self.value is not None else 0.0


@dataclass(frozen=True)
class FaultSchedule:
    """The plant's true thruster health over a run, and what the controller is told of it.

    Built by :func:`fault_schedule`.  ``health[k]`` and ``offset[k]`` hold over control
    interval ``k`` (from ``t0 + k dt`` to ``t0 + (k+1) dt``).

    Attributes
    ----------
    health : numpy.ndarray, shape (steps, n)
        True effectiveness of each thruster on each interval, in [0, 1].
    offset : numpy.ndarray, shape (steps, n)
        Known force of each thruster on each interval (N): a stuck thruster's value, else 0.
    health_known : bool
        Whether the controller is told ``health[k]`` and ``offset[k]`` at step ``k`` (oracle).
    allocation : numpy.ndarray or None, shape (6, n)
        The healthy allocation matrix of the plant-side pseudo-inverse allocation, or ``None``
        when the controls are the thruster forces themselves.
    bounds : numpy.ndarray, shape (n,)
        Each thruster's force bound (N): the allocation's clip.
    forces : numpy.ndarray, shape (steps, n)
        Filled during the run: the force each thruster delivered (N), ``h ∘ f + s``.
    """

    health: np.ndarray
    offset: np.ndarray
    health_known: bool
    allocation: np.ndarray | None
    bounds: np.ndarray
    forces: np.ndarray
    pseudo_inverse: np.ndarray | None = None

    @property
    def active(self) -> bool:
        """Whether the run has faults or an allocation (else the loop runs as without them)."""
        return self.health.shape[1] > 0

    def commanded_forces(self, control: np.ndarray) -> np.ndarray:
        """Thruster forces commanded by a control: itself, or ``clip(T⁺ τ)`` with an allocation."""
        if self.pseudo_inverse is None:
            return np.asarray(control, dtype=float)
        return np.clip(self.pseudo_inverse @ control, -self.bounds, self.bounds)

    def plant_control(self, k: int, control: np.ndarray) -> np.ndarray:
        """Return the control the plant receives on interval ``k``; record the delivered forces."""
        delivered = self.health[k] * self.commanded_forces(control) + self.offset[k]
        self.forces[k] = delivered  # the array's contents, not the frozen field, change
        return delivered if self.allocation is None else self.allocation @ delivered

    def plant_step(self, plant_step: Callable[..., Any], k: int) -> Callable[..., Any]:
        """``plant_step`` with interval ``k``'s faults applied to its control (itself if none)."""
        if not self.active:
            return plant_step

        def faulty(state: np.ndarray, control: np.ndarray, current: np.ndarray) -> Any:
            return plant_step(state, self.plant_control(k, control), current)

        return faulty

    def told(self, k: int, known: dict[str, Any]) -> dict[str, Any]:
        """Keyword arguments of the controller's step ``k``: ``known``, plus the health if told."""
        if not self.health_known:
            return known
        return {"parameters": {"health": self.health[k].copy(), "thrust_offset": self.offset[k].copy()}}

    def recorded(self, result: Any) -> Any:
        """Return ``result`` (a ClosedLoopResult) with the true health and delivered forces of its steps."""
        if not self.active:
            return result
        n = result.controls.shape[0]
        return dataclasses.replace(
            result, thruster_health=self.health[:n].copy(), thruster_forces=self.forces[:n].copy()
        )


def fault_schedule(
    faults: object,
    problem: Any,
    *,
    steps: int,
    t0: float,
    health_known: object = False,
    allocation: object = None,
) -> FaultSchedule:
    """Return the :class:`FaultSchedule` of a run of ``steps`` intervals from ``t0``.

    Parameters
    ----------
    faults : sequence of ThrusterFault
        At most one per thruster and time; a later fault of a thruster replaces its earlier one.
    problem : TrackingProblem
        The controller's problem.  Without ``allocation`` its vehicle's controls must be
        thruster forces (it declares the ``health`` model parameter, one per control).
    steps : int
        Control intervals of the run.
    t0 : float
        Start time (s); the intervals start at ``t0 + k dt``.
    health_known : bool
        Tell the controller the true health (and stuck forces) at each step (oracle).
    allocation : ThrusterConfiguration, optional
        Map the controller's generalised force to these thrusters by the pseudo-inverse of
        their healthy allocation matrix (module doc); the problem's vehicle then plans the six
        generalised forces ``X, Y, Z, K, M, N``.

    Raises
    ------
    ValueError
        Naming the argument: not a tuple of ThrusterFault, a thruster index out of range, a
        stuck value beyond the thruster's bound, two faults of one thruster at one time, a
        problem without thruster controls, ``health_known`` with an allocation.
    """
    from uuv_ocp.tracking import TrackingProblem

    health_known = check.boolean("health_known", health_known)
    if isinstance(faults, ThrusterFault) or not isinstance(faults, Sequence) or isinstance(faults, str):
        raise ValueError(f"faults must be a tuple of uuv_ocp.ThrusterFault, got {faults!r}")
    faults = tuple(faults)
    for i, fault in enumerate(faults):
        if not isinstance(fault, ThrusterFault):
            raise ValueError(f"faults[{i}] must be a uuv_ocp.ThrusterFault, got {fault!r}")
    if allocation is not None and not isinstance(allocation, ThrusterConfiguration):
        raise ValueError(f"allocation must be a uuv_ocp.ThrusterConfiguration or None, got {allocation!r}")
    if not (faults or allocation is not None or health_known):
        return _inactive(steps)
    if not isinstance(problem, TrackingProblem):
        raise ValueError(
            f"faults, health_known and allocation need a TrackingProblem, got a {type(problem).__name__}"
        )
    layout = problem.vehicle.layout
    matrix: np.ndarray | None = None
    pseudo_inverse: np.ndarray | None = None
    if allocation is not None:
        if tuple(layout.control_names) != GENERALISED_FORCE_NAMES:
            raise ValueError(
                f"allocation maps a generalised force {GENERALISED_FORCE_NAMES} to thrusters: the "
                f"controller's vehicle must plan in it, got controls {layout.control_names}"
            )
        if health_known:
            raise ValueError(
                "health_known=True needs a controller whose model takes the health (a vehicle with "
                "thrusters); the pseudo-inverse allocation (allocation=) is the baseline that ignores it"
            )
        matrix = allocation.allocation
        pseudo_inverse = np.linalg.pinv(matrix)
        bounds = np.array(allocation.max_thrust)
    else:
        names = {item.name: item.size for item in problem.model_parameters}
        if names.get("health") != layout.control_dim or names.get("thrust_offset") != layout.control_dim:
            raise ValueError(
                f"faults and health_known need a vehicle whose controls are thruster forces (it declares "
                f"the model parameters health and thrust_offset, one per control), or allocation=; "
                f"vehicle {getattr(problem.vehicle, 'name', '?')!r} declares {sorted(names) or 'none'}"
            )
        bounds = np.asarray(problem.vehicle.control_bound, dtype=float)
    count = bounds.size
    seen: set[tuple[int, float]] = set()
    for i, fault in enumerate(faults):
        if fault.thruster >= count:
            raise ValueError(
                f"faults[{i}].thruster must be an index in [0, {count}) (the vehicle's thrusters), "
                f"got {fault.thruster}"
            )
        if fault.kind == "stuck" and abs(fault.offset) > bounds[fault.thruster]:
            raise ValueError(
                f"faults[{i}].value must lie within thruster {fault.thruster}'s bound "
                f"±{bounds[fault.thruster]:g} N, got {fault.value!r}"
            )
        if (fault.thruster, fault.time) in seen:
            raise ValueError(
                f"faults[{i}] is a second fault of thruster {fault.thruster} at t = {fault.time} s; "
                "give one fault per thruster and time"
            )
        seen.add((fault.thruster, fault.time))
    health = np.ones((steps, count))
    offset = np.zeros((steps, count))
    dt = problem.dt
    for fault in sorted(faults, key=lambda item: item.time):  # a later fault replaces an earlier one
        first = fault_step(fault.time, t0, dt)
        health[first:, fault.thruster] = fault.health
        offset[first:, fault.thruster] = fault.offset
    return FaultSchedule(
        health, offset, health_known, matrix, bounds, np.zeros((steps, count)), pseudo_inverse
    )


def fault_step(time: float, t0: float, dt: float) -> int:
    """Index of the first control interval a fault at ``time`` acts on (0 if it precedes ``t0``)."""
    return max(0, math.ceil((time - t0) / dt - GRID_TOLERANCE))


def _inactive(steps: int) -> FaultSchedule:
    """Return the schedule of a run without faults or allocation: the loop's own plant and controller."""
    empty = np.zeros((steps, 0))
    return FaultSchedule(empty, empty, False, None, np.zeros(0), empty)


@dataclass(frozen=True)
class RandomFaults:
    """Thruster faults drawn at random per trial (campaigns: ``CampaignConfig(faults=...)``).

    :meth:`draw` picks ``count`` distinct thrusters uniformly, a time for each uniform in
    ``window`` (s after the run's start), and a kind uniform among ``kinds``: ``"failed"`` (no
    force), ``"loss"`` (``effectiveness`` of the command remains) or ``"stuck"`` (a force of a
    random sign and a magnitude uniform in ``stuck_range`` times the thruster's bound).  All of it
    from the one ``numpy.random.Generator`` it is given, so a trial's faults follow its seed.

    Parameters
    ----------
    count : int
        Thrusters that fault in each trial, >= 0 (0: none, the trial's fault-free twin).
    window : tuple of float
        ``(earliest, latest)`` fault time after the run's start (s), 0 <= earliest <= latest.
    kinds : tuple of str
        Non-empty, distinct, among ``"failed"``, ``"loss"``, ``"stuck"``.  Default: a complete
        failure or a loss, the issue's "complete failure or 50 % loss".
    effectiveness : float
        Remaining effectiveness of a ``"loss"``, in [0, 1).  Default 0.5.
    stuck_range : tuple of float
        ``(low, high)`` magnitude of a stuck force as a fraction of the thruster's bound,
        0 <= low <= high <= 1.  Default (0.25, 0.75).
    """

    count: int = 1
    window: tuple[float, float] = (5.0, 15.0)
    kinds: tuple[str, ...] = ("failed", "loss")
    effectiveness: float = 0.5
    stuck_range: tuple[float, float] = (0.25, 0.75)

    def __post_init__(self) -> None:
        """Check every field (``ValueError`` names it)."""
        set_field = object.__setattr__
        set_field(self, "count", check.positive_int("count", self.count, minimum=0))
        window = check.vector("window", self.window, 2, nonnegative=True)
        if window[0] > window[1]:
            raise ValueError(f"window must be (earliest, latest) with earliest <= latest s, got {window!r}")
        set_field(self, "window", window)
        kinds = (self.kinds,) if isinstance(self.kinds, str) else self.kinds
        if not isinstance(kinds, Sequence) or not kinds or len(set(kinds)) != len(kinds):
            raise ValueError(f"kinds must be a non-empty tuple of distinct fault kinds, got {self.kinds!r}")
        for kind in kinds:
            check.choice("kinds", kind, FAULT_KINDS)
        set_field(self, "kinds", tuple(kinds))
        effectiveness = check.finite_float("effectiveness", self.effectiveness)
        if not 0.0 <= effectiveness < 1.0:
            raise ValueError(f"effectiveness must lie in [0, 1) (a loss), got {effectiveness!r}")
        set_field(self, "effectiveness", effectiveness)
        stuck = check.vector("stuck_range", self.stuck_range, 2, nonnegative=True)
        if not stuck[0] <= stuck[1] <= 1.0:
            raise ValueError(f"stuck_range must be (low, high) with 0 <= low <= high <= 1, got {stuck!r}")
        set_field(self, "stuck_range", stuck)

    def draw(self, rng: np.random.Generator, bounds: object, t0: float = 0.0) -> tuple[ThrusterFault, ...]:
        """Return the faults of one trial, in time order (class doc).

        Parameters
        ----------
        rng : numpy.random.Generator
            The trial's generator (the only source of randomness).
        bounds : array_like, shape (n,)
            Each thruster's force bound (N): ``n`` thrusters to choose from, the stuck forces' scale.
        t0 : float
            The run's start time (s): the window is counted from it.
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        limits = np.asarray(bounds, dtype=float).ravel()
        if self.count > limits.size:
            raise ValueError(f"count must be at most the number of thrusters {limits.size}, got {self.count}")
        thrusters = rng.choice(limits.size, size=self.count, replace=False)
        faults = []
        for thruster in thrusters:
            time = t0 + float(rng.uniform(*self.window))
            kind = self.kinds[int(rng.integers(len(self.kinds)))]
            if kind == "loss":
                faults.append(ThrusterFault(int(thruster), time, "loss", effectiveness=self.effectiveness))
            elif kind == "stuck":
                magnitude = float(rng.uniform(*self.stuck_range)) * limits[thruster]
                sign = 1.0 if rng.random() < 0.5 else -1.0
                faults.append(ThrusterFault(int(thruster), time, "stuck", value=sign * magnitude))
            else:
                faults.append(ThrusterFault(int(thruster), time, "failed"))
        return tuple(sorted(faults, key=lambda item: item.time))
