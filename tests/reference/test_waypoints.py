"""Waypoint, lawnmower, hold and 3-D references, and headings independent of the tangent.

Every expected value here is computed independently of ``uuv_ocp.reference``: the corner
geometry from the bisector of each corner, derivatives by finite differences or closed forms.
"""

import math

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.reference.path import Reference


# ------------------------------------------------------------------ independent geometry
def corners(points, radius):
    """Per interior waypoint: None (straight through) or a dict of its arc.

    The interior angle ``beta`` between the legs gives the tangent length ``R / tan(beta/2)``,
    the centre at ``R / sin(beta/2)`` from the corner along the bisector, and the arc length
    ``R (pi - beta)``.
    """
    points = np.asarray(points, dtype=float)[:, :2]
    result = []
    for i in range(1, len(points) - 1):
        back = points[i - 1] - points[i]
        ahead = points[i + 1] - points[i]
        back, ahead = back / np.linalg.norm(back), ahead / np.linalg.norm(ahead)
        beta = math.acos(float(np.clip(back @ ahead, -1.0, 1.0)))
        if math.pi - beta < 1e-12:
            result.append(None)
            continue
        bisector = (back + ahead) / np.linalg.norm(back + ahead)
        incoming = -back
        side = math.copysign(1.0, incoming[0] * ahead[1] - incoming[1] * ahead[0])
        result.append(
            {
                "tangent": radius / math.tan(beta / 2),
                "centre": points[i] + radius / math.sin(beta / 2) * bisector,
                "length": radius * (math.pi - beta),
                "turn": side * (math.pi - beta),
            }
        )
    return result


def segments(points, radius):
    """Independent layout: list of (kind, s_begin, s_end, data) along the arc length."""
    points = np.asarray(points, dtype=float)[:, :2]
    arcs = [None, *corners(points, radius), None]
    out, s = [], 0.0
    for i in range(len(points) - 1):
        leg = points[i + 1] - points[i]
        cut = sum(arcs[k]["tangent"] for k in (i, i + 1) if arcs[k] is not None)
        straight = np.linalg.norm(leg) - cut
        if straight > 1e-12:
            out.append(("line", s, s + straight, math.atan2(leg[1], leg[0])))
            s += straight
        arc = arcs[i + 1]
        if arc is not None:
            out.append(("arc", s, s + arc["length"], arc))
            s += arc["length"]
    return out


def total_length(points, radius):
    points = np.asarray(points, dtype=float)[:, :2]
    legs = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
    arcs = [arc for arc in corners(points, radius) if arc is not None]
    return legs - 2 * sum(a["tangent"] for a in arcs) + sum(a["length"] for a in arcs)


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def random_walk(seed, count, leg=(10.0, 20.0), max_turn=2.4):
    rng = np.random.default_rng(seed)
    angles = np.cumsum(np.r_[rng.uniform(-np.pi, np.pi), rng.uniform(-max_turn, max_turn, count - 2)])
    lengths = rng.uniform(*leg, count - 1)
    steps = np.column_stack([lengths * np.cos(angles), lengths * np.sin(angles)])
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + rng.uniform(-50, 50, 2)


SQUARE = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
ZIGZAG = [[0.0, 0.0], [8.0, 3.0], [12.0, -4.0], [20.0, -2.0], [25.0, 6.0]]
CASES = {
    "square": (SQUARE, 1.0, 2.0, 0.0),
    "zigzag": (ZIGZAG, 0.7, 1.5, 3.0),
    "random": (random_walk(7, 9), 1.3, 1.0, -4.0),
    "tight": ([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [8.0, 4.0]], 0.5, 2.0, 0.0),  # arc meets arc
}


def velocity_from_state(states):
    """Inertial velocity from the body-frame [u, v] and the heading psi (planar columns)."""
    psi, u, v = states[:, 2], states[:, 3], states[:, 4]
    return np.column_stack([u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)])


def joint_times(points, speed, radius, t_start):
    layout = segments(points, radius)
    return t_start + np.array([seg[1] for seg in layout[1:]]) / speed


