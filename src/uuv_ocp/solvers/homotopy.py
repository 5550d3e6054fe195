"""Initial guesses across homotopy classes: around each obstacle that blocks the reference path.

Among circular obstacles an optimal-control problem has one local optimum per homotopy class
(which side of each obstacle the path passes), and a gradient solver started on a path that
runs through an obstacle is pushed to the side the path's deepest point already lies on, which
may be the worse class.  This module builds one guess per class for the exact solver:

1. **Blockers**: the discs (centre, radius with margin; possibly moving) that the guess's path
   enters, at a node or on the straight segment between two nodes, sorted by depth
   (radius − smallest distance of the path to the centre, m).  The :data:`BLOCKERS` deepest
   are kept.
2. **Classes**: each side assignment ``s ∈ {+1, −1}^k`` of the k kept blockers (``+1``: the
   path passes to the left of the centre, seen along the path's chord from its first to its
   last node).  The path is *pushed* around each blocker in turn: a node ``q`` with
   ``q − c = a t + b n`` (``t`` the chord's direction, ``n`` its left normal) and
   ``|a| < R`` moves to ``b = s √(R² − a²)`` unless it is already farther on that side
   (``R`` = radius × (1 + :data:`PAD`), so the guess clears the disc).  Node 0 (the measured
   state) never moves.
3. **Order**: the classes are ranked by the squared displacement of their pushed path from the
   original one (a cheap proxy of a tracking cost), the least first; near-duplicates (every
   node within 1 cm) and assignments the pushes cannot realise (a later push across an
   overlapping disc undoing an earlier one, checked at the node abreast of each centre) are
   dropped.

The guess of a class keeps the original guess's controls and every state except the
horizontal position, which is the pushed path, and (when the geometry names them) the
horizontal velocity, the path's finite differences over ``dt``.

**Swarm seeds** (:func:`class_seeds`, the hybrids' ``initial_population="classes"``): the same
class paths, each turned into the swarm's search coordinates ``W ∈ [-1, 1]^{nu N}`` whose
rollout follows it (:class:`PathFit`: projected Gauss-Newton on the squared position error, so
box and rate bounds hold by construction through the swarm's ``decode``), plus seeded
perturbations of them; the swarm then starts with particles in every class it can reach.

The geometry comes from a :class:`Geometry` provider (a callable of the parameter vector ``p``,
the ``geometry`` option of the hybrids), or, for a
:class:`~uuv_ocp.tracking.TrackingProblem`, from its ``obstacles`` (an ellipse is taken as the
circle of its larger half-axis).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.solvers.result import Iterate
from uuv_ocp.transcription.condensed import encode

BLOCKERS = 3
"""Number of blockers whose sides are enumerated (at most ``2**BLOCKERS`` classes)."""

PAD = 0.1
"""Relative clearance of a pushed path from a blocker's boundary (0.1: 10 % of its radius)."""

SEGMENT_SAMPLES = 4
"""Points per interval at which the path between two nodes is checked for entering a disc."""

DUPLICATE = 0.01
"""Two class paths closer than this at every node (m) are one guess."""

FIT_ITERATIONS = 10
"""Largest number of Gauss-Newton steps of :class:`PathFit`."""

FIT_PADS = (0.5, 1.0)
"""Wider clearances (relative to the radius) of the class paths refitted when a fit of the
:data:`PAD` path ends in another class (the vehicle cuts the corner of a hard push)."""

FREE_WEIGHT = 0.1
"""Fit weight of the nodes a push left in place: a pushed path jumps sideways at its first moved
node, which no bounded acceleration follows; the gates beside the obstacles decide the class."""

CLASS_SPREAD = 0.05
"""Standard deviation of the seeded perturbation of a class seed's coordinates ``W`` (of the
range 2 of each): small enough that a perturbed particle stays in its class as a rule."""


