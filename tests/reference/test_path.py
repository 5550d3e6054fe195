"""References: AD-derived quantities against hand derivations, continuity, validation."""

import math

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo


def hand_reference(dx, dy, ddx, ddy, x, y):
    speed_sq = dx**2 + dy**2
    return np.column_stack(
        [x, y, np.arctan2(dy, dx), np.sqrt(speed_sq), 0 * x, (dx * ddy - dy * ddx) / speed_sq]
    )


def test_s2_matches_hand_derivation():
    t = np.linspace(0.0, 30.0, 301)
    expected = hand_reference(
        0.5 + 0 * t, np.cos(0.5 * t), 0 * t, -0.5 * np.sin(0.5 * t), 0.5 * t, 2 * np.sin(0.5 * t)
    )
    np.testing.assert_allclose(uo.Reference.paper("s2").evaluate(t), expected, rtol=0, atol=1e-12)


def test_s8_matches_hand_derivation():
    t = np.linspace(0.0, 30.0, 301)
    dy = 0.5 * np.sin(0.5 * t) + 0.25 * t * np.cos(0.5 * t)
    ddy = 0.5 * np.cos(0.5 * t) - 0.125 * t * np.sin(0.5 * t)
    expected = hand_reference(0.5 + 0 * t, dy, 0 * t, ddy, 0.5 * t, 0.5 * t * np.sin(0.5 * t))
    np.testing.assert_allclose(uo.Reference.paper("s8").evaluate(t), expected, rtol=0, atol=1e-12)


def test_circle_heading_is_continuous_and_matches_yaw_rate():
    circle = uo.Reference.from_xy(lambda t: 3 * ca.cos(t), lambda t: 3 * ca.sin(t), "circle")
    t = np.linspace(0.0, 20.0, 201)  # three full turns
    states = circle.evaluate(t)
    # heading of a counter-clockwise circle is t + pi/2, unwrapped
    np.testing.assert_allclose(states[:, 2], t + math.pi / 2, atol=1e-12)
    np.testing.assert_allclose(states[:, 5], 1.0, atol=1e-12)
    # sparse sampling (gaps of 2 s, i.e. > pi/2 rad of turn) is still unwrapped correctly
    sparse = circle.evaluate(np.arange(0.0, 20.0, 2.0))
    np.testing.assert_allclose(sparse[:, 2], np.arange(0.0, 20.0, 2.0) + math.pi / 2, atol=1e-12)


def test_stationary_point_raises_naming_time():
    stop = uo.Reference.from_xy(lambda t: t**2, lambda t: 0 * t, "stop")
    with pytest.raises(ValueError, match=r"t = 0\.0"):
        stop.evaluate([0.0, 0.5])


def test_window_and_unknown_names_raise():
    with pytest.raises(ValueError, match="s11"):
        uo.Reference.paper("s11")
    s3 = uo.Reference.paper("s3")
    with pytest.raises(ValueError, match="t = 0.0"):
        s3.evaluate([0.0])
    with pytest.raises(ValueError, match="path_x"):
        uo.Reference.from_xy("not callable", lambda t: t)


@pytest.mark.parametrize("name", uo.PAPER_REFERENCES)
def test_every_paper_reference_is_finite_on_its_window(name):
    reference = uo.Reference.paper(name)
    end = min(reference.t_end, reference.t_start + 32.0)
    states = reference.evaluate(np.linspace(reference.t_start, end, 321))
    assert np.all(np.isfinite(states))
    assert np.all(states[:, 3] > 0)
    # x = 0.5 t for every paper path
    np.testing.assert_allclose(states[:, 0], 0.5 * np.linspace(reference.t_start, end, 321))


def test_initial_state_is_on_the_path_at_rest():
    state = uo.Reference.paper("s2").initial_state(1.0)
    np.testing.assert_allclose(state[:2], [0.5, 2 * math.sin(0.5)])
    assert np.all(state[3:] == 0)


@pytest.mark.parametrize("name", ["fast circle", "s-curve #2", "__", "é"])
def test_any_name_is_a_valid_label(name):
    reference = uo.Reference.from_xy(lambda t: t, lambda t: 0 * t, name)
    assert reference.name == name
    np.testing.assert_allclose(reference.evaluate([1.0])[0, :4], [1.0, 0.0, 0.0, 1.0])