# ------------------------------------------------------------------------ waypoints
@pytest.mark.parametrize("case", list(CASES))
def test_position_and_velocity_are_continuous_at_every_joint(case):
    points, speed, radius, t_start = CASES[case]
    reference = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    scale = max(1.0, float(np.max(np.abs(points))))
    joints = joint_times(points, speed, radius, t_start)
    assert joints.size >= 1
    h, tiny = 1e-4, 1e-9
    for tau in joints:
        stencil = reference.evaluate(tau + h * np.array([-2, -1, 0, 1, 2]))[:, :2]
        left = (3 * stencil[2] - 4 * stencil[1] + stencil[0]) / (2 * h)  # one-sided, 2nd order
        right = (-3 * stencil[2] + 4 * stencil[3] - stencil[4]) / (2 * h)
        assert np.linalg.norm(left - right) < 1e-6 * speed, (case, tau)
        around = reference.evaluate([tau - tiny, tau, tau + tiny])
        # position: no jump beyond the motion over 2 * tiny
        jump = np.linalg.norm(around[2, :2] - around[0, :2]) - 2 * tiny * speed
        assert abs(jump) < 1e-9 * scale, (case, tau, jump)
        # velocity from the reference's own u, v and psi: continuous, and equal to the FD one
        velocity = velocity_from_state(around)
        assert np.max(np.abs(velocity[2] - velocity[0])) < 1e-6 * speed
        assert np.max(np.abs(velocity[1] - left)) < 1e-6 * speed
        # derivatives exactly on the joint are those of one side: finite, r in {0, ±v/R}
        assert np.all(np.isfinite(around))
        assert min(abs(around[1, 5]), abs(abs(around[1, 5]) - speed / radius)) < 1e-12


@pytest.mark.parametrize("case", list(CASES))
def test_speed_is_constant_along_the_whole_path(case):
    points, speed, radius, t_start = CASES[case]
    reference = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    dense = np.linspace(reference.t_start, reference.t_end, 20001)
    states = reference.evaluate(dense)
    assert np.max(np.abs(states[:, 3] - speed)) < 1e-9
    assert np.max(np.abs(states[:, 4])) < 1e-12
    # finite differences of the positions (central, h = 1e-6 s)
    h = 1e-6
    inner = dense[1:-1]
    ahead = reference.evaluate(inner + h)[:, :2]
    behind = reference.evaluate(inner - h)[:, :2]
    fd_speed = np.linalg.norm(ahead - behind, axis=1) / (2 * h)
    assert np.max(np.abs(fd_speed - speed)) < 1e-5 * speed


@pytest.mark.parametrize("case", list(CASES))
def test_heading_is_continuous_and_follows_the_legs(case):
    points, speed, radius, t_start = CASES[case]
    reference = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    dense = np.linspace(reference.t_start, reference.t_end, 5001)
    psi = reference.evaluate(dense)[:, 2]
    step = dense[1] - dense[0]
    assert np.max(np.abs(np.diff(psi))) <= speed / radius * step * (1 + 1e-9) + 1e-12
    arcs = [arc for arc in corners(points, radius) if arc is not None]
    # unwrapped: the total change is the sum of the signed turns
    assert psi[-1] - psi[0] == pytest.approx(sum(a["turn"] for a in arcs), abs=1e-9)
    for kind, begin, end, data in segments(points, radius):
        if kind != "line":
            continue
        times = t_start + np.linspace(begin, end, 7)[1:-1] / speed
        states = reference.evaluate(times)
        assert np.max(np.abs(wrap(states[:, 2] - data))) < 1e-9
        assert np.max(np.abs(states[:, 5])) < 1e-12