@dataclass(frozen=True)
class Geometry:
    """Where the obstacles are and which states are the horizontal position.

    Parameters
    ----------
    discs : ndarray, shape (N+1, n, 3)
        Per node ``k`` and obstacle ``i``: centre x (m), centre y (m), radius including the
        vehicle's margin (m), > 0.  A fixed obstacle repeats the same row at every node.
    position : tuple of 2 int
        State columns of the horizontal position (x, y).
    velocity : tuple of 2 int or None
        State columns of the horizontal velocity in the same frame (m/s), set from the pushed
        path's finite differences; ``None``: the velocity of the guess is kept.
    dt : float
        Interval length (s), > 0 (only used with ``velocity``).
    """

    discs: np.ndarray
    position: tuple[int, int]
    velocity: tuple[int, int] | None = None
    dt: float = 1.0

    def __post_init__(self) -> None:
        """Check shapes and values."""
        discs = np.asarray(self.discs, dtype=float)
        if discs.ndim != 3 or discs.shape[2] != 3:
            raise ValueError(f"discs must have shape (N+1, n, 3), got {discs.shape}")
        if not np.all(np.isfinite(discs)) or np.any(discs[:, :, 2] <= 0.0):
            raise ValueError("discs must be finite with radii > 0")
        object.__setattr__(self, "discs", discs)
        for name in ("position", "velocity"):
            value = getattr(self, name)
            if value is None and name == "velocity":
                continue
            if (
                not isinstance(value, (tuple, list, np.ndarray))
                or len(value) != 2
                or any(not isinstance(i, (int, np.integer)) or i < 0 for i in value)
            ):
                raise ValueError(f"{name} must be 2 state columns (int >= 0), got {value!r}")
            object.__setattr__(self, name, (int(value[0]), int(value[1])))
        object.__setattr__(self, "dt", check.positive_float("dt", self.dt))


GeometryProvider = Callable[[np.ndarray], Geometry | None]


