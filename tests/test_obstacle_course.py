"""Obstacles between the nodes: the tolerance of ``obstacles.between_nodes`` and closed loops on a course.

The bound is checked against sampled paths (brute force, seeded), the closed loops against an
independent numpy distance at every plant integration step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.obstacles import between_nodes, centre_motion, vehicle_motion

SAMPLES = 2001  # points per sampled path between two nodes


def _implicit(obstacle: uo.Obstacle, points: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """(ξ/a)² + (η/b)² − scale² of the enlarged obstacle (numpy, independent of CasADi): < 0 inside."""
    offset = points - np.asarray(obstacle.centre)
    cos_a, sin_a = math.cos(obstacle.angle), math.sin(obstacle.angle)
    xi = cos_a * offset[:, 0] + sin_a * offset[:, 1]
    eta = -sin_a * offset[:, 0] + cos_a * offset[:, 1]
    a, b = obstacle.axes[0] + obstacle.margin, obstacle.axes[1] + obstacle.margin
    return (xi / a) ** 2 + (eta / b) ** 2 - scale**2


def _boundary(obstacle: uo.Obstacle, angle: np.ndarray, scale: float) -> np.ndarray:
    """Points of the enlarged boundary scaled by ``scale`` at parameter ``angle`` (rad)."""
    a, b = obstacle.axes[0] + obstacle.margin, obstacle.axes[1] + obstacle.margin
    local = np.stack([scale * a * np.cos(angle), scale * b * np.sin(angle)], axis=-1)
    cos_a, sin_a = math.cos(obstacle.angle), math.sin(obstacle.angle)
    rotation = np.array([[cos_a, -sin_a], [sin_a, cos_a]])
    return local @ rotation.T + np.asarray(obstacle.centre)


def _bulging_path(start: np.ndarray, end: np.ndarray, dt: float, acceleration: float, centre: np.ndarray):
    """Chord from ``start`` to ``end`` bent toward ``centre`` by the largest acceleration: (points, speed).

    ``p(t) = chord(t) + n a t (dt − t) / 2`` with ``n`` the chord's unit normal toward the
    centre: ``‖p̈‖ = a``, and the speed is largest at the ends.
    """
    t = np.linspace(0.0, dt, SAMPLES)[:, None]
    chord = end - start
    normal = np.array([-chord[1], chord[0]]) / np.linalg.norm(chord)
    if normal @ (centre - 0.5 * (start + end)) < 0:
        normal = -normal
    points = start + chord * t / dt + normal * acceleration * t * (dt - t) / 2.0
    speed = math.hypot(np.linalg.norm(chord) / dt, acceleration * dt / 2.0)
    return points, speed


def _random_obstacle(rng: np.random.Generator, kind: str) -> uo.Obstacle:
    centre = tuple(rng.uniform(-5.0, 5.0, 2))
    margin = rng.uniform(0.0, 1.0)
    if kind == "circle":
        return uo.Obstacle.circle(centre, rng.uniform(0.1, 2.0), margin=margin)
    axes = tuple(rng.uniform(0.1, 2.5, 2))
    return uo.Obstacle.ellipse(centre, axes, rng.uniform(-math.pi, math.pi), margin=margin)


@pytest.mark.parametrize("kind", ["circle", "ellipse"])
def test_paths_between_tightened_nodes_stay_out_of_the_enlarged_obstacle(kind):
    """Brute force: ends on the tightened boundary, bent inward at the largest acceleration."""
    rng = np.random.default_rng(30)
    deepest = []
    for _ in range(300):
        obstacle = _random_obstacle(rng, kind)
        dt = rng.uniform(0.02, 0.5)
        speed = rng.uniform(0.1, 3.0)
        acceleration = rng.uniform(0.0, min(20.0, 2.0 * speed / dt))  # a dt / 2 <= v: a path exists
        tolerance = between_nodes(obstacle, dt, speed, acceleration)
        scale = 1.0 + tolerance / (min(obstacle.axes) + obstacle.margin)
        # the chord as long as the speed allows once the bend's own speed is counted
        longest = dt * math.sqrt(max(speed**2 - (acceleration * dt / 2.0) ** 2, 0.0))
        start_angle = rng.uniform(-math.pi, math.pi)
        # the end on the same tightened boundary, at the chord length asked (bisection on the angle)
        low, high = 0.0, math.pi
        start = _boundary(obstacle, np.array(start_angle), scale)
        for _ in range(60):
            middle = 0.5 * (low + high)
            gap = np.linalg.norm(_boundary(obstacle, np.array(start_angle + middle), scale) - start)
            low, high = (middle, high) if gap < longest * rng.uniform(0.999, 1.0) else (low, middle)
        end = _boundary(obstacle, np.array(start_angle + low), scale)
        points, path_speed = _bulging_path(start, end, dt, acceleration, np.asarray(obstacle.centre))
        assert path_speed <= speed * (1 + 1e-9)
        inside = _implicit(obstacle, points)
        assert np.all(inside >= -1e-9), (obstacle, dt, speed, acceleration, float(inside.min()))
        deepest.append(float(inside.min()))
    # the circle's bound is exact for this worst case: some paths end up within 1e-3 of the margin
    if kind == "circle":
        assert min(deepest) < 1e-3


def test_the_circle_bound_is_tight_and_a_smaller_tolerance_lets_the_chord_in():
    rng = np.random.default_rng(7)
    for _ in range(50):
        radius, margin, dt, speed = rng.uniform(0.2, 2.0), rng.uniform(0.0, 1.0), rng.uniform(0.05, 0.5), 2.0
        obstacle = uo.Obstacle.circle((0.0, 0.0), radius, margin=margin)
        tolerance = between_nodes(obstacle, dt, speed)
        enlarged = radius + margin
        half = speed * dt / 2.0
        # a straight chord of length v dt with both ends on the tightened circle
        for factor, expect_inside in ((1.0, False), (0.9, True)):
            height = math.sqrt((enlarged + factor * tolerance) ** 2 - half**2)
            chord = np.stack([np.linspace(-half, half, SAMPLES), np.full(SAMPLES, height)], axis=1)
            nearest = float(np.min(np.linalg.norm(chord, axis=1)))
            if expect_inside:
                assert nearest < enlarged
            else:
                assert nearest == pytest.approx(enlarged, abs=1e-12)


def test_the_ellipse_bisection_agrees_with_the_circle_formula_and_the_bound_grows_as_it_should():
    rng = np.random.default_rng(3)
    for _ in range(100):
        radius, margin = rng.uniform(0.1, 3.0), rng.uniform(0.0, 1.0)
        dt, speed, acceleration = rng.uniform(0.01, 1.0), rng.uniform(0.0, 3.0), rng.uniform(0.0, 10.0)
        circle = uo.Obstacle.circle((1.0, 2.0), radius, margin=margin)
        round_ellipse = uo.Obstacle.ellipse((1.0, 2.0), (radius, radius), 0.3, margin=margin)
        exact = between_nodes(circle, dt, speed, acceleration)
        assert between_nodes(round_ellipse, dt, speed, acceleration) == pytest.approx(
            exact, rel=1e-9, abs=1e-15
        )
        # the closed form's two terms: the chord's sagitta and the bend, to first order
        enlarged = radius + margin
        first_order = (speed * dt) ** 2 / (8.0 * enlarged) + acceleration * dt**2 / 8.0
        assert exact <= first_order * (1 + 1e-12) + 1e-15
    assert between_nodes(uo.Obstacle.circle((0, 0), 1.0), 0.1, 0.0, 0.0) == 0.0
    flat = uo.Obstacle.ellipse((0, 0), (3.0, 0.5))
    # a flatter ellipse curves more sharply at its tips: more tolerance than the inscribed circle
    assert between_nodes(flat, 0.2, 2.0, 1.0) > between_nodes(uo.Obstacle.circle((0, 0), 0.5), 0.2, 2.0, 1.0)


def test_motion_bounds_of_obstacles_and_vehicles():
    diver = uo.Obstacle.moving(lambda t: (3.5 + 0.2 * t, -1.0 + 0.1 * t), 0.3)
    speed, acceleration = centre_motion(diver, 0.0, 10.0)
    assert speed == pytest.approx(math.hypot(0.2, 0.1), rel=1e-12) and acceleration == pytest.approx(
        0.0, abs=1e-12
    )
    circling = uo.Obstacle.moving(lambda t: (2.0 * np.cos(0.5 * t), 2.0 * np.sin(0.5 * t)), 0.3)
    speed, acceleration = centre_motion(circling, 0.0, 10.0)
    assert speed == pytest.approx(1.0, rel=1e-9) and acceleration == pytest.approx(0.5, rel=1e-9)
    assert centre_motion(uo.Obstacle.circle((0, 0), 1.0), 0.0, 1.0) == (0.0, 0.0)
    rexrov = uo.Vehicle.rexrov()
    top, largest = vehicle_motion(rexrov)
    assert top == rexrov.max_horizontal_speed()[0]
    # at rest, full surge force alone: M_x⁻¹ τ_x, a lower bound of the sampled largest acceleration
    assert largest >= rexrov.max_thrust[0] / rexrov.inertia_diagonal[0]


def test_obstacle_tolerance_is_checked_and_tightens_the_node_constraint():
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    rock = uo.Obstacle.circle((5.0, 0.2), 1.0, margin=1.0)
    with pytest.raises(ValueError, match="obstacle_tolerance"):
        uo.TrackingProblem(uo.Vehicle.rexrov(), line, obstacles=[rock], obstacle_tolerance=-0.1)
    with pytest.raises(ValueError, match="obstacle_tolerance"):
        uo.TrackingProblem(uo.Vehicle.rexrov(), line, obstacles=[rock], obstacle_tolerance="safe")
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), line, horizon=5, obstacles=[rock], obstacle_tolerance="auto"
    )
    speed, acceleration = vehicle_motion(uo.Vehicle.rexrov())
    (tolerance,) = problem.obstacle_tolerances
    assert tolerance == between_nodes(rock, 0.1, speed, acceleration)
    assert 1e-3 < tolerance < 1e-2  # a few mm at dt = 0.1 s
    assert uo.TrackingProblem(uo.Vehicle.rexrov(), line, obstacles=[rock]).obstacle_tolerances == (0.0,)
    # the problem's own node constraint: held on the tightened circle, broken halfway to the margin
    (constraint, node), *_ = [(c, f) for c, f in problem.spec().constraints if c.place == "node"]
    x = problem.initial_state(0.0)
    for distance, feasible in ((2.0 + tolerance + 1e-9, True), (2.0 + 0.5 * tolerance, False)):
        x[:2] = (5.0, 0.2 + distance)
        value = float(node(x, np.zeros(3), np.zeros(3), np.zeros(0), np.zeros(node.size1_in(4))))
        held = bool(constraint.lower[0] <= value <= constraint.upper[0])
        assert held == feasible, (distance, value)


# --------------------------------------------------------------------------- closed loops on a course
# a short RexROV course: a rock just off the line and a diver crossing it, both met within 6 s
ROCK = ((2.0, 0.15), 0.4, 0.3)  # centre (m), radius (m), margin (m)
DIVER_SPEED = 0.1  # m/s, crossing the line upward


def _diver_centre(t):
    return (3.2, -1.0 + DIVER_SPEED * t)


def _course(tolerance: float | str) -> uo.TrackingProblem:
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    obstacles = [
        uo.Obstacle.circle(ROCK[0], ROCK[1], margin=ROCK[2], name="rock"),
        uo.Obstacle.moving(_diver_centre, 0.3, margin=0.3, name="diver"),
    ]
    return uo.TrackingProblem(
        uo.Vehicle.rexrov(),
        line,
        horizon=8,
        dt=0.2,
        terminal="cost",
        obstacles=obstacles,
        obstacle_tolerance=tolerance,
    )


def _smallest_clearance(run) -> float:
    """Smallest distance (m) of the plant, at every integration step, to either enlarged obstacle (numpy)."""
    t, positions = run.substep_t, run.substep_states[:, :2]
    rock = np.linalg.norm(positions - np.asarray(ROCK[0]), axis=1) - (ROCK[1] + ROCK[2])
    centres = np.stack([np.full_like(t, 3.2), -1.0 + DIVER_SPEED * t], axis=1)
    diver = np.linalg.norm(positions - centres, axis=1) - 0.6
    return float(min(rock.min(), diver.min()))


def _closed_loop(solver: str, tolerance: float | str = "auto"):
    problem = _course(tolerance)
    # small swarms: the plant path is checked here, not the swarm's quality
    swarm = solver.split("+")[0]
    small = {"samples": 64, "iterations": 4} if swarm == "mppi" else {"population": 8, "iterations": 8}
    options = {"swarm": small} if "+" in solver else (small if swarm == "mppi" else None)
    controller = uo.NMPC(problem, solver, options=options, seed=1)
    return uo.simulate(controller, problem.initial_state(0.0), duration=7.0, record_substeps=True)


def _course_solvers() -> list[str]:
    """MPPI alone and every registered hybrid: a hybrid registered later is tested without an edit."""
    from uuv_ocp.solvers import REGISTRY

    return ["mppi"] + [name for name in REGISTRY.names() if REGISTRY.kind(name) == "hybrid"]


@pytest.mark.slow
@pytest.mark.parametrize("solver", _course_solvers())
def test_no_plant_step_enters_a_margin_on_the_course(solver):
    run = _closed_loop(solver)
    assert run.substep_states.shape[0] == 10 * run.controls.shape[0] + 1  # every plant step recorded
    assert np.max(run.substep_t) >= 6.9
    clearance = _smallest_clearance(run)
    # the obstacles were met (the line runs through the rock's margin), and never entered; a
    # loop whose plans all fail stops short of the rock (the braking fallback) rather than in it
    assert 0.0 <= clearance < 0.25, (solver, clearance)


@pytest.mark.slow
def test_without_the_tolerance_the_plant_cuts_into_the_margin_between_nodes():
    # the same loop, nodes only: the sub-step check above fails (what the tolerance is for)
    assert _smallest_clearance(_closed_loop("sqp", 0.0)) < 0.0


@pytest.mark.parametrize("axes", [(10.0, 1.0), (5.0, 1.0), (3.0, 0.2)])
def test_a_chord_across_a_flat_ellipse_tip_stays_out(axes):
    """A flat ellipse's tip: chords longer than twice its radius of curvature there (b²/a).

    Both ends on the tightened boundary either side of the tip, the chord as long as the speed
    allows; the disc of the tip's curvature alone bounds the depth only up to its radius.
    """
    obstacle = uo.Obstacle.ellipse((0.0, 0.0), axes, 0.0)
    dt, speed = 0.5, 2.0
    tolerance = between_nodes(obstacle, dt, speed)
    scale = 1.0 + tolerance / min(axes)
    # bisection on the half-angle about the tip (angle 0) for a chord of length v dt
    low, high = 0.0, math.pi / 2
    for _ in range(80):
        middle = 0.5 * (low + high)
        ends = _boundary(obstacle, np.array([-middle, middle]), scale)
        low, high = (middle, high) if np.linalg.norm(ends[1] - ends[0]) < speed * dt else (low, middle)
    ends = _boundary(obstacle, np.array([-low, low]), scale)
    chord = ends[0] + np.linspace(0.0, 1.0, SAMPLES)[:, None] * (ends[1] - ends[0])
    assert np.min(_implicit(obstacle, chord)) >= -1e-12