@pytest.mark.parametrize("case", list(CASES))
def test_arcs_are_circles_of_the_turn_radius(case):
    points, speed, radius, t_start = CASES[case]
    reference = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    scale = max(1.0, float(np.max(np.abs(points))))
    arcs = [seg for seg in segments(points, radius) if seg[0] == "arc"]
    assert arcs
    for _, begin, end, arc in arcs:
        times = t_start + np.linspace(begin, end, 13)[1:-1] / speed
        states = reference.evaluate(times)
        distance = np.linalg.norm(states[:, :2] - arc["centre"], axis=1)
        np.testing.assert_allclose(distance, radius, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(states[:, 5], math.copysign(speed / radius, arc["turn"]), atol=1e-12)


@pytest.mark.parametrize("case", list(CASES))
def test_duration_is_length_over_speed_and_ends_are_the_waypoints(case):
    points, speed, radius, t_start = CASES[case]
    reference = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    assert reference.t_start == t_start
    assert reference.t_end - reference.t_start == pytest.approx(
        total_length(points, radius) / speed, rel=1e-12
    )
    ends = reference.evaluate([reference.t_start, reference.t_end])[:, :2]
    np.testing.assert_allclose(ends, np.asarray(points)[[0, -1]], atol=1e-9)


def test_square_numbers_by_hand():
    # 10 m square, R = 2: three legs lose 2 R in total each side pair, two quarter circles
    reference = Reference.waypoints(SQUARE, 1.0, 2.0, hold=0.0)
    assert reference.t_end == pytest.approx(30.0 - 4 * 2.0 + 2 * (math.pi / 2) * 2.0)
    quarter = reference.evaluate([8.0 + math.pi / 2])[0]  # halfway round the first arc
    np.testing.assert_allclose(
        quarter[:3], [8 + 2 * math.sin(math.pi / 4), 2 - 2 * math.cos(math.pi / 4), math.pi / 4]
    )


def test_straight_through_waypoint_needs_no_arc():
    points = [[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [10.0, 8.0]]
    reference = Reference.waypoints(points, 1.0, 2.0, hold=0.0)
    assert reference.t_end == pytest.approx(10.0 - 2.0 + 8.0 - 2.0 + math.pi)
    straight = reference.evaluate(np.linspace(0.0, 8.0, 81))
    np.testing.assert_allclose(straight[:, 1:3], 0.0, atol=1e-15)
    np.testing.assert_allclose(straight[:, 0], np.linspace(0.0, 8.0, 81), atol=1e-12)
    # a turn below 1e-9 rad counts as straight through as well
    nearly = Reference.waypoints([[0.0, 0.0], [5.0, 0.0], [10.0, 1e-12], [10.0, 8.0]], 1.0, 2.0, hold=0.0)
    assert nearly.t_end == pytest.approx(reference.t_end, abs=1e-9)


def test_heading_unwraps_over_repeated_loops():
    loop = SQUARE + [[0.0, 0.0]]
    points = loop + loop[1:] + loop[1:] + [[10.0, 0.0]]  # three laps, 12 left turns
    reference = Reference.waypoints(points, 1.0, 2.0, hold=0.0)
    psi = reference.evaluate(np.linspace(0.0, reference.t_end, 3001))[:, 2]
    assert psi[-1] - psi[0] == pytest.approx(12 * math.pi / 2, abs=1e-9)
    assert np.all(np.diff(psi) >= -1e-12)


def test_many_waypoints_cost_no_more_than_few():
    few = Reference.waypoints(random_walk(1, 4), 1.0, 1.0, hold=0.0)
    many = Reference.waypoints(random_walk(2, 40), 1.0, 1.0, hold=0.0)
    # up to CHAIN_ROWS pieces a chain of if_else, beyond it binary searches: the instruction
    # count is bounded whatever the number of pieces
    assert many.function.n_instructions() <= few.function.n_instructions() + 5
    assert many.function.n_instructions() < 200
    many.evaluate_grid(10.0 + 0.1 * np.arange(21))  # windows as TrackingProblem evaluates them


def test_a_lawnmowers_jacobian_is_exact_across_two_evaluations():
    """``b + p(a)``: its Jacobian in ``b`` is the constant identity, as for a gap ``X_(k+1) − F``.

    Analytic: ``p(a)`` does not read ``b``.  The C step's stage map needs the constant block
    (the gap of the REMUS survey was refused while the piece look-ups were interpolant calls:
    their forward derivatives with a zero seed stayed in the Jacobian, reading ``a``).
    """
    survey = Reference.lawnmower(width=40.0, spacing=10.0, lanes=3, speed=1.5, depth=10.0)
    a, b = ca.SX.sym("a"), ca.SX.sym("b")
    size = survey.function.size1_out(0)
    values = ca.vertcat(b + survey.function(a), survey.function(b))
    block = ca.jacobian(values, b)[:size, 0]
    assert block.is_constant()
    np.testing.assert_array_equal(np.array(ca.DM(block)).ravel(), np.ones(size))


def test_waypoints_work_in_a_tracking_problem():
    reference = Reference.waypoints(SQUARE, 0.5, 2.0, hold=0.0)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=10)
    for t0 in (15.5, 15.0):  # the first arc starts at 8 m / 0.5 m/s = 16 s; 15.0 s: cached blocks
        window = problem.reference_window(t0)
        expected = reference.evaluate(t0 + 0.1 * np.arange(11))
        np.testing.assert_allclose(window, expected, atol=1e-12)


# ---------------------------------------------------------------------- 3-D waypoints
POINTS_3D = [[0.0, 0.0, 0.0], [10.0, 0.0, 4.0], [10.0, 10.0, 5.0], [0.0, 10.0, 1.0], [0.0, 20.0, 1.0]]


def test_spatial_waypoints_share_the_horizontal_path_and_keep_roll_pitch_zero():
    spatial = Reference.waypoints(POINTS_3D, 0.8, 2.5, hold=0.0)
    planar = Reference.waypoints(np.asarray(POINTS_3D)[:, :2], 0.8, 2.5, hold=0.0)
    assert spatial.spatial and spatial.state_dim == 12 and spatial.heading_index == 5
    assert spatial.t_end == planar.t_end
    t = np.linspace(0.0, spatial.t_end, 2001)
    s, p = spatial.evaluate(t), planar.evaluate(t)
    np.testing.assert_allclose(s[:, [0, 1, 5, 6, 7, 11]], p, atol=1e-12)
    assert np.all(s[:, [3, 4, 9, 10]] == 0.0)
    np.testing.assert_allclose(s[[0, -1], 2], [0.0, 1.0], atol=1e-12)


def test_spatial_waypoints_are_c1_in_depth_and_linear_between_stations():
    speed, radius = 0.8, 2.5
    reference = Reference.waypoints(POINTS_3D, speed, radius, hold=0.0)
    layout = segments(POINTS_3D, radius)
    # w = dz/dt by finite differences, everywhere
    t = np.linspace(1e-3, reference.t_end - 1e-3, 4001)
    h = 1e-6
    fd = (reference.evaluate(t + h)[:, 2] - reference.evaluate(t - h)[:, 2]) / (2 * h)
    np.testing.assert_allclose(reference.evaluate(t)[:, 8], fd, atol=1e-7)
    # w continuous at every joint (arc ends are where the depth blends start and stop)
    for tau in joint_times(POINTS_3D, speed, radius, 0.0):
        w = reference.evaluate([tau - 1e-9, tau + 1e-9])[:, 8]
        assert abs(w[1] - w[0]) < 1e-6 * speed
    # stations: ends and arc midpoints; on straight pieces z is linear in the arc length
    arcs = [seg for seg in layout if seg[0] == "arc"]
    stations = [0.0] + [0.5 * (a[1] + a[2]) for a in arcs] + [layout[-1][2]]
    z = np.asarray(POINTS_3D)[:, 2]
    lines = [seg for seg in layout if seg[0] == "line"]
    for leg, (_, begin, end, _) in enumerate(lines):
        slope = (z[leg + 1] - z[leg]) / (stations[leg + 1] - stations[leg])
        times = np.linspace(begin, end, 5)[1:-1] / speed
        states = reference.evaluate(times)
        np.testing.assert_allclose(states[:, 8], slope * speed, atol=1e-12)
        np.testing.assert_allclose(states[:, 2], z[leg] + slope * (speed * times - stations[leg]), atol=1e-9)


def test_spatial_straight_through_waypoint_blends_the_slope():
    points = [[0.0, 0.0, 0.0], [10.0, 0.0, 5.0], [20.0, 0.0, 5.0]]
    reference = Reference.waypoints(points, 1.0, 2.0, hold=0.0)
    w = reference.evaluate([10.0 - 1e-9, 10.0, 10.0 + 1e-9])[:, 8]
    assert np.max(np.abs(np.diff(w))) < 1e-6
    assert reference.evaluate([5.0])[0, 8] == pytest.approx(0.5)
    assert reference.evaluate([15.0])[0, 8] == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------------- lawnmower
def test_lawnmower_lanes_are_parallel_and_spaced_as_asked():
    origin, width, spacing, lanes, speed, heading = (5.0, -2.0), 30.0, 6.0, 4, 0.8, 0.4
    reference = Reference.lawnmower(
        origin, width=width, spacing=spacing, lanes=lanes, speed=speed, heading=heading, hold=0.0
    )
    radius = spacing / 2
    along = np.array([math.cos(heading), math.sin(heading)])
    across = np.array([-math.sin(heading), math.cos(heading)])
    # independent layout: lanes shortened by R at each turn; each lane change a semicircle
    begin = 0.0
    for lane in range(lanes):
        straight = width - radius * ((lane > 0) + (lane < lanes - 1))
        times = (begin + np.linspace(0.0, straight, 9)[1:-1]) / speed
        states = reference.evaluate(times)
        offset = (states[:, :2] - origin) @ across
        np.testing.assert_allclose(offset, lane * spacing, atol=1e-9)
        np.testing.assert_allclose(wrap(states[:, 2] - heading - lane * math.pi), 0.0, atol=1e-9)
        begin += straight + math.pi * radius
    assert reference.t_end == pytest.approx((begin - math.pi * radius) / speed)
    end = reference.evaluate([reference.t_end])[0, :2]
    np.testing.assert_allclose(
        end, origin + (lanes - 1) * spacing * across + (0 if lanes % 2 == 0 else width) * along, atol=1e-9
    )


def test_lawnmower_at_depth_is_spatial_and_level():
    reference = Reference.lawnmower(
        width=20.0, spacing=5.0, lanes=3, speed=1.0, turn_radius=2.0, depth=12.0, hold=0.0
    )
    assert reference.spatial
    states = reference.evaluate(np.linspace(0.0, reference.t_end, 501))
    np.testing.assert_allclose(states[:, 2], 12.0, atol=1e-12)
    np.testing.assert_allclose(states[:, 8], 0.0, atol=1e-12)
    np.testing.assert_allclose(states[:, 6], 1.0, atol=1e-9)
    yaw_rate = np.abs(states[:, 11])
    assert np.all(np.isclose(yaw_rate, 0.0, atol=1e-12) | np.isclose(yaw_rate, 1.0 / 2.0, atol=1e-12))


# ------------------------------------------------------------------------------ hold
def test_hold_keeps_any_heading_at_rest():
    reference = Reference.hold((1.0, -2.0, 3.0))
    assert reference.t_end == math.inf and not reference.spatial
    states = reference.evaluate(np.linspace(0.0, 100.0, 11))
    np.testing.assert_array_equal(states[:, :3], np.tile([1.0, -2.0, 3.0], (11, 1)))
    np.testing.assert_array_equal(states[:, 3:], 0.0)
    np.testing.assert_array_equal(reference.initial_state(), [1.0, -2.0, 3.0, 0.0, 0.0, 0.0])


def test_hold_spatial_pose_and_wrapped_heading():
    reference = Reference.hold((1.0, 2.0, 30.0, 4.0), name="dock", duration=60.0)
    assert reference.spatial and reference.state_dim == 12 and reference.t_end == 60.0
    states = reference.evaluate([0.0, 30.0, 60.0])
    np.testing.assert_allclose(states[:, :6], np.tile([1.0, 2.0, 30.0, 0.0, 0.0, 4.0 - 2 * math.pi], (3, 1)))
    np.testing.assert_array_equal(states[:, 6:], 0.0)
    assert reference.initial_state(10.0).shape == (12,)


def test_hold_works_in_a_tracking_problem():
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), Reference.hold((0.0, 0.0, 3.0)), horizon=5)
    window = problem.reference_window(2.0, heading=3.0)
    np.testing.assert_allclose(window[:, 2], 3.0)
    np.testing.assert_array_equal(window[:, 3:], 0.0)


