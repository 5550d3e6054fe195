"""The closed loop's fast paths give the numbers of the general paths they stand in for.

Each fast path of ``NMPC.step`` (the parameter vector written straight into ``p``, one-comparison
input checks) is checked here against an independent, general path: ``Ocp.parameters`` (every
part validated and packed by name) and the checks' own definitions written out in numpy.
"""

import math

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp import _validation as check
from uuv_ocp.model import Vehicle6DOF


def _planar():
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)


def _spatial():
    reference = uo.Reference.from_xyz(
        lambda t: 0.3 * t, lambda t: ca.sin(0.2 * t), lambda t: 1.0 + 0.5 * ca.sin(0.1 * t), name="dive"
    )
    return uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), reference, horizon=12, dt=0.1)


def _with_moving_obstacle():
    reference = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line", t_end=30.0)
    crossing = uo.Obstacle.moving(lambda t: (3.0 + 0 * t, -2.1 + 0.3 * t), 0.3, margin=0.1)
    fixed = uo.Obstacle.circle((2.8, 1.0), 0.4, margin=0.1)
    return uo.TrackingProblem(
        uo.Vehicle.rexrov(), reference, terminal="cost", obstacles=[fixed, crossing], horizon=10
    )


def _general_path(problem, x0, t0, u_prev, current):
    """``p`` through ``Ocp.parameters``: every part by name, validated and packed by the Ocp."""
    spec = problem.spec()
    n, heading = problem.horizon, 2 if spec.state_dim == 6 else 5
    nc = spec.layout.entries["current"][1]
    if current is None:
        full = np.zeros((n + 1, nc))
    else:
        current = np.asarray(current, dtype=float)
        full = {
            (nc,): lambda: np.tile(current, (n + 1, 1)),
            (n, nc): lambda: np.vstack([current, current[-1:]]),
            (n + 1, nc): lambda: current,
        }[current.shape]()
    values = {"reference": problem.reference_window(t0, heading=x0[heading]), "current": full}
    times = t0 + problem.dt * np.arange(n + 1)
    for i, obstacle in enumerate(problem.obstacles):
        if obstacle.is_moving:
            values[f"obstacle{i}"] = obstacle.centre_at(times)
    return problem.ocp.parameters(x0, values, u_prev)


@pytest.mark.parametrize("make", [_planar, _spatial, _with_moving_obstacle])
def test_tracking_parameters_equal_the_general_ocp_path_on_random_instances(make):
    problem = make()
    spec = problem.spec()
    nx, n = spec.state_dim, problem.horizon
    nc = spec.layout.entries["current"][1]
    heading = 2 if nx == 6 else 5
    reference = problem.reference
    rng = np.random.default_rng(7)
    for trial in range(40):
        on_grid = trial % 2 == 0
        latest = min(problem.latest_start(), 60.0)
        grid = problem.dt * int(rng.integers(0, int(latest / problem.dt)))
        t0 = grid if on_grid else rng.uniform(0.0, latest)
        x0 = reference.evaluate([t0])[0] + rng.normal(scale=0.3, size=nx)
        x0[heading] += 2 * math.pi * int(rng.integers(-3, 4))  # the window follows the vehicle's branch
        u_prev = None if trial % 5 == 0 else rng.uniform(spec.lower, spec.upper)
        current = [
            None,
            rng.normal(scale=0.2, size=nc),
            rng.normal(scale=0.2, size=(n, nc)),
            rng.normal(scale=0.2, size=(n + 1, nc)),
        ][trial % 4]
        p = problem.parameters(x0, t0, u_prev, current)
        expected = _general_path(problem, x0, t0, u_prev, current)
        assert p.shape == expected.shape
        assert np.array_equal(p, expected), (trial, np.flatnonzero(p != expected))
        assert not np.shares_memory(p, problem.parameters(x0, t0, u_prev, current))  # a fresh p each call


@pytest.mark.parametrize("make", [_planar, _spatial, _with_moving_obstacle])
def test_with_state_equals_the_general_path_at_the_new_state(make):
    """``NMPC.feedback``'s ``p``: the prepared instance with the measured state put in.

    Checked against ``Ocp.parameters`` at the new state, across heading branches (the window
    follows the vehicle's), with the guess and the measurement several turns apart.
    """
    problem = make()
    spec = problem.spec()
    nx = spec.state_dim
    heading = 2 if nx == 6 else 5
    rng = np.random.default_rng(11)
    for trial in range(30):
        t0 = problem.dt * int(rng.integers(0, int(min(problem.latest_start(), 40.0) / problem.dt)))
        guess = problem.reference.evaluate([t0])[0] + rng.normal(scale=0.3, size=nx)
        measured = guess + rng.normal(scale=0.05, size=nx)
        measured[heading] += 2 * math.pi * int(rng.integers(-2, 3)) if trial % 3 == 0 else 0.0
        u_prev = rng.uniform(spec.lower, spec.upper)
        current = rng.normal(scale=0.2, size=spec.layout.entries["current"][1])
        prepared = problem.parameters(guess, t0, u_prev, current)
        p = problem.with_state(prepared, measured)
        expected = _general_path(problem, measured, t0, u_prev, current)
        assert np.array_equal(p, expected), (trial, np.flatnonzero(p != expected))
        assert not np.shares_memory(p, prepared)
    with pytest.raises(ValueError, match="x0"):
        problem.with_state(prepared, np.r_[measured[:-1], np.nan])


