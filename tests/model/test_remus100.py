"""The REMUS 100 preset (``uo.Remus100``) against an independent implementation and published data.

The reference is ``tests/helpers_remus.py``: a numpy transcription of the same published model
(Fossen's PythonVehicleSimulator ``remus100.py`` at commit 7e1db8ed and its ``gnc`` helpers),
written separately from the package, in Fossen's state order ``[ν, η]`` and with the current
as ``(V_c, β_c)``.  The published steady speed is the source's module docstring: "The maximum
speed of 2.5 m/s is obtained when the propeller runs at 1525 rpm in zero currents."
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import uuv_ocp as uo

reference = pytest.importorskip("tests.helpers_remus", reason="the independent model")

# package state [x, y, z, φ, θ, ψ, u, v, w, p, q, r] <-> Fossen's [u, v, w, p, q, r, x, y, z, φ, θ, ψ]
TO_FOSSEN = np.r_[6:12, 0:6]
FROM_FOSSEN = np.r_[6:12, 0:6]
PUBLISHED_SPEED = 2.5  # m/s at 1525 rpm, remus100.py's module docstring (see above)


def _current_ned(speed: float, direction: float) -> np.ndarray:
    """Return the reference's ``(V_c, β_c)`` as the package's NED current ``[V_x, V_y, V_z]`` (m/s)."""
    return np.array([speed * math.cos(direction), speed * math.sin(direction), 0.0])


def _random_points(count: int, seed: int):
    """Seeded states (forward, reverse, slow and sideways motion), commands within bounds, currents."""
    rng = np.random.default_rng(seed)
    bound = np.asarray(uo.Remus100().control_bound)
    for index in range(count):
        nu = rng.normal(scale=[1.0, 0.4, 0.4, 0.6, 0.4, 0.4])
        nu[0] += (1.5, -0.5, 0.0, 2.5)[index % 4]  # cruising, backing, drifting, flat out
        if index % 17 == 0:
            nu[:3] *= 1e-3  # nearly at rest: U, U_r and α at small speeds
        pose = np.concatenate(
            [rng.normal(scale=50.0, size=3), rng.uniform(-1.2, 1.2, 2), rng.uniform(-math.pi, math.pi, 1)]
        )
        command = rng.uniform(-1.0, 1.0, 3) * bound
        yield pose, nu, command, (rng.uniform(0.0, 1.0), rng.uniform(-math.pi, math.pi))


def test_dynamics_equal_the_independent_implementation_at_random_points():
    f = uo.Remus100().model_function()
    checked = 0
    for pose, nu, command, (speed, direction) in _random_points(200, seed=28):
        state = np.concatenate([pose, nu])
        mine = np.asarray(f(state, command, _current_ned(speed, direction))).ravel()
        theirs = reference.remus100_derivative(state[TO_FOSSEN], command, (speed, direction))
        np.testing.assert_allclose(mine[TO_FOSSEN], theirs, rtol=1e-9, atol=0.0)
        checked += 1
    assert checked == 200


@pytest.mark.parametrize(
    ("nu", "command", "current"),
    [
        (np.zeros(6), (0.0, 0.0, 0.0), (0.0, 0.0)),  # at rest: U = U_r = 0, α = atan2(0, 0)
        (np.zeros(6), (0.1, -0.2, 1525.0), (0.0, 0.0)),  # propeller starting from rest
        (np.array([0.0, 0.0, 0.3, 0.0, 0.1, 0.0]), (0.0, 0.2, 800.0), (0.0, 0.0)),  # α = 90°
        (np.array([-0.8, 0.1, 0.0, 0.0, 0.0, 0.2]), (0.2, 0.0, -1000.0), (0.0, 0.0)),  # reverse
        (np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), (0.0, 0.0, 900.0), (0.3, 0.0)),  # drifting with it
    ],
)
def test_dynamics_equal_the_independent_implementation_at_special_points(nu, command, current):
    pose = np.array([1.0, -2.0, 10.0, 0.05, -0.1, 0.7])
    state = np.concatenate([pose, nu])
    mine = np.asarray(uo.Remus100().model_function()(state, command, _current_ned(*current))).ravel()
    theirs = reference.remus100_derivative(state[TO_FOSSEN], command, current)
    np.testing.assert_allclose(mine[TO_FOSSEN], theirs, rtol=1e-9, atol=1e-15)


def test_derivatives_are_finite_at_rest_and_match_finite_differences_of_the_reference():
    """The guarded √ and atan2 give finite Jacobians at rest (a solver may start there)."""
    import casadi as ca

    f = uo.Remus100().model_function()
    x, u, c = ca.SX.sym("x", 12), ca.SX.sym("u", 3), ca.SX.sym("c", 3)
    jacobian = ca.Function("remus_jacobian", [x, u, c], [ca.jacobian(f(x, u, c), ca.vertcat(x, u))])
    for command in ((0.0, 0.0, 0.0), (0.0, 0.0, 1525.0)):
        assert np.all(np.isfinite(np.asarray(jacobian(np.zeros(12), command, np.zeros(3)))))
    # away from rest, the CasADi Jacobian is the reference's by central differences
    state = np.array([3.0, 1.0, 8.0, 0.1, -0.05, 0.4, 1.4, 0.1, -0.05, 0.02, 0.03, -0.04])
    command = np.array([0.1, -0.05, 1200.0])
    current = (0.2, 0.5)
    analytic = np.asarray(jacobian(state, command, _current_ned(*current)))
    point = np.concatenate([state, command])
    for column in range(15):
        step = 1e-6 * max(1.0, abs(point[column]))
        plus, minus = point.copy(), point.copy()
        plus[column] += step
        minus[column] -= step
        numeric = (
            reference.remus100_derivative(plus[:12][TO_FOSSEN], plus[12:], current)
            - reference.remus100_derivative(minus[:12][TO_FOSSEN], minus[12:], current)
        ) / (2.0 * step)
        np.testing.assert_allclose(analytic[:, column][TO_FOSSEN], numeric, rtol=1e-5, atol=1e-6)


def test_straight_run_at_full_propeller_speed_reaches_the_published_speed():
    """1525 rpm, fins at zero, still water: the source's 2.5 m/s.

    The published model itself settles at 2.554 m/s, 2.2 % above the 2.5 m/s its docstring
    states (and that its ``Ja_max = 0.944 * 2.5 / (0.14 * 1525/60)`` assumes): the issue's 2 %
    cannot be met by the published coefficients, so the check against the statement is 2.5 %,
    and the settled speed is checked tightly against the independent implementation's.
    """
    vehicle = uo.Remus100()
    step = uo.rk4_step(vehicle.model_function(), 0.05, 1)
    state, command = np.zeros(12), np.array([0.0, 0.0, 1525.0])
    for _ in range(1200):  # 60 s; the surge time constant is about 0.6 s
        state = np.asarray(step(state, command, np.zeros(3))).ravel()
    speed = state[6]
    assert speed == pytest.approx(PUBLISHED_SPEED, rel=0.025)
    assert speed == pytest.approx(reference.remus100_steady_speed(1525.0), rel=1e-6)
    # it ran straight: the propeller's roll moment heels it by 1° and the roll transient leaves
    # a few centimetres of sideways drift over 150 m
    assert abs(state[5]) < 1e-2 and abs(state[1]) < 0.5 and state[0] > 140.0


def test_bounds_are_the_published_ones():
    vehicle = uo.Remus100()
    assert vehicle.control_bound == pytest.approx((reference.MAX_FIN, reference.MAX_FIN, reference.MAX_RPM))
    # rate bounds: the source's first-order lags' initial rates after a step from 0 to the bound
    assert vehicle.control_rate_bound == pytest.approx(
        (
            reference.MAX_FIN / reference.FIN_TIME_CONSTANT,
            reference.MAX_FIN / reference.FIN_TIME_CONSTANT,
            reference.MAX_RPM / reference.PROPELLER_TIME_CONSTANT,
        )
    )
    layout = vehicle.layout
    assert layout.control_names == ("delta_r", "delta_s", "n")
    assert layout.control_units == ("rad", "rad", "rpm")
    assert layout.state_names == uo.Vehicle6DOF.bluerov2_heavy().layout.state_names  # the 6-DOF order
    assert layout.current_dim == 3 and layout.reference == "spatial"
    assert vehicle.mass == pytest.approx(reference.remus100_matrices().mass, rel=1e-12)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"length": -1.6}, r"length must be a finite number > 0, got -1\.6"),
        ({"diameter": 2.0}, r"diameter must be smaller than length = 1\.6 m"),
        ({"max_rudder": 2.0}, r"max_rudder must be an angle in \(0, π/2\) rad, got 2\.0"),
        ({"max_propeller_speed": 0.0}, r"max_propeller_speed must be a finite number > 0"),
        ({"centre_of_gravity": (0.0, 0.0, -0.02)}, r"centre_of_gravity must lie below centre_of_buoyancy"),
        ({"thrust_coefficients": (0.4566,)}, r"thrust_coefficients must have shape \(2,\)"),
        ({"wake_fraction": 1.2}, r"thrust_deduction and wake_fraction must be in \[0, 1\)"),
        ({"fin_area": float("nan")}, r"fin_area must be finite"),
        ({"name": ""}, r"name must be a non-empty string"),
    ],
)
def test_bad_parameters_are_refused_by_name(change, message):
    with pytest.raises(ValueError, match=message):
        uo.Remus100(**change)


def test_a_vehicle_file_starts_from_the_preset(tmp_path):
    import dataclasses

    from uuv_ocp.specs import vehicle_from_spec

    path = tmp_path / "remus30.toml"
    path.write_text('[vehicle]\npreset = "remus100"\nname = "remus-30"\nmax_rudder = 0.5236\n')
    vehicle = vehicle_from_spec(path)
    assert vehicle == dataclasses.replace(uo.Remus100(), name="remus-30", max_rudder=0.5236)
    assert vehicle.control_bound[0] == 0.5236
    path.write_text('[vehicle]\npreset = "remus100"\nmax_rudder = 2.0\n')
    with pytest.raises(ValueError, match=r"remus30\.toml: max_rudder must be an angle in \(0, π/2\) rad"):
        vehicle_from_spec(path)


def test_a_straight_line_at_cruise_speed_is_tracked_in_closed_loop():
    """TrackingProblem + simulate through the protocol only; the plant replayed independently."""
    from scipy.integrate import solve_ivp

    vehicle = uo.Remus100()
    line = uo.Reference.waypoints([(0.0, 0.0, 10.0), (100.0, 0.0, 10.0)], speed=1.5, turn_radius=2.0)
    problem = uo.TrackingProblem(vehicle, line, horizon=10, dt=0.1, terminal="cost")
    x0 = problem.reference_window(0.0)[0].copy()  # on the line, at 10 m, moving at 1.5 m/s
    x0[2] += 0.3  # 30 cm too deep: only the stern planes can bring it up
    run = uo.simulate(uo.NMPC(problem, solver="ipopt"), x0=x0, duration=2.0, seed=3)
    assert run.failures == 0
    controls = np.asarray(run.controls)
    bound, rate = np.asarray(vehicle.control_bound), np.asarray(vehicle.control_rate_bound)
    assert np.all(np.abs(controls) <= bound + 1e-6)
    steps = np.diff(np.vstack([np.zeros(3), controls]), axis=0)  # the loop starts from zero commands
    assert np.all(np.abs(steps) <= rate * problem.dt + 1e-6)
    assert abs(run.states[-1, 2] - 10.0) < 0.2  # the depth error shrinks
    assert np.all(np.abs(run.states[:, 1]) < 0.05)  # no sideways drift
    assert controls[-1, 2] > 500.0  # the propeller runs
    # the recorded plant states are the independent model's, integrated by scipy
    state = run.states[0]
    for k, command in enumerate(controls):
        solution = solve_ivp(
            lambda _, y, u=command: reference.remus100_derivative(y, u),
            (run.t[k], run.t[k + 1]),
            state[TO_FOSSEN],
            rtol=1e-10,
            atol=1e-10,
        )
        state = solution.y[:, -1][FROM_FOSSEN]
        np.testing.assert_allclose(state, run.states[k + 1], atol=1e-6)
    # plots read the run by roles and the layout's units
    pytest.importorskip("matplotlib")
    from uuv_ocp import plotting

    figure = plotting.state_figure(run)
    labels = [axis.get_ylabel() for axis in figure.axes if axis.get_visible()]
    assert any(label.startswith("z") for label in labels)
    thrust = plotting.thrust_figure(run, vehicle=vehicle)
    assert {"delta_r (rad)", "delta_s (rad)", "n (rpm)"} <= {axis.get_ylabel() for axis in thrust.axes}


def test_the_cli_tracks_with_the_preset_name(tmp_path, capsys):
    from uuv_ocp import cli
    from uuv_ocp.control.simulation import ClosedLoopResult

    line = Path(__file__).resolve().parents[2] / "examples" / "paths" / "straight_10m.toml"
    argv = ["track", "--vehicle", "remus100", "-r", str(line), "--duration", "0.5", "--horizon", "5"]
    assert cli.main([*argv, "--out", str(tmp_path / "out")]) == 0
    assert "remus100" in capsys.readouterr().out
    (saved,) = (tmp_path / "out" / "runs").glob("*.npz")
    run = ClosedLoopResult.load(str(saved))
    assert run.states.shape == (6, 12) and run.controls.shape == (5, 3)
    assert np.all(np.abs(run.controls) <= np.asarray(uo.Remus100().control_bound) + 1e-6)
    assert "remus100" in cli._VEHICLE_HELP


def test_the_roll_mode_bounds_the_rk4_step_as_documented():
    """Roll, λ = −1.94 ± 6.03i 1/s: RK4 is stable on it up to h = 0.446 s, not at 0.5 s (docstring).

    Eigenvalues by numpy of the preset's central-difference Jacobian; RK4's stability function
    written out here.
    """
    f = uo.Remus100().model_function()
    for surge in (0.0, 1.5):  # at rest and at cruise
        state = np.zeros(12)
        state[6] = surge
        jacobian = np.zeros((12, 12))
        for column in range(12):
            step = np.zeros(12)
            step[column] = 1e-6
            plus = np.asarray(f(state + step, np.zeros(3), np.zeros(3))).ravel()
            minus = np.asarray(f(state - step, np.zeros(3), np.zeros(3))).ravel()
            jacobian[:, column] = (plus - minus) / 2e-6
        eigenvalues = np.linalg.eigvals(jacobian)
        fastest = eigenvalues[np.argmax(np.abs(eigenvalues))]
        assert abs(fastest.real - -1.94) < 0.005 and abs(abs(fastest.imag) - 6.03) < 0.005

        def amplification(h: float, lam: complex = fastest) -> float:
            z = lam * h
            return abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)  # RK4's stability function

        assert amplification(0.5) == pytest.approx(1.80, abs=0.005)
        assert amplification(0.25) < 0.65
        assert amplification(0.446) <= 1.0 < amplification(0.447)
