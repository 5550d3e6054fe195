"""Waypoint paths: straight legs joined by tangent circular arcs, as CasADi expressions.

:class:`WaypointPath` turns waypoints into a path parametrised by the horizontal arc length
``s`` (m).  Every corner is replaced by a circular arc of radius ``turn_radius`` tangent to both
legs: with the turn angle ``Δ`` at waypoint ``i`` (signed, positive from the x axis towards the
y axis), the arc starts ``R tan(|Δ|/2)`` before the corner on the incoming leg, ends as
far after it on the outgoing leg and has length ``R |Δ|``.  Position and direction are
continuous at every joint, so a traversal at constant speed is C¹ in time; the curvature jumps
between 0 and ``±1/R`` there.

Each coordinate is one line formula and one arc formula (chosen by ``casadi.if_else``) in the
constants of the piece that holds ``s``; the constants are found by table look-ups (binary
search, so 40 waypoints cost no more than 4) and enter as placeholders of a
:class:`PiecewiseExpression`: CasADi's AD differentiates the formulas with the constants held
fixed, so the derivatives at a joint are those of the piece that starts there (finite, one
side's formula) and never pass through the look-ups.

:func:`lawnmower_points` lays out the waypoints of a boustrophedon survey.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check

#: Turn angle (rad) below which a waypoint is passed straight through, without an arc.
STRAIGHT_THROUGH_ANGLE = 1e-9
#: A turn this close to π (rad) is a reversal: no arc tangent to both legs exists.
REVERSAL_MARGIN = 1e-9
#: Relative slack allowed when two arcs exactly use up the leg between them.
FIT_TOLERANCE = 1e-9


class _Piece(NamedTuple):
    """One piece of the horizontal path on ``[start, start + length]`` (m of arc length).

    A line runs from ``(base_x, base_y)`` along the unit vector ``(a, b)``; an arc has centre
    ``(base_x, base_y)``, signed radius ``a`` (> 0: turning left) and initial direction ``b``
    (rad).
    """

    start: float
    length: float
    base_x: float
    base_y: float
    a: float
    b: float
    is_arc: float


class _Quadratic(NamedTuple):
    """``z = c0 + c1 σ + c2 σ²`` with ``σ = s − start`` (m)."""

    start: float
    c0: float
    c1: float
    c2: float


@dataclass(frozen=True)
class WaypointPath:
    """Horizontal path through waypoints with tangent arcs, and its depth profile.

    Parameters
    ----------
    points : array_like, shape (n, 2) or (n, 3)
        Waypoints (m), n >= 2; consecutive waypoints must differ horizontally.  A third column
        is the depth ``z`` (m, NED: positive down).
    turn_radius : float
        Radius (m) of every turning arc, > 0.  Each arc must fit into its two legs (together
        with the arc at the leg's other end); a waypoint where the path goes straight on needs
        no arc, and a reversal (turn of π) is rejected.

    Attributes
    ----------
    count : int
        Number of waypoints (``points`` is stored as a tuple of rows).
    spatial : bool
        Whether the waypoints carry a depth column.
    length : float
        Horizontal length of the path (m): the legs shortened by the arcs, plus the arcs.

    Notes
    -----
    Depth (three columns) is interpolated linearly in the horizontal arc length ``s`` between
    *stations* of the waypoints: the end points, the midpoint of each turning arc and the
    straight-through waypoints.  To keep the climb rate continuous, the slope change at a
    station is blended parabolically over its arc (over up to ``turn_radius`` either side of a
    straight-through waypoint, at most half of the adjoining straight pieces): the path misses
    the depth of a turning waypoint by ``(m_out − m_in) ℓ / 8`` (slopes ``m`` of the adjoining
    stretches, arc length ``ℓ``), just as it misses the corner horizontally.
    """

    points: object
    turn_radius: float
    count: int = field(init=False)
    spatial: bool = field(init=False)
    length: float = field(init=False)
    _pieces: tuple[_Piece, ...] = field(init=False, repr=False)
    _depth_pieces: tuple[_Quadratic, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        """Validate the waypoints and the radius, and lay out the pieces of the path."""
        array = _checked_points(self.points)
        radius = check.positive_float("turn_radius", self.turn_radius)
        horizontal = array[:, :2]
        legs = np.diff(horizontal, axis=0)
        lengths = np.hypot(legs[:, 0], legs[:, 1])
        scale = max(1.0, float(np.max(np.abs(horizontal))))
        for index, leg_length in enumerate(lengths):
            if leg_length <= 1e-9 * scale:
                raise ValueError(
                    f"points[{index}] and points[{index + 1}] must differ horizontally (a leg needs a "
                    f"direction), got {_row(array[index])} and {_row(array[index + 1])}"
                )
        directions = legs / lengths[:, None]
        turns, tangents = _turns(horizontal, directions, radius)
        for index, leg_length in enumerate(lengths):
            if tangents[index] + tangents[index + 1] > leg_length * (1.0 + FIT_TOLERANCE):
                raise ValueError(_misfit_message(index, array, lengths, turns, tangents, radius))
        straights = np.maximum(0.0, lengths - tangents[:-1] - tangents[1:])
        straights[straights <= 1e-12 * np.maximum(1.0, lengths)] = 0.0

        pieces: list[_Piece] = []
        blends = [(0.0, 0.0)]  # per waypoint: where its depth blend starts and ends (m)
        arc_length = 0.0
        last = len(array) - 1
        for index, direction in enumerate(directions):
            if straights[index] > 0.0:
                start = horizontal[index] + tangents[index] * direction
                pieces.append(
                    _Piece(arc_length, straights[index], start[0], start[1], direction[0], direction[1], 0.0)
                )
                arc_length += straights[index]
            corner = index + 1
            if corner == last:
                break
            if turns[corner] == 0.0:  # straight through: a station, no arc
                half = min(radius, straights[index] / 2.0, straights[corner] / 2.0)
                blends.append((arc_length - half, arc_length + half))
                continue
            signed_radius = math.copysign(radius, turns[corner])
            entry = horizontal[corner] - tangents[corner] * direction
            centre = entry + signed_radius * np.array([-direction[1], direction[0]])
            arc = radius * abs(turns[corner])
            angle = math.atan2(direction[1], direction[0])
            pieces.append(_Piece(arc_length, arc, centre[0], centre[1], signed_radius, angle, 1.0))
            blends.append((arc_length, arc_length + arc))
            arc_length += arc
        blends.append((arc_length, arc_length))

        set_field = object.__setattr__
        set_field(self, "points", tuple(tuple(float(v) for v in row) for row in array))
        set_field(self, "turn_radius", radius)
        set_field(self, "count", len(array))
        set_field(self, "spatial", array.shape[1] == 3)
        set_field(self, "length", arc_length)
        set_field(self, "_pieces", tuple(_Piece(*(float(v) for v in piece)) for piece in pieces))
        depth = _depth_profile(array[:, 2], blends) if self.spatial else ()
        set_field(self, "_depth_pieces", depth)

    def horizontal(self, s: ca.SX) -> tuple[PiecewiseExpression, PiecewiseExpression]:
        """Horizontal position ``(x, y)`` (m) at arc length ``s``.

        Parameters
        ----------
        s : casadi.SX
            Arc length (m), an expression of time; outside ``[0, length]`` the first and last
            pieces are extended.

        Returns
        -------
        tuple of two PiecewiseExpression
            ``x`` and ``y``.
        """
        pieces = self._pieces
        rows = [piece[:1] + piece[2:] for piece in pieces]  # start, base_x, base_y, a, b, is_arc
        arcs = any(piece.is_arc for piece in pieces)
        coordinates = []
        for axis in (0, 1):
            constants = ca.SX.sym(f"piece_{'xy'[axis]}", len(rows[0]))
            start, base_x, base_y, a, b, is_arc = ca.vertsplit(constants)
            sigma = s - start
            line = (base_x + sigma * a, base_y + sigma * b)[axis]
            if arcs:
                radius = ca.if_else(is_arc, a, 1.0)  # the arc formula stays finite on lines
                angle = b + sigma / radius
                arc = base_x + radius * ca.sin(angle) if axis == 0 else base_y - radius * ca.cos(angle)
                expression = ca.if_else(is_arc, arc, line)
            else:
                expression = line
            values = _look_up(s, rows, "waypoint_pieces")
            coordinates.append(PiecewiseExpression(expression, constants, values, s, tuple(rows)))
        return coordinates[0], coordinates[1]

    def heading(self, s: ca.SX) -> PiecewiseExpression:
        """Direction of the path (rad, from the x axis towards the y axis) at arc length ``s``.

        The tangent's angle: a leg's direction, ``b + σ / a`` on an arc (initial direction
        ``b``, signed radius ``a``).  Wrapped into (−π, π] on legs; a reference unwraps it.
        Given as the heading of a reference, it stays defined where the path speed vanishes
        (a mission holding its last waypoint).
        """
        pieces = self._pieces
        rows = [piece[:1] + piece[2:] for piece in pieces]  # start, base_x, base_y, a, b, is_arc
        constants = ca.SX.sym("piece_heading", len(rows[0]))
        start, _, _, a, b, is_arc = ca.vertsplit(constants)
        line = ca.atan2(b, a)
        arc = b + (s - start) / ca.if_else(is_arc, a, 1.0)  # finite on lines too
        expression = ca.if_else(is_arc, arc, line)
        return PiecewiseExpression(
            expression, constants, _look_up(s, rows, "waypoint_pieces"), s, tuple(rows)
        )

    def depth(self, s: ca.SX) -> PiecewiseExpression:
        """Depth ``z`` (m, positive down) of a spatial path at arc length ``s`` (m, SX)."""
        if not self.spatial:
            raise ValueError("depth needs waypoints with three columns (x, y, z)")
        constants = ca.SX.sym("depth_piece", 4)
        start, c0, c1, c2 = ca.vertsplit(constants)
        sigma = s - start
        expression = c0 + sigma * (c1 + sigma * c2)
        values = _look_up(s, self._depth_pieces, "waypoint_depth")
        return PiecewiseExpression(expression, constants, values, s, tuple(self._depth_pieces))


@dataclass(frozen=True, eq=False)
class PiecewiseExpression:
    """An expression of time written with placeholders for piecewise-constant quantities.

    Parameters
    ----------
    expression : casadi.SX
        Scalar expression of the time symbol and of the symbols ``constants``.
    constants : casadi.SX
        Column of placeholder symbols.
    values : casadi.SX
        Their values, expressions of time that are constant between joints (table look-ups).
    key : casadi.SX or None
        The look-up variable (an expression of time, non-decreasing), if ``values`` is a table
        look-up: ``values`` is the row of ``table`` whose start (column 0) is the last one
        ``<= key`` (the first row before the first start).
    table : tuple of tuple of float or None
        That table, one row per piece (as many columns as ``constants``), starts strictly
        increasing.  With both, a caller may look up a window of the table (rows as parameters:
        :func:`window_look_up`) instead of the whole (``PathFollowingProblem``).

    Notes
    -----
    A path callable of :class:`~uuv_ocp.reference.path.Reference` may return one of these.
    The reference differentiates ``expression`` with the placeholders held fixed, which is
    exact because their time derivative is zero between joints, and substitutes ``values``
    afterwards: the derivatives never pass through the look-ups, and at a joint they are the
    ones of the piece that the look-up selects.
    """

    expression: ca.SX
    constants: ca.SX
    values: ca.SX
    key: ca.SX | None = None
    table: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        """Check the types and shapes."""
        if (self.key is None) != (self.table is None):
            raise ValueError("key and table must be given together (a table look-up) or both be None")
        if self.key is not None:
            if not isinstance(self.key, ca.SX) or self.key.shape != (1, 1):
                raise ValueError(f"key must be a scalar casadi SX, got {self.key!r}")
            table = np.array(self.table, dtype=float)
            width = self.constants.numel()
            if table.ndim != 2 or table.shape[1] != width or table.shape[0] < 1:
                raise ValueError(
                    f"table must have rows of {width} floats (as constants), got shape {table.shape}"
                )
            if np.any(np.diff(table[:, 0]) <= 0.0):
                raise ValueError("table starts (column 0) must be strictly increasing")
        for label in ("expression", "constants", "values"):
            if not isinstance(getattr(self, label), ca.SX):
                raise ValueError(f"{label} must be a casadi SX, got {type(getattr(self, label)).__name__}")
        if self.expression.shape != (1, 1):
            raise ValueError(f"expression must be scalar, got shape {self.expression.shape}")
        if not self.constants.is_column() or not self.constants.is_valid_input():
            raise ValueError("constants must be a column of SX symbols")
        if self.values.shape != self.constants.shape:
            raise ValueError(
                f"values must have the shape of constants {self.constants.shape}, got {self.values.shape}"
            )


def window_look_up(key: ca.SX, rows: ca.SX) -> ca.SX:
    """Return the row of ``rows`` (SX, a row per piece) whose start (column 0) is the last <= ``key``.

    The first row before its start: a window of a :class:`PiecewiseExpression`'s table whose
    rows are parameters (chosen by the caller to hold every ``key`` it will meet), as
    :func:`_look_up`'s chain on the whole table; a row repeated at the end (padding) selects
    itself.
    """
    value = rows[0, :].T
    for i in range(1, rows.size1()):
        value = ca.if_else(key >= rows[i, 0], rows[i, :].T, value)
    return value


#: Most rows :func:`_look_up` selects by an ``if_else`` chain; longer tables use interpolants.
CHAIN_ROWS = 64


def _look_up(s: ca.SX, rows: Sequence[Sequence[float]], name: str) -> ca.SX:
    """Look up the row whose start (column 0) is the last one <= ``s`` (the first row before it).

    Up to :data:`CHAIN_ROWS` rows: a chain of ``casadi.if_else`` on ``s >= start`` (pure SX, one
    comparison per row).  CasADi's SX Jacobian through a Function call (an interpolant) has
    structural entries on every variable seeded in the same direction, e.g. a gap
    ``X_(k+1) − F(X_k, u_k)`` reading ``s_(k+1)``, which HPIPM's OCP-QP map refuses; a
    chain has none.  Longer tables (a chain's cost grows with them): two table look-ups (CasADi
    interpolants, binary search), ``s`` -> piece index, then index -> row; the C step then
    falls back to CasADi's QP path.  Starts must be strictly increasing.
    """
    count = len(rows)
    starts = [row[0] for row in rows]
    if count <= CHAIN_ROWS:
        value = ca.SX(ca.DM(rows[0]))
        for start, row in zip(starts[1:], rows[1:], strict=True):
            value = ca.if_else(s >= start, ca.DM(row), value)
        return value
    end = starts[-1] + max(1.0, starts[-1] - starts[0])
    index = ca.interpolant(f"{name}_index", "linear", [[*starts, end]], [float(k) for k in range(count + 1)])
    table = ca.interpolant(
        f"{name}_table",
        "linear",
        [[float(k) for k in range(count + 1)]],
        [float(v) for row in (*rows, rows[-1]) for v in row],  # last row repeated: rows sit at knots
    )
    piece = ca.fmin(ca.fmax(ca.floor(index(s)), 0.0), float(count - 1))
    return table(piece)


def _checked_points(points: object) -> np.ndarray:
    try:
        array = np.array(points, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"points must be an (n, 2) or (n, 3) array of waypoints (m), got {points!r}"
        ) from error
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (n, 2) or (n, 3) (waypoints in m), got shape {array.shape}")
    if array.shape[0] < 2:
        raise ValueError(f"points must hold at least 2 waypoints, got {array.shape[0]}")
    finite = np.all(np.isfinite(array), axis=1)
    if not np.all(finite):
        row = int(np.argmin(finite))
        raise ValueError(f"points must be finite, got points[{row}] = {_row(array[row])}")
    # 1e300 passed and gave NaN states (its squares overflow): beyond ±1e9 m a waypoint is a
    # unit or typing mistake (the plausibility bound of states, uuv_ocp._validation)
    inside = np.all(np.abs(array) <= check.PLAUSIBLE_MAGNITUDE, axis=1)
    if not np.all(inside):
        row = int(np.argmin(inside))
        raise ValueError(
            f"points must lie within ±{check.PLAUSIBLE_MAGNITUDE:g} m (a plausibility bound), got "
            f"points[{row}] = {_row(array[row])}"
        )
    return array


def _row(values: np.ndarray) -> tuple[float, ...]:
    """Return a waypoint as plain floats, for error messages."""
    return tuple(float(v) for v in values)


def _turns(horizontal: np.ndarray, directions: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed turn angle (rad) and tangent length ``R tan(|Δ|/2)`` (m) at every waypoint."""
    count = len(horizontal)
    turns, tangents = np.zeros(count), np.zeros(count)
    for corner in range(1, count - 1):
        incoming, outgoing = directions[corner - 1], directions[corner]
        cross = incoming[0] * outgoing[1] - incoming[1] * outgoing[0]
        turn = math.atan2(cross, float(incoming @ outgoing))
        if abs(turn) <= STRAIGHT_THROUGH_ANGLE:
            continue
        if math.pi - abs(turn) <= REVERSAL_MARGIN:
            raise ValueError(
                f"points: the path reverses at waypoint {corner} (points[{corner}] = "
                f"{_row(horizontal[corner])}, a turn of 180 degrees): no arc is tangent to both legs; "
                "add a waypoint to the side"
            )
        turns[corner] = turn
        tangents[corner] = radius * math.tan(abs(turn) / 2.0)
    return turns, tangents


def _misfit_message(
    leg: int,
    points: np.ndarray,
    lengths: np.ndarray,
    turns: np.ndarray,
    tangents: np.ndarray,
    radius: float,
) -> str:
    """Why the arcs at the ends of ``leg`` (from waypoint ``leg`` to ``leg + 1``) do not fit."""
    length = lengths[leg]
    ends = [corner for corner in (leg, leg + 1) if tangents[corner] > 0.0]
    largest = length / sum(math.tan(abs(turns[corner]) / 2.0) for corner in ends)
    if len(ends) == 1:
        corner = ends[0]
        other = leg + 1 if corner == leg else leg
        return (
            f"turn_radius = {radius:g} m is too large for the turn at waypoint {corner} "
            f"(points[{corner}] = {_row(points[corner])}): its arc needs "
            f"{tangents[corner]:.6g} m of the {length:.6g} m leg to waypoint {other}; this leg fits "
            f"turn_radius <= {largest:.6g} m"
        )
    return (
        f"turn_radius = {radius:g} m is too large for the turns at waypoints {leg} and {leg + 1}: "
        f"their arcs need {tangents[leg]:.6g} + {tangents[leg + 1]:.6g} m of the {length:.6g} m leg "
        f"between them; this leg fits turn_radius <= {largest:.6g} m"
    )


def _depth_profile(depths: np.ndarray, blends: list[tuple[float, float]]) -> tuple[_Quadratic, ...]:
    """Build the C¹ piecewise-quadratic depth ``z(s)``.

    Linear in ``s`` between the stations (blend midpoints), parabolic over each waypoint's blend
    ``[a, b]`` (matching value and slope at both ends).
    """
    stations = np.array([0.5 * (start + end) for start, end in blends])
    slopes = np.diff(depths) / np.diff(stations)
    pieces = [_Quadratic(0.0, depths[0], slopes[0], 0.0)]
    for index in range(1, len(depths) - 1):
        (start, end), station, depth = blends[index], stations[index], depths[index]
        incoming, outgoing = slopes[index - 1], slopes[index]
        if end > start:
            curvature = (outgoing - incoming) / (2.0 * (end - start))
            pieces.append(_Quadratic(start, depth - incoming * (station - start), incoming, curvature))
            pieces.append(_Quadratic(end, depth + outgoing * (end - station), outgoing, 0.0))
        else:  # no room to blend: the climb rate steps here
            pieces.append(_Quadratic(station, depth, outgoing, 0.0))
    kept: list[_Quadratic] = []
    for piece in reversed(pieces):  # drop pieces of zero length (a blend that starts at 0, ...)
        if not kept or piece.start < kept[-1].start:
            kept.append(piece)
    return tuple(_Quadratic(*(float(v) for v in piece)) for piece in reversed(kept))


def lawnmower_points(
    origin: object,
    width: float,
    spacing: float,
    lanes: int,
    heading: float = 0.0,
    depth: float | None = None,
) -> np.ndarray:
    """Waypoints of a boustrophedon survey: ``lanes`` lanes of length ``width``, alternating.

    Parameters
    ----------
    origin : (float, float)
        Start of the first lane (m).
    width : float
        Lane length (m), > 0.
    spacing : float
        Distance between neighbouring lanes (m), > 0.
    lanes : int
        Number of lanes, >= 1.
    heading : float
        Direction of the first lane (rad); the lanes are stacked along ``heading + π/2``.
    depth : float or None
        Depth (m) of every waypoint (a third column), or ``None`` for planar waypoints.

    Returns
    -------
    numpy.ndarray, shape (2 lanes, 2) or (2 lanes, 3)
        Start and end of every lane in travel order.
    """
    x0, y0 = check.vector("origin", origin, 2)
    width = check.positive_float("width", width)
    spacing = check.positive_float("spacing", spacing)
    lanes = check.positive_int("lanes", lanes)
    heading = check.finite_float("heading", heading)
    along = np.array([math.cos(heading), math.sin(heading)])
    across = np.array([-along[1], along[0]])
    corners: list[np.ndarray] = []
    for lane in range(lanes):
        offset = np.array([x0, y0]) + lane * spacing * across
        ends = (0.0, width) if lane % 2 == 0 else (width, 0.0)
        corners.extend(offset + end * along for end in ends)
    points = np.array(corners)
    if depth is None:
        return points
    depth = check.finite_float("depth", depth)
    return np.column_stack([points, np.full(len(points), depth)])