def test_ocp_with_state_equals_its_parameters():
    ocp = uo.Ocp(horizon=4, dt=0.1)
    x = ocp.state("x", 2)
    u = ocp.control("u", 2, lower=-1.0, upper=1.0)
    target = ocp.parameter("target", 2)
    ocp.set_der(x, u)
    ocp.add_stage_cost(ca.sumsqr(x - target))
    prepared = ocp.parameters([0.1, 0.2], {"target": [1.0, -1.0]}, [0.5, 0.0])
    p = ocp.with_state(prepared, [3.0, -4.0])
    assert np.array_equal(p, ocp.parameters([3.0, -4.0], {"target": [1.0, -1.0]}, [0.5, 0.0]))
    with pytest.raises(ValueError, match="x0"):
        ocp.with_state(prepared, [1.0])


def test_tracking_parameters_still_reject_bad_parts_by_name():
    problem = _planar()
    x0, t0 = problem.reference.evaluate([2.0])[0], 2.0
    bad = {
        "x0": dict(x0=np.r_[x0[:5], np.nan]),
        "u_prev": dict(u_prev=[np.inf, 0.0, 0.0]),
        "current": dict(current=[0.1, 2e9]),
    }
    for name, change in bad.items():
        arguments = {"x0": x0, "t0": t0, **change}
        with pytest.raises(ValueError, match=name):
            problem.parameters(**arguments)


@pytest.mark.parametrize("make", [_planar, _spatial, _with_moving_obstacle])
def test_closed_loop_instance_rejects_what_the_general_path_rejects(make):
    """Float arrays take the closed loop's fast instance: the same ``p`` and the same errors.

    Every entry of ``x0`` and ``u_prev`` is pushed past its bound (NaN, ±inf, beyond
    ±PLAUSIBLE_MAGNITUDE, past the slack box) and to just inside it; the time to NaN and past
    the window.  Accepted exactly when the checks' definitions accept, with ``p`` then equal
    to ``Ocp.parameters``'; a refusal names the part.
    """
    problem = make()
    spec = problem.spec()
    nx, nu = spec.state_dim, spec.control_size
    assert (problem._closed_loop_plan is None) == any(o.is_moving for o in problem.obstacles)
    t0 = problem.dt * 20
    x0 = problem.reference.evaluate([t0])[0]
    u_prev = 0.5 * (spec.lower + spec.upper)
    slack_low = 1e-6 * np.maximum(1.0, np.abs(spec.lower))
    slack_high = 1e-6 * np.maximum(1.0, np.abs(spec.upper))
    cases = []
    for i in range(nx):
        for value in (np.nan, np.inf, -2e9, check.PLAUSIBLE_MAGNITUDE, -check.PLAUSIBLE_MAGNITUDE):
            x = x0.copy()
            x[i] = value
            cases.append(("x0", x, u_prev, abs(value) <= check.PLAUSIBLE_MAGNITUDE))
    for i in range(nu):
        for value in (np.nan, -np.inf, spec.lower[i] - 2 * slack_low[i], spec.upper[i] + 2 * slack_high[i]):
            u = u_prev.copy()
            u[i] = value
            cases.append(("u_prev", x0, u, False))
        for value in (spec.lower[i] - 0.5 * slack_low[i], spec.upper[i] + 0.5 * slack_high[i]):
            u = u_prev.copy()
            u[i] = value
            cases.append(("u_prev", x0, u, True))
    for name, x, u, accepted in cases:
        assert accepted == (
            np.all(np.abs(x) <= check.PLAUSIBLE_MAGNITUDE) and _previous_accepted(spec.lower, spec.upper, u)
        )
        if accepted:
            assert np.array_equal(problem.parameters(x, t0, u), _general_path(problem, x, t0, u, None))
        else:
            with pytest.raises(ValueError, match=name):
                problem.parameters(x, t0, u)
    for t in (math.nan, math.inf, -1.0, problem.latest_start() + 1.0):  # the last inf without an end
        with pytest.raises(ValueError, match="t0"):
            problem.parameters(x0, t, u_prev)


def _previous_accepted(lower, upper, value):
    """``check_previous``'s definition: finite, inside the box widened by 1e-6 relative (>= 1e-6)."""
    slack_low, slack_high = 1e-6 * np.maximum(1.0, np.abs(lower)), 1e-6 * np.maximum(1.0, np.abs(upper))
    with np.errstate(invalid="ignore"):
        inside = np.all(value >= lower - slack_low) and np.all(value <= upper + slack_high)
    return bool(np.all(np.isfinite(value)) and inside)


