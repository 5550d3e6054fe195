"""Line-of-sight guidance with autopilots (``uo.LosGuidance``) against independent references.

* the ILOS law against a numpy implementation written here from Fossen (2021) §12.4 /
  ``ILOSpsi.m`` (rotation of the position error into the path frame by a rotation matrix);
* straight-line following of the REMUS 100 under a 0.3 m/s cross current: ILOS removes the
  cross-track error, plain LOS keeps the offset ``Δ tan(asin(V⊥/U_r) + β_r)`` that its crab
  angle needs, with ``U_r`` and the sideslip ``β_r`` measured from the run's positions (finite
  differences) and the current;
* the depth autopilot and the command bounds against the published REMUS numbers of
  ``tests/helpers_remus.py``;
* the propeller speed for 1.5 m/s against the independent model's settled speed.
"""

import math
import warnings

import numpy as np
import pytest

import uuv_ocp as uo
from tests import helpers_remus as remus
from uuv_ocp.control.guidance import ilos_heading

DT = 0.1
DEPTH = 10.0
CURRENT = 0.3  # m/s, towards +y (east): across a path along x (north)


def book_ilos(position, start, end, y_int, lookahead, kappa):
    """ψ_d, ẏ_int, x_e, y_e of Fossen 2021 §12.4 (ILOSpsi.m) in numpy, by a rotation matrix."""
    start, end, position = (np.asarray(v, dtype=float) for v in (start, end, position))
    pi_h = np.arctan2(*(end - start)[::-1])
    rotation = np.array([[np.cos(pi_h), -np.sin(pi_h)], [np.sin(pi_h), np.cos(pi_h)]])
    along, cross = rotation.T @ (position - start)  # path-frame coordinates of the vehicle
    psi_d = pi_h - np.arctan((cross + kappa * y_int) / lookahead)
    y_int_dot = lookahead * cross / (lookahead**2 + (cross + kappa * y_int) ** 2)
    return psi_d, y_int_dot, along, cross


@pytest.mark.parametrize(
    ("position", "start", "end", "y_int", "lookahead", "kappa"),
    [
        ((5.0, 2.0), (0.0, 0.0), (10.0, 0.0), 0.0, 2.0, 0.0),
        ((5.0, -2.0), (0.0, 0.0), (10.0, 0.0), 0.0, 2.0, 0.0),
        ((3.0, 7.0), (1.0, -2.0), (-4.0, 6.0), 1.5, 8.0, 0.4),
        ((-20.0, 13.0), (10.0, 10.0), (10.0, 60.0), -3.0, 5.0, 1.0),
    ],
)
def test_ilos_law_matches_the_book_formula(position, start, end, y_int, lookahead, kappa):
    mine = ilos_heading(position, start, end, y_int, lookahead, kappa)
    assert mine == pytest.approx(book_ilos(position, start, end, y_int, lookahead, kappa), abs=1e-12)


def test_ilos_turns_a_vehicle_back_towards_the_path():
    # path along +x (north): +y (east) is the right side; Δ = 2 m, 2 m off gives ±45°
    right = ilos_heading((5.0, 2.0), (0.0, 0.0), (10.0, 0.0), 0.0, 2.0, 0.0)
    left = ilos_heading((5.0, -2.0), (0.0, 0.0), (10.0, 0.0), 0.0, 2.0, 0.0)
    assert right[0] == pytest.approx(-math.pi / 4) and right[3] == pytest.approx(2.0)
    assert left[0] == pytest.approx(math.pi / 4) and left[3] == pytest.approx(-2.0)
    # ẏ_int = Δ y_e / (Δ² + y_e²) = 2·2/8
    assert right[1] == pytest.approx(0.5) and left[1] == pytest.approx(-0.5)


def straight_problem(length=500.0):
    reference = uo.Reference.waypoints([(0.0, 0.0, DEPTH), (length, 0.0, DEPTH)], speed=1.5, turn_radius=5.0)
    return uo.TrackingProblem(uo.Remus100(), reference, horizon=1, dt=DT)