def _chord(path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the unit direction of the path's chord (first to last node) and its left normal."""
    chord = path[-1] - path[0]
    length = float(np.hypot(*chord))
    along = chord / length if length > 1e-9 else np.array([1.0, 0.0])
    return along, np.array([-along[1], along[0]])


def blockers(path: np.ndarray, discs: np.ndarray, count: int = BLOCKERS) -> list[tuple[int, float]]:
    """Obstacles the path enters, deepest first: ``[(index, depth m), ...]`` (at most ``count``).

    Parameters
    ----------
    path : ndarray, shape (N+1, 2)
        Horizontal positions at the nodes (m).
    discs : ndarray, shape (N+1, n, 3)
        Obstacles per node (see :class:`Geometry`).
    count : int
        Largest number returned.
    """
    weights = np.linspace(0.0, 1.0, SEGMENT_SAMPLES + 1)[:-1]
    # points between nodes, with the centres interpolated alike (moving obstacles)
    points = np.concatenate([(1 - w) * path[:-1] + w * path[1:] for w in weights] + [path[-1:]], axis=0)
    centres = np.concatenate(
        [(1 - w) * discs[:-1, :, :2] + w * discs[1:, :, :2] for w in weights] + [discs[-1:, :, :2]],
        axis=0,
    )
    radii = np.concatenate([discs[:-1, :, 2]] * len(weights) + [discs[-1:, :, 2]], axis=0)
    distance = np.linalg.norm(points[:, None, :] - centres, axis=2)
    depth = np.max(radii - distance, axis=0)
    inside = [int(i) for i in np.flatnonzero(depth > 0.0)]
    inside.sort(key=lambda i: -depth[i])
    return [(i, float(depth[i])) for i in inside[:count]]


def push(path: np.ndarray, track: np.ndarray, side: float, pad: float = PAD) -> np.ndarray:
    """Return ``path`` pushed around one disc on ``side`` (+1 left of the centre, −1 right).

    Parameters
    ----------
    path : ndarray, shape (N+1, 2)
        Horizontal positions (m); node 0 is kept.
    track : ndarray, shape (N+1, 3)
        The disc at each node: centre x, y and radius (m).
    side : {+1, -1}
        Side of the centre the pushed path passes on, along the chord of ``path``.
    pad : float
        Relative extra clearance (the pushed nodes sit at radius × (1 + pad)).
    """
    along, normal = _chord(path)
    out = path.copy()
    offset = path - track[:, :2]
    a = offset @ along
    b = offset @ normal
    reach = track[:, 2] * (1.0 + pad)
    near = np.abs(a) < reach
    near[0] = False  # the measured state does not move
    wanted = side * np.sqrt(np.maximum(reach**2 - a**2, 0.0))
    move = near & (side * b < np.abs(wanted))
    out[move] = track[move, :2] + a[move, None] * along + wanted[move, None] * normal
    return out


def _passes(path: np.ndarray, track: np.ndarray, side: int) -> bool:
    """Whether ``path`` is on ``side`` of the disc at the node most nearly abreast of its centre."""
    along, normal = _chord(path)
    offset = path[1:] - track[1:, :2]
    k = int(np.argmin(np.abs(offset @ along)))
    return bool(side * float(offset[k] @ normal) > 0.0)


def sides(path: np.ndarray, discs: np.ndarray) -> tuple[int, ...]:
    """Homotopy class of ``path`` among every disc: the side it passes each one on (+1 left, −1 right).

    The side of disc ``i`` is the sign of the path's offset from its centre along the chord's
    left normal at the node most nearly abreast of the centre (node 0 excluded, as in the
    pushes); two paths with equal tuples pass every obstacle on the same side.

    Parameters
    ----------
    path : ndarray, shape (N+1, 2)
        Horizontal positions at the nodes (m).
    discs : ndarray, shape (N+1, n, 3)
        Obstacles per node (see :class:`Geometry`).
    """
    return tuple(1 if _passes(path, discs[:, i, :], 1) else -1 for i in range(discs.shape[1]))


def class_paths(
    path: np.ndarray, discs: np.ndarray, count: int = BLOCKERS, pad: float = PAD
) -> list[tuple[dict[int, int], np.ndarray]]:
    """Pushed paths of every side assignment of the ``count`` deepest blockers, best first.

    Returns ``[(sides, path), ...]`` with ``sides`` mapping an obstacle index to +1 (left) or
    −1 (right); ordered by squared displacement from ``path`` (least first), near-duplicates
    dropped.  Empty when the path enters no obstacle.
    """
    found = [i for i, _ in blockers(path, discs, count)]
    if not found:
        return []
    along, _ = _chord(path)
    # push in the order the path meets them (nearest centre along the chord first)
    found.sort(key=lambda i: float(np.min((discs[:, i, :2] - path[0]) @ along)))
    ranked = []
    for signs in itertools.product((1, -1), repeat=len(found)):
        pushed = path
        for i, s in zip(found, signs, strict=True):
            pushed = push(pushed, discs[:, i, :], float(s), pad)
        if not all(_passes(pushed, discs[:, i, :], s) for i, s in zip(found, signs, strict=True)):
            continue  # a later push undid an earlier one (overlapping discs): not this class
        ranked.append((float(np.sum((pushed - path) ** 2)), dict(zip(found, signs, strict=True)), pushed))
    ranked.sort(key=lambda row: row[0])
    out: list[tuple[dict[int, int], np.ndarray]] = []
    for _, sides, pushed in ranked:
        if all(np.max(np.abs(pushed - other)) > DUPLICATE for _, other in out):
            out.append((sides, pushed))
    return out


def geometry_of(problem: Any, p: np.ndarray, provider: GeometryProvider | None = None) -> Geometry | None:
    """Return the obstacle geometry of instance ``p``: the ``provider``'s, else a tracking problem's.

    ``None`` when neither gives one (no obstacles known: no class guesses).
    """
    if provider is not None:
        geometry = provider(p)
        if geometry is not None:
            if not isinstance(geometry, Geometry):
                got = type(geometry).__name__
                raise ValueError(f"geometry must return a homotopy.Geometry or None, got {got}")
            horizon = problem.spec().horizon
            if geometry.discs.shape[0] != horizon + 1:
                raise ValueError(
                    f"geometry's discs must have {horizon + 1} rows (N+1 nodes), "
                    f"got {geometry.discs.shape[0]}"
                )
        return geometry
    obstacles = getattr(problem, "obstacles", None)
    if not obstacles:
        return None
    spec = problem.spec()
    layout = getattr(getattr(problem, "vehicle", None), "layout", None)
    positions = getattr(layout, "positions", None)
    if positions is None or len(positions) < 2:
        return None
    nodes = spec.horizon + 1
    entries = spec.layout.entries
    rows = []
    for i, obstacle in enumerate(obstacles):
        radius = obstacle.radius + obstacle.margin
        if obstacle.is_moving:  # its centres at the nodes are a stagewise parameter of p
            where = entries[f"obstacle{i}"][0]
            centres = np.asarray(p[where], dtype=float).reshape(-1, 2)[:nodes]
        else:
            centres = np.tile(np.asarray(obstacle.centre, dtype=float), (nodes, 1))
        rows.append(np.column_stack([centres, np.full(nodes, radius)]))
    return Geometry(np.stack(rows, axis=1), (int(positions[0]), int(positions[1])), None, spec.dt)


def class_guesses(
    problem: Any,
    p: np.ndarray,
    warm_start: Iterate | None,
    geometry: Geometry,
    count: int = BLOCKERS,
) -> list[tuple[str, Iterate]]:
    """Exact solver's guesses across homotopy classes: ``[(label, Iterate), ...]``, best first.

    The path is the warm start's horizontal position (the problem's cold guess without one);
    the label names each blocker's side, e.g. ``"class 2L 0R"`` (obstacle 2 left, 0 right).
    """
    if warm_start is not None and warm_start.states is not None and warm_start.scaled_controls is not None:
        states = np.asarray(warm_start.states, dtype=float)
        controls = np.asarray(warm_start.scaled_controls, dtype=float)
    else:
        states, controls = problem.initial_guess(p)
    columns = list(geometry.position)
    out = []
    for sides, path in class_paths(states[:, columns], geometry.discs, count):
        new = states.copy()
        new[:, columns] = path
        if geometry.velocity is not None:
            velocity = np.gradient(path, geometry.dt, axis=0)
            new[1:, list(geometry.velocity)] = velocity[1:]
        label = "class " + " ".join(f"{i}{'L' if s > 0 else 'R'}" for i, s in sides.items())
        out.append(
            (
                label,
                Iterate(
                    scaled_controls=controls.copy(),
                    states=new,
                    variant=warm_start.variant if warm_start is not None else "hard",
                    terminal_relaxed=warm_start.terminal_relaxed if warm_start is not None else False,
                ),
            )
        )
    return out


class PathFit:
    """Swarm coordinates ``W`` whose rollout follows a horizontal path: ``fit(path, start, p)``.

    Minimises ``Σ_{k≥1} c_k ‖pos_k(W) − path_k‖²`` (m², weights ``c_k``, default 1) over the
    box ``W ∈ [-1, 1]^{nu N}`` by Gauss-Newton from ``start``: the coordinates on a bound that
    the gradient pushes out stay fixed, the step (damped by 1e-6 × the largest curvature) is
    clipped into the box and halved until it lowers the error (at most 3 times; else the fit
    stops).  ``pos(W)`` is the rollout through the problem's own ``decode`` and RK4 Function,
    so every ``W`` in the box holds the control box and the rate bound.

    Parameters
    ----------
    problem : Transcribed
        Any built problem (an :class:`~uuv_ocp.ocp.Ocp` or a tracking problem).
    position : tuple of 2 int
        State columns of the horizontal position (x, y) in m.
    """

    def __init__(self, problem: Any, position: tuple[int, int]) -> None:
        spec = problem.spec()
        built = problem.build()
        self.dim = spec.control_size * spec.horizon
        with BUILD_LOCK:  # CasADi's graph building is not thread-safe (hybrids in N threads)
            coordinates = ca.MX.sym("W", self.dim)
            p = ca.MX.sym("p", spec.layout.size)
            states = built.rollout(built.decode(coordinates, p), p)  # (nx, N + 1)
            positions = ca.vec(states[list(position), 1:])  # x1, y1, x2, y2, ...
            jacobian = ca.jacobian(positions, coordinates)
            function = ca.Function("path_fit", [coordinates, p], [positions, jacobian])
            try:  # the SX form evaluates several times faster on the virtual machine
                function = function.expand()
            except RuntimeError:  # a Function inside without an SX form: keep the MX one
                pass
            self._function = BufferedFunction(function)
        self.position = position
        self._x0 = spec.layout.x0

    def __call__(
        self,
        path: np.ndarray,
        start: np.ndarray,
        p: np.ndarray,
        iterations: int = FIT_ITERATIONS,
        weights: np.ndarray | None = None,
    ) -> np.ndarray:
        """Return ``W`` (flat, in ``[-1, 1]``) whose rollout follows ``path`` (N+1, 2) on nodes 1..N.

        ``weights`` (N+1,): of each node's squared error (node 0's unused); default all 1.
        """
        target = np.asarray(path, dtype=float)[1:].ravel()
        root = np.ones(target.size) if weights is None else np.repeat(np.sqrt(weights[1:]), 2)
        w = np.clip(np.asarray(start, dtype=float).ravel(), -1.0, 1.0)
        positions, jacobian = self._evaluate(w, p, root)
        target = root * target
        error = float(np.sum((positions - target) ** 2))
        for _ in range(iterations):
            residual = positions - target
            gradient = jacobian.T @ residual
            # coordinates on a bound that the descent pushes further out stay there (active set)
            free = ~(((w <= -1.0) & (gradient > 0.0)) | ((w >= 1.0) & (gradient < 0.0)))
            if not np.any(free):
                break
            normal = jacobian[:, free].T @ jacobian[:, free]
            normal[np.diag_indices_from(normal)] += 1e-6 * max(float(np.max(np.diag(normal))), 1e-12)
            step = np.zeros_like(w)
            step[free] = np.linalg.solve(normal, -gradient[free])
            for length in (1.0, 0.5, 0.25, 0.125):  # backtrack: the clipped step must lower the error
                trial = np.clip(w + length * step, -1.0, 1.0)
                trial_positions, trial_jacobian = self._evaluate(trial, p, root)
                trial_error = float(np.sum((trial_positions - target) ** 2))
                if trial_error < error:
                    break
            else:
                break  # no step lowers it: a (local) optimum of the fit
            w, positions, jacobian, error = trial, trial_positions, trial_jacobian, trial_error
        return w

    def positions(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Horizontal positions (N+1, 2) of the rollout of ``w`` (m); node 0 the measured state."""
        states = self._function(w, p)[0].reshape(-1, 2)
        x0 = np.asarray(p[self._x0], dtype=float)[list(self.position)]
        return np.vstack([x0, states])

    def _evaluate(self, w: np.ndarray, p: np.ndarray, root: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted positions (2N,) and their Jacobian (2N, nu N) at ``w`` (rows times ``root``)."""
        positions, jacobian = self._function(w, p)
        return root * positions, root[:, None] * jacobian.reshape(positions.size, self.dim, order="F")


def _gates(path: np.ndarray, pushed: np.ndarray) -> np.ndarray:
    """Return the fit weight of each node: 1 where the push moved it (a gate), else :data:`FREE_WEIGHT`."""
    return np.where(np.any(np.abs(pushed - path) > 1e-9, axis=1), 1.0, FREE_WEIGHT)


def _reached(path: np.ndarray, discs: np.ndarray, wanted: dict[int, int]) -> bool:
    """Whether ``path`` passes every obstacle of ``wanted`` on its side."""
    passed = sides(path, discs)
    return all(passed[i] == side for i, side in wanted.items())


def class_seeds(
    problem: Any,
    p: np.ndarray,
    warm_start: Iterate | None,
    geometry: Geometry,
    fit: PathFit | Callable[[], PathFit],
    size: int,
    rng: np.random.Generator,
    count: int = BLOCKERS,
    spread: float = CLASS_SPREAD,
) -> tuple[np.ndarray, list[dict[int, int]]]:
    """Return initial swarm particles across the homotopy classes: ``(W rows (k, nu N), sides per row)``.

    One particle per class of :func:`class_paths` (of the warm start's path, best first), each
    the :class:`PathFit` of the class path from the warm start's coordinates, then, while fewer
    than ``size`` rows, perturbed copies of them in turn (``W + N(0, spread²)`` from ``rng``,
    clipped into ``[-1, 1]``).  Empty (shape (0, nu N)) when the path enters no obstacle or
    ``size`` is 0.  The sides are the intended class of each row (obstacle index -> +1 left,
    −1 right), not checked here: a class whose path the vehicle cannot follow may be missed.
    ``fit`` may be a function returning the :class:`PathFit`, called only when some class path
    exists (building one takes 0.4 s for RexROV at N = 20: not worth it with nothing in the way).
    """
    if warm_start is not None and warm_start.states is not None and warm_start.scaled_controls is not None:
        states = np.asarray(warm_start.states, dtype=float)
        controls = np.asarray(warm_start.scaled_controls, dtype=float)
    else:
        states, controls = problem.initial_guess(p)
    start = encode(problem.spec(), controls, problem.previous_scaled(p))
    path = states[:, list(geometry.position)]
    classes = class_paths(path, geometry.discs, count)[:size]
    if not classes or size < 1:
        return np.empty((0, start.size)), []
    if not isinstance(fit, PathFit):
        fit = fit()
    wider = {pad: class_paths(path, geometry.discs, count, pad) for pad in FIT_PADS}
    fitted = []
    for wanted, target in classes:
        w = fit(target, start, p, weights=_gates(path, target))
        for pad in FIT_PADS:  # the fit cut a corner into the other class: push the path farther out
            if _reached(fit.positions(w, p), geometry.discs, wanted):
                break
            farther = [other for sides_, other in wider[pad] if sides_ == wanted]
            if farther:
                w = fit(farther[0], w, p, weights=_gates(path, farther[0]))
        fitted.append(w)
    rows, sides = list(fitted), [dict(s) for s, _ in classes]
    extra = size - len(rows)
    if extra > 0:  # round robin: the best-ranked classes get the first perturbed copies
        base = np.array([fitted[i % len(fitted)] for i in range(extra)])
        noise = spread * rng.standard_normal(base.shape)
        rows += list(np.clip(base + noise, -1.0, 1.0))
        sides += [dict(classes[i % len(classes)][0]) for i in range(extra)]
    return np.array(rows), sides