def test_check_previous_accepts_exactly_what_its_definition_accepts():
    ocp = uo.Ocp(horizon=3, dt=0.1)
    x = ocp.state("x", 3)
    u = ocp.control("u", 3, lower=[-2.0, -math.inf, -0.5], upper=[2.0, 1.0, math.inf])
    ocp.set_der(x, u)
    ocp.add_stage_cost(ca.sumsqr(x))
    spec = ocp.spec()
    edges = [
        -2.0 - 2e-6,
        -2.0 - 2.1e-6,
        2.0 + 2e-6,
        2.0 + 2.1e-6,
        1.0 + 1e-6,
        1.0 + 1.1e-6,
        -0.5 - 1e-6,
        -0.5 - 1.1e-6,
        -1e300,
        1e300,
        0.0,
        np.nan,
        np.inf,
        -np.inf,
    ]
    rng = np.random.default_rng(3)
    for _ in range(400):
        value = rng.choice(edges, size=3)
        accepted = _previous_accepted(spec.lower, spec.upper, value)
        if accepted:
            assert np.array_equal(ocp.check_previous(value), value)
        else:
            with pytest.raises(ValueError, match="u_prev"):
                ocp.check_previous(value)


@pytest.mark.parametrize("shape", [(2, 3), (5, 4)])  # Python floats, then numpy (SMALL_ARRAY)
def test_plausible_array_accepts_exactly_finite_values_within_the_bound(shape):
    bound = check.PLAUSIBLE_MAGNITUDE
    values = [0.0, -bound, bound, np.nextafter(bound, np.inf), -np.nextafter(bound, np.inf), np.nan, np.inf]
    rng = np.random.default_rng(5)
    for _ in range(200):
        value = rng.choice(values, size=shape, p=[0.8, *[0.2 / 6] * 6])
        if np.all(np.isfinite(value)) and np.all(np.abs(value) <= bound):
            result = check.plausible_array("w", value.tolist(), shape)
            assert np.array_equal(result, value) and result.dtype == float
        else:
            with pytest.raises(ValueError, match="w must"):
                check.plausible_array("w", value, shape)
    with pytest.raises(ValueError, match="shape"):
        check.plausible_array("w", np.zeros(6), (2, 3))
    with pytest.raises(ValueError, match="real array"):
        check.plausible_array("w", ["a", None], (2,))


@pytest.mark.parametrize("size", [3, check.SMALL_ARRAY, check.SMALL_ARRAY + 1, 40])
def test_within_is_its_numpy_definition(size):
    """``within`` on both of its paths: every entry in its interval, NaN in none."""
    rng = np.random.default_rng(size)
    choices = np.array([-2.0, -1.0, 0.0, 1.0, 2.0, np.nan, np.inf, -np.inf])
    for _ in range(300):
        values = rng.choice(choices, size=size, p=[0.15, 0.15, 0.3, 0.15, 0.15, 0.04, 0.03, 0.03])
        lower, upper = -1.0 - rng.random(size) * (rng.random() < 0.5), np.ones(size)
        expected = bool(np.all((values >= lower) & (values <= upper)))
        assert check.within(values, lower.tolist(), upper.tolist()) is expected
        assert check.within(values, lower, upper) is expected
        assert check.within(values, -1.0, 1.0) is bool(np.all(np.abs(values) <= 1.0))
        assert check.within(values, -1, np.float32(1.0)) is bool(np.all(np.abs(values) <= 1.0))
    with pytest.raises(ValueError):  # a bound per entry, or one for all: nothing in between
        check.within(np.zeros(size), [0.0] * (size - 1), 1.0)


def test_check_previous_defaults_to_zero_clipped_into_the_box_and_checks_a_given_value():
    # zero lies outside this box: the default is zero clipped into it (as simulate starts, so a
    # propeller floored above 0 rpm needs no u_prev), and a given value outside still raises
    ocp = uo.Ocp(horizon=3, dt=0.1)
    x = ocp.state("x")
    u = ocp.control("u", lower=1.0, upper=2.0)
    ocp.set_der(x, u)
    ocp.add_stage_cost(ca.sumsqr(x))
    assert np.array_equal(ocp.check_previous(None), [1.0])
    with pytest.raises(ValueError, match="u_prev must lie inside the control bounds"):
        ocp.check_previous([0.0])
    assert np.array_equal(ocp.check_previous([1.5]), [1.5])


def test_a_fast_path_record_is_the_record_its_constructor_builds():
    """``StepRecord._of_fast_path`` (no ``__init__``): the constructor's record, field by field."""
    import dataclasses

    from uuv_ocp.control.mpc import StepRecord

    class Plan(uo.solvers.base.DeferredPlan):
        path = "resident C step"
        control = np.array([1.0, -2.0])

        def iterate(self):
            raise AssertionError("not built")

        def result(self):
            return "built"

    plan, control = Plan(), np.array([0.5, -0.5])
    fast, built = (
        StepRecord._of_fast_path(control, plan),
        StepRecord(control, plan, False, fast_path=plan.path),
    )
    names = [field.name for field in dataclasses.fields(StepRecord)]
    assert names == list(vars(fast)) == list(vars(built))
    assert all(getattr(fast, name) is getattr(built, name) for name in names)
    assert fast == built and repr(fast) == repr(built)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.fallback = True
    assert fast.result == "built" and fast._result == "built"  # the deferred result, built once