def test_steps_integrate_the_book_law():
    """The guidance's commands over two steps: the law above with ``y_int`` Euler-integrated."""
    options = uo.LosOptions(lookahead=8.0, kappa=0.5)
    guidance = uo.LosGuidance(straight_problem(), options)
    assert isinstance(guidance, uo.Controller)
    guidance.warm_up(np.zeros(12))
    first, second = np.zeros(12), np.zeros(12)
    first[[0, 1, 2]] = (20.0, 3.0, DEPTH)
    second[[0, 1, 2]] = (21.0, 2.5, DEPTH)
    step1 = guidance.step(first)
    step2 = guidance.step(second)
    psi1, y_int_dot, _, cross1 = book_ilos((20.0, 3.0), (0, 0), (500, 0), 0.0, 8.0, 0.5)
    psi2, _, _, cross2 = book_ilos((21.0, 2.5), (0, 0), (500, 0), DT * y_int_dot, 8.0, 0.5)
    assert (step1.heading_command, step1.cross_track) == pytest.approx((psi1, cross1), abs=1e-12)
    assert (step2.heading_command, step2.cross_track) == pytest.approx((psi2, cross2), abs=1e-12)
    # reset forgets the integral: the first step's command again
    guidance.reset()
    assert guidance.step(first).heading_command == pytest.approx(psi1, abs=1e-12)


def test_on_a_turning_arc_the_command_follows_the_path_tangent():
    """A vehicle moved along the 30 m arc of a 90° corner: ψ_ref is the circle's tangent.

    The arc of ``Reference.waypoints`` at the corner (100, 0) has its centre at (70, 30); where
    the tangent heading is φ the point is ``(70 + 30 sin φ, 30 − 30 cos φ)``.  Plain LOS on the
    chord polyline (within 5 cm of the arc) would step by the chord angle at each switch.
    """
    points = [(0.0, 0.0, DEPTH), (100.0, 0.0, DEPTH), (100.0, 100.0, DEPTH)]
    reference = uo.Reference.waypoints(points, speed=1.5, turn_radius=30.0)
    problem = uo.TrackingProblem(uo.Remus100(), reference, horizon=1, dt=DT)
    guidance = uo.LosGuidance(problem, uo.LosOptions(kappa=0.0))
    guidance.warm_up(np.zeros(12))
    assert len(guidance.path) > 10  # the arc is many chords
    state = np.zeros(12)
    state[2] = DEPTH
    for x in np.arange(0.0, 70.0, 1.5):  # the straight leg first: the switches are walked
        state[:2] = (x, 0.0)
        assert guidance.step(state).heading_command == pytest.approx(0.0, abs=6e-3)
    commands = []
    for phi in np.linspace(0.0, math.pi / 2, 100):
        state[:2] = (70.0 + 30.0 * math.sin(phi), 30.0 - 30.0 * math.cos(phi))
        commands.append(guidance.step(state).heading_command - phi)
    assert np.max(np.abs(commands)) < 6e-3  # Δ = 10 m: 5 cm off the chord is 0.005 rad


def cross_current_run(kappa):
    guidance = uo.LosGuidance(straight_problem(), uo.LosOptions(lookahead=10.0, kappa=kappa))
    x0 = np.zeros(12)
    x0[2], x0[6] = DEPTH, 1.5
    current = uo.Current(speed=CURRENT, direction=math.pi / 2)
    return guidance, uo.simulate(guidance, x0, 200.0, current=current, seed=1)


@pytest.fixture(scope="module")
def ilos_run():
    return cross_current_run(kappa=0.3)


@pytest.fixture(scope="module")
def los_run():
    return cross_current_run(kappa=0.0)


def test_ilos_removes_the_cross_track_error_of_a_cross_current(ilos_run):
    _, run = ilos_run
    cross = run.states[:, 1]  # the path is the x axis: y is the cross-track error
    settled = run.t >= 120.0
    assert np.max(np.abs(cross[settled])) < 0.1
    assert np.max(np.abs(cross)) > 1.0  # the current really pushed it off first
    assert run.solver == "ilos" and set(run.statuses) == {"ilos"} and run.failures == 0


def test_plain_los_keeps_the_crab_angle_offset(los_run):
    guidance, run = los_run
    settled = run.t >= 150.0
    cross = run.states[settled, 1]
    assert np.ptp(cross) < 0.01  # steady
    # the water-relative horizontal velocity (ground velocity minus the current), from positions
    ground = np.diff(run.states[:, :2], axis=0)[settled[1:]] / DT
    water = ground - np.array([0.0, CURRENT])
    speed_r = np.mean(np.hypot(water[:, 0], water[:, 1]))
    sideslip = np.mean(np.arctan2(water[:, 1], water[:, 0]) - run.states[settled, 5][: len(water)])
    # the course over ground along the path (π_h = 0) needs U_r sin(ψ + β_r) = −V⊥, and LOS
    # sets ψ = −atan(y_e/Δ): y_e = Δ tan(asin(V⊥/U_r) + β_r)
    expected = guidance.options.lookahead * math.tan(math.asin(CURRENT / speed_r) + sideslip)
    assert expected > 1.5
    assert np.mean(cross) == pytest.approx(expected, rel=0.005)