# -------------------------------------------------------------- heading not the tangent
def test_given_heading_rotates_the_path_velocity_into_the_body_frame():
    circle = Reference.from_xy(
        lambda t: 3 * ca.cos(t), lambda t: 3 * ca.sin(t), "spin", heading=lambda t: 0.3 * t + 1.0
    )
    t = np.linspace(0.0, 40.0, 401)
    states = circle.evaluate(t)
    psi = 0.3 * t + 1.0
    dx, dy = -3 * np.sin(t), 3 * np.cos(t)
    np.testing.assert_allclose(states[:, 2], psi, atol=1e-12)  # 12 rad: unwrapped
    np.testing.assert_allclose(states[:, 3], dx * np.cos(psi) + dy * np.sin(psi), atol=1e-12)
    np.testing.assert_allclose(states[:, 4], -dx * np.sin(psi) + dy * np.cos(psi), atol=1e-12)
    np.testing.assert_allclose(states[:, 5], 0.3, atol=1e-12)


def test_given_heading_allows_a_vanishing_speed():
    stop = Reference.from_xy(lambda t: t**2, lambda t: 0 * t, heading=lambda t: 0.5 + 0 * t)
    states = stop.evaluate([0.0, 1.0])
    np.testing.assert_allclose(states[0], [0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(states[1], [1.0, 0.0, 0.5, 2 * math.cos(0.5), -2 * math.sin(0.5), 0.0])


def test_non_finite_heading_raises_naming_time():
    # refused at construction (its window is checked), naming the first time as evaluation did
    with pytest.raises(ValueError, match=r"heading.*t = 0\.0"):
        Reference.from_xy(lambda t: t, lambda t: 0 * t, heading=lambda t: ca.log(t - 1.0))


# ------------------------------------------------------------------------------- 3-D
def test_from_xyz_helix():
    helix = Reference.from_xyz(
        lambda t: 4 * ca.cos(0.25 * t),
        lambda t: 4 * ca.sin(0.25 * t),
        lambda t: 0.3 * t + 0.5 * ca.sin(0.2 * t),
        "helix",
    )
    assert helix.spatial and helix.state_dim == 12 and helix.heading_index == 5
    t = np.linspace(0.0, 60.0, 601)
    states = helix.evaluate(t)
    # w_R = dz/dt: central differences of the reference's own z (h = 1e-5 s), inside the window
    h, inner = 1e-5, slice(1, None)
    fd = (helix.evaluate(t[inner] + h)[:, 2] - helix.evaluate(t[inner] - h)[:, 2]) / (2 * h)
    np.testing.assert_allclose(states[inner, 8], fd, atol=1e-8)
    np.testing.assert_allclose(states[:, 8], 0.3 + 0.1 * np.cos(0.2 * t), atol=1e-14)
    assert np.all(states[:, [3, 4, 9, 10]] == 0.0)
    np.testing.assert_allclose(states[:, 5], 0.25 * t + math.pi / 2, atol=1e-12)  # 15 rad: unwrapped
    np.testing.assert_allclose(states[:, 6], 1.0, atol=1e-12)
    np.testing.assert_allclose(states[:, 7], 0.0, atol=1e-15)
    np.testing.assert_allclose(states[:, 11], 0.25, atol=1e-12)
    start = helix.initial_state()
    assert start.shape == (12,) and np.all(start[6:] == 0.0)
    np.testing.assert_allclose(start[:6], [4.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2], atol=1e-15)


def test_from_xyz_vertical_dive_needs_a_heading():
    with pytest.raises(ValueError, match=r"does not move horizontally: its horizontal speed is below"):
        Reference.from_xyz(lambda t: 0 * t, lambda t: 0 * t, lambda t: 0.5 * t)
    steered = Reference.from_xyz(
        lambda t: 0 * t, lambda t: 0 * t, lambda t: 0.5 * t, heading=lambda t: 0 * t + 2.0
    )
    np.testing.assert_allclose(steered.evaluate([1.0])[0], [0, 0, 0.5, 0, 0, 2.0, 0, 0, 0.5, 0, 0, 0])


# --------------------------------------------------------------------------- bad input
def line(t):
    return t


def flat(t):
    return 0 * t


BAD_INPUTS = [
    (lambda: Reference.from_xy(line, flat, heading="north"), r"heading must be a callable"),
    (
        lambda: Reference.from_xy(line, flat, heading=lambda t: ca.vertcat(t, t)),
        r"heading must return a scalar",
    ),
    (lambda: Reference.from_xy(line, flat, None), r"name must be a string, got None"),
    (lambda: Reference.from_xy(line, flat, description=3), r"description must be a string"),
    (lambda: Reference.from_xyz(line, flat, "deep"), r"path_z must be a callable"),
    (lambda: Reference.waypoints(SQUARE, 0.0, 1.0), r"speed must be a finite number > 0"),
    (lambda: Reference.waypoints(SQUARE, -1.0, 1.0), r"speed must be a finite number > 0"),
    (lambda: Reference.waypoints(SQUARE, math.nan, 1.0), r"speed must be finite"),
    (lambda: Reference.waypoints(SQUARE, math.inf, 1.0), r"speed must be finite"),
    (lambda: Reference.waypoints([[0.0, 0.0]], 1.0, 1.0), r"points must hold at least 2 waypoints, got 1"),
    (
        lambda: Reference.waypoints([[0.0, 0.0], [1.0, math.nan]], 1.0, 1.0),
        r"points must be finite.*points\[1\]",
    ),
    (lambda: Reference.waypoints([0.0, 1.0, 2.0], 1.0, 1.0), r"points must have shape \(n, 2\) or \(n, 3\)"),
    (lambda: Reference.waypoints(np.zeros((3, 4)), 1.0, 1.0), r"points must have shape"),
    (lambda: Reference.waypoints([[0, 0], [1]], 1.0, 1.0), r"points must be an \(n, 2\) or \(n, 3\) array"),
    (lambda: Reference.waypoints(SQUARE, 1.0, 0.0), r"turn_radius must be a finite number > 0"),
    (lambda: Reference.waypoints(SQUARE, 1.0, -2.0), r"turn_radius must be a finite number > 0"),
    (lambda: Reference.waypoints(SQUARE, 1.0, math.nan), r"turn_radius must be finite"),
    (
        lambda: Reference.waypoints(SQUARE, 1.0, 6.0),
        r"turn_radius = 6 m is too large for the turns at waypoints 1 and 2",
    ),
    (
        lambda: Reference.waypoints(ZIGZAG[:3], 1.0, 30.0),
        r"turn_radius = 30 m is too large for the turn at waypoint 1",
    ),
    (
        lambda: Reference.waypoints([[0, 0], [5, 0], [5, 0], [5, 5]], 1.0, 1.0),
        r"points\[1\] and points\[2\] must differ",
    ),
    (
        lambda: Reference.waypoints([[0, 0, 0], [0, 0, 5]], 1.0, 1.0),
        r"points\[0\] and points\[1\] must differ horizontally",
    ),
    (
        lambda: Reference.waypoints([[0, 0], [5, 0], [2, 0]], 1.0, 1.0),
        r"points: the path reverses at waypoint 1",
    ),
    (lambda: Reference.waypoints(SQUARE, 1.0, 1.0, name=None), r"name must be a string, got None"),
    (
        lambda: Reference.lawnmower(width=0.0, spacing=2.0, lanes=2, speed=1.0),
        r"width must be a finite number > 0",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=-2.0, lanes=2, speed=1.0),
        r"spacing must be a finite number > 0",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=2.0, lanes=0, speed=1.0),
        r"lanes must be an integer >= 1",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=2.0, lanes=2.5, speed=1.0),
        r"lanes must be an integer >= 1",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=2.0, lanes=2, speed=0.0),
        r"speed must be a finite number > 0",
    ),
    (
        lambda: Reference.lawnmower((0, 0, 0), width=10.0, spacing=2.0, lanes=2, speed=1.0),
        r"origin must have shape \(2,\)",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=2.0, lanes=2, speed=1.0, heading="x"),
        r"heading must be a real number",
    ),
    (
        lambda: Reference.lawnmower(width=10.0, spacing=2.0, lanes=2, speed=1.0, depth=math.nan),
        r"depth must be finite",
    ),
    (
        lambda: Reference.lawnmower(width=1.0, spacing=2.0, lanes=3, speed=1.0),
        r"turn_radius = 1 m is too large",
    ),
    (lambda: Reference.hold((1.0, 2.0)), r"pose must be \(x, y, psi\) or \(x, y, z, psi\).*shape \(2,\)"),
    (lambda: Reference.hold((1.0, 2.0, 3.0, 4.0, 5.0)), r"pose must be .*shape \(5,\)"),
    (lambda: Reference.hold((1.0, math.nan, 3.0)), r"pose must be finite"),
    (lambda: Reference.hold("abc"), r"pose must be"),
    (lambda: Reference.hold((1.0, 2.0, 3.0), duration=0.0), r"duration must be a number > 0"),
    (lambda: Reference.hold((1.0, 2.0, 3.0), duration=math.nan), r"duration must be a number > 0"),
    (lambda: Reference.hold((1.0, 2.0, 3.0), name=None), r"name must be a string, got None"),
]