def test_depth_autopilot_holds_depth_and_commands_respect_the_bounds():
    """From rest at 10 m, a 45° turn under the current: depth held, every command admissible."""
    points = [(0.0, 0.0, DEPTH), (60.0, 0.0, DEPTH), (160.0, 100.0, DEPTH)]
    reference = uo.Reference.waypoints(points, speed=1.5, turn_radius=30.0)
    problem = uo.TrackingProblem(uo.Remus100(), reference, horizon=1, dt=DT)
    x0 = np.zeros(12)
    x0[2] = DEPTH
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # duration clipped to the window
        run = uo.simulate(
            uo.LosGuidance(problem), x0, 150.0, current=uo.Current(speed=CURRENT, direction=math.pi / 2)
        )
    assert run.t[-1] > 100.0
    assert np.max(np.abs(run.states[:, 2] - DEPTH)) < 0.15
    assert np.max(np.abs(run.states[run.t > 20.0, 2] - DEPTH)) < 0.05
    # the published bounds (helpers_remus: remus100.py's deltaMax, nMax, T_delta, T_n)
    bound = np.array([remus.MAX_FIN, remus.MAX_FIN, remus.MAX_RPM])
    rate = DT * np.array(
        [
            remus.MAX_FIN / remus.FIN_TIME_CONSTANT,
            remus.MAX_FIN / remus.FIN_TIME_CONSTANT,
            remus.MAX_RPM / remus.PROPELLER_TIME_CONSTANT,
        ]
    )
    assert np.all(np.abs(run.controls) <= bound * (1 + 1e-12))
    steps = np.diff(np.vstack([np.zeros(3), run.controls]), axis=0)  # simulate starts from zero
    assert np.all(np.abs(steps) <= rate * (1 + 1e-12))
    assert np.max(np.abs(run.controls[:, 0])) == pytest.approx(remus.MAX_FIN)  # the turn saturates
    assert np.max(np.abs(steps[:, 2])) == pytest.approx(rate[2])  # the propeller ramps at its rate


def test_propeller_speed_holds_the_commanded_speed():
    guidance = uo.LosGuidance(straight_problem())
    guidance.warm_up(np.zeros(12))
    speed = remus.remus100_steady_speed(guidance.propeller_speed)
    assert speed == pytest.approx(1.5, rel=1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"speed": 0.0}, "speed must be"),
        ({"lookahead": -1.0}, "lookahead must be"),
        ({"kappa": -0.1}, "kappa must be"),
        ({"acceptance_radius": math.inf}, "acceptance_radius must be"),
        ({"pitch_gains": (5.0, 2.0)}, "pitch_gains"),
        ({"pitch_gains": (5.0, -2.0, 0.3)}, "pitch_gains must be three finite numbers >= 0"),
        ({"max_pitch": 2.0}, "max_pitch must be an angle"),
        ({"heading_reference_frequency": "fast"}, "heading_reference_frequency must be"),
        ({"smc_switching": -1.0}, "smc_switching must be"),
    ],
)
def test_bad_options_are_refused_by_name(change, message):
    with pytest.raises(ValueError, match=message):
        uo.LosOptions(**change)


def test_bad_problems_are_refused_by_name():
    rexrov = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5)
    with pytest.raises(ValueError, match="problem.vehicle must be steered by rudder"):
        uo.LosGuidance(rexrov)
    with pytest.raises(ValueError, match="problem must have a vehicle, a dt and a reference path"):
        uo.LosGuidance(rexrov.ocp)
    with pytest.raises(ValueError, match="options must be a uuv_ocp.LosOptions"):
        uo.LosGuidance(straight_problem(), {"kappa": 0.1})
    endless = uo.Reference.from_xyz(lambda t: 1.5 * t, lambda t: 0 * t, lambda t: 0 * t + DEPTH)
    guidance = uo.LosGuidance(uo.TrackingProblem(uo.Remus100(), endless, horizon=1, dt=DT))
    with pytest.raises(ValueError, match="finite window"):
        guidance.warm_up(np.zeros(12))
    too_fast = uo.LosGuidance(straight_problem(), uo.LosOptions(speed=3.0))
    with pytest.raises(ValueError, match="speed must be reachable at the propeller bound"):
        too_fast.warm_up(np.zeros(12))