@pytest.mark.parametrize("build, message", BAD_INPUTS, ids=[m for _, m in BAD_INPUTS])
def test_bad_input_raises_naming_the_parameter(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_non_finite_position_is_reported_as_such():
    with pytest.raises(ValueError, match=r"position is not finite at t = 0\.0 s"):
        Reference.from_xy(lambda t: float("nan"), line)


# ------------------------------------------------------------ the paper's s1..s10 unchanged
def paper_closed_form(name, t):
    """y, dy/dt, d²y/dt² of the paper's references (x = 0.5 t), written out by hand."""
    c, s = np.cos(0.5 * t), np.sin(0.5 * t)
    if name == "s3":
        w = 0.5 * t - 7.5
        y = np.sqrt(56.25 - w**2)
        dy = -0.5 * w / y
        return y, dy, (-0.25 * y + 0.5 * w * dy) / y**2
    return {
        "s1": (0.025 * t**2, 0.05 * t, 0.05 + 0 * t),
        "s2": (2 * s, c, -0.5 * s),
        "s4": (0.5 * t + s, 0.5 + 0.5 * c, -0.25 * s),
        "s5": (0.5 * t + c, 0.5 - 0.5 * s, -0.25 * c),
        "s6": (0.5 * t - s, 0.5 - 0.5 * c, 0.25 * s),
        "s7": (0.5 * t - c, 0.5 + 0.5 * s, 0.25 * c),
        "s8": (0.5 * t * s, 0.5 * s + 0.25 * t * c, 0.5 * c - 0.125 * t * s),
        "s9": (0.5 * t * c, 0.5 * c - 0.25 * t * s, -0.5 * s - 0.125 * t * c),
        "s10": (np.log(0.5 * t + 1), 0.5 / (0.5 * t + 1), -0.25 / (0.5 * t + 1) ** 2),
    }[name]


@pytest.mark.parametrize("name", uo.PAPER_REFERENCES)
def test_paper_references_match_closed_forms(name):
    reference = Reference.paper(name)
    assert reference.state_dim == 6 and reference.heading_index == 2 and not reference.spatial
    t = np.linspace(reference.t_start, min(reference.t_end, 30.0), 271)
    y, dy, ddy = paper_closed_form(name, t)
    expected = np.column_stack(
        [0.5 * t, y, np.arctan2(dy, 0.5), np.sqrt(0.25 + dy**2), 0 * t, 0.5 * ddy / (0.25 + dy**2)]
    )
    np.testing.assert_allclose(reference.evaluate(t), expected, rtol=1e-12, atol=1e-12)


def legacy_function(path_y):
    """Build the tangent-heading formulas as the package wrote them before headings could be given."""
    time = ca.SX.sym("t")
    position_x = ca.SX(0.5 * time) + 0 * time
    position_y = ca.SX(path_y(time)) + 0 * time
    velocity_x = ca.jacobian(position_x, time)
    velocity_y = ca.jacobian(position_y, time)
    acceleration_x = ca.jacobian(velocity_x, time)
    acceleration_y = ca.jacobian(velocity_y, time)
    speed_squared = velocity_x**2 + velocity_y**2
    heading = ca.atan2(velocity_y, velocity_x)
    yaw_rate = (velocity_x * acceleration_y - velocity_y * acceleration_x) / speed_squared
    outputs = ca.vertcat(position_x, position_y, heading, ca.sqrt(speed_squared), 0 * time, yaw_rate)
    return ca.Function("legacy", [time], [outputs])


LEGACY_Y = {
    "s1": lambda t: 0.1 * (0.5 * t) ** 2,
    "s2": lambda t: 2.0 * ca.sin(0.5 * t),
    "s3": lambda t: ca.sqrt(7.5**2 - (0.5 * t - 7.5) ** 2),
    "s4": lambda t: 0.5 * t + ca.sin(0.5 * t),
    "s5": lambda t: 0.5 * t + ca.cos(0.5 * t),
    "s6": lambda t: 0.5 * t - ca.sin(0.5 * t),
    "s7": lambda t: 0.5 * t - ca.cos(0.5 * t),
    "s8": lambda t: 0.5 * t * ca.sin(0.5 * t),
    "s9": lambda t: 0.5 * t * ca.cos(0.5 * t),
    "s10": lambda t: ca.log(0.5 * t + 1.0),
}


@pytest.mark.parametrize("name", uo.PAPER_REFERENCES)
def test_paper_references_are_bit_identical_to_the_tangent_formulas(name):
    reference = Reference.paper(name)
    t = np.linspace(reference.t_start, min(reference.t_end, 40.0), 401)
    legacy = np.array(legacy_function(LEGACY_Y[name])(t[None, :])).T
    np.testing.assert_array_equal(np.array(reference.function(t[None, :])).T, legacy)
    states = reference.evaluate(t)
    np.testing.assert_array_equal(states[:, [0, 1, 3, 4, 5]], legacy[:, [0, 1, 3, 4, 5]])
    np.testing.assert_allclose(states[:, 2], legacy[:, 2], rtol=0, atol=1e-13)  # unwrapping: rounding


# ---------------------------------------------------------------------- the mission's end
@pytest.mark.parametrize("case", list(CASES))
def test_a_mission_holds_its_last_waypoint_at_rest(case):
    points, speed, radius, t_start = CASES[case]
    moving = Reference.waypoints(points, speed, radius, t_start=t_start, hold=0.0)
    mission = Reference.waypoints(points, speed, radius, t_start=t_start, hold=7.5)
    length = total_length(points, radius)
    braking = min(radius, length / 2)  # the documented stretch, at speed**2 / (2 braking)
    cruise_end = t_start + (length - braking) / speed
    rest = cruise_end + 2 * braking / speed
    assert mission.t_end == pytest.approx(rest + 7.5, rel=1e-12)
    # the same path up to the braking stretch (the heading: the path's direction, not the
    # tangent of the velocity, which agree there)
    before = np.linspace(t_start, cruise_end, 3001)[:-1]
    np.testing.assert_allclose(mission.evaluate(before), moving.evaluate(before), atol=1e-9)
    # braking: the path speed falls linearly to 0, checked on finite differences of the
    # positions (C¹: no jump of the velocity that AD derivatives would miss)
    t = np.linspace(cruise_end, rest, 401)
    states = mission.evaluate(t)
    expected = speed * (1 - (t - cruise_end) / (rest - cruise_end))
    np.testing.assert_allclose(np.hypot(states[:, 3], states[:, 4]), expected, atol=1e-9)
    path_speed = np.hypot(*np.diff(states[:, :2], axis=0).T) / np.diff(t)
    np.testing.assert_allclose(path_speed, 0.5 * (expected[1:] + expected[:-1]), atol=1e-6)
    # then the last waypoint, with the last leg's heading, at rest
    after = mission.evaluate(np.linspace(rest + 1e-6, mission.t_end, 50))
    np.testing.assert_allclose(after[:, :2], np.tile(points[-1], (50, 1)), atol=1e-9)
    leg = np.asarray(points[-1], dtype=float) - np.asarray(points[-2], dtype=float)
    assert np.allclose(np.cos(after[:, 2]), leg[0] / np.hypot(*leg)) and np.allclose(
        np.sin(after[:, 2]), leg[1] / np.hypot(*leg)
    )
    np.testing.assert_allclose(after[:, 3:], 0.0, atol=1e-12)


def test_a_spatial_mission_holds_its_last_waypoint_and_depth():
    mission = Reference.waypoints(POINTS_3D, 0.8, 2.5, hold=5.0)
    after = mission.evaluate([mission.t_end - 4.0, mission.t_end])
    np.testing.assert_allclose(after[:, :3], np.tile(POINTS_3D[-1], (2, 1)), atol=1e-9)
    np.testing.assert_array_equal(np.abs(after[:, 6:]), 0.0)


@pytest.mark.parametrize("hold", [-1.0, math.nan, math.inf, "5"])
def test_bad_hold_raises(hold):
    with pytest.raises(ValueError, match="hold must be"):
        Reference.waypoints(SQUARE, 1.0, 1.0, hold=hold)
