"""Direct Radau collocation (transcription/collocation.py) against independent references.

The Radau IIA step of degree d maps ``x' = Mx`` to ``R(hM) x`` with ``R`` the (d−1, d) Padé
approximant of ``exp`` (scipy's ``pade`` of the Taylor series); its order is ``2d − 1``
(against scipy's adaptive Radau at tight tolerance); and every exact backend of the registry
solves a collocation LQR to the discrete Riccati solution of those Padé matrices.
"""

from __future__ import annotations

from math import factorial

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import pade

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.transcription.collocation import COLLOCATION_DEGREES, implicit_step

EXACT = [name for name in REGISTRY.names() if REGISTRY.kind(name) == "exact"]
DT, HORIZON = 0.25, 10
#: tolerances tight enough to compare with the Riccati solution at 1e-6 (the defaults stop earlier)
TIGHT = {
    "sqp": {"plugin_options": {"tol_du": 1e-12, "tol_pr": 1e-12}},
    "slsqp": {"objective_scale": 1.0, "tol": 1e-14},  # this LQR's cost is O(1): no scaling needed
}


def pade_matrix(matrix: np.ndarray, degree: int) -> np.ndarray:
    """R(M) = q(M)⁻¹ p(M), the (degree−1, degree) Padé approximant of exp at a matrix."""
    numerator, denominator = pade([1.0 / factorial(i) for i in range(2 * degree + 1)], degree, degree - 1)

    def at(polynomial: np.poly1d) -> np.ndarray:
        value = np.zeros_like(matrix)
        for coefficient in polynomial.coeffs:  # Horner, highest power first
            value = value @ matrix + coefficient * np.eye(len(matrix))
        return value

    return np.linalg.solve(at(denominator), at(numerator))


def linear_dynamics(a: np.ndarray, b: np.ndarray) -> ca.Function:
    x, u = ca.SX.sym("x", a.shape[0]), ca.SX.sym("u", b.shape[1])
    ps, pg = ca.SX.sym("ps", 0), ca.SX.sym("pg", 0)
    return ca.Function("f", [x, u, ps, pg], [ca.DM(a) @ x + ca.DM(b) @ u])


A = np.array([[0.0, 1.0], [-2.0, -0.3]])  # a lightly damped oscillator
B = np.array([[0.0], [1.0]])


@pytest.mark.parametrize("degree", COLLOCATION_DEGREES)
def test_one_step_is_the_pade_approximant_of_the_exponential(degree):
    step = implicit_step(linear_dynamics(A, B), DT, degree)
    expected = pade_matrix(DT * augmented(), degree)[:2]  # the control held on the interval
    for x0, u in (([1.0, 0.0], 0.0), ([0.0, 1.0], 0.0), ([0.0, 0.0], 1.0), ([0.3, -0.7], 0.4)):
        got = np.array(step(x0, u, [], [])).ravel()
        np.testing.assert_allclose(got, expected @ np.array([*x0, u]), rtol=0, atol=1e-13)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_order_is_two_degree_minus_one_on_a_nonlinear_pendulum(degree):
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    ps, pg = ca.SX.sym("ps", 0), ca.SX.sym("pg", 0)
    pendulum = ca.Function("f", [x, u, ps, pg], [ca.vertcat(x[1], -ca.sin(x[0]) - 0.2 * x[1] + u)])
    x0, torque, span = np.array([1.0, 0.0]), 0.3, 0.8

    def rhs(_t: float, state: np.ndarray) -> list[float]:
        return [state[1], -np.sin(state[0]) - 0.2 * state[1] + torque]

    exact = solve_ivp(rhs, (0.0, span), x0, method="Radau", rtol=1e-13, atol=1e-13).y[:, -1]
    errors = []
    for intervals in (4, 8):
        step = implicit_step(pendulum, span / intervals, degree)
        state = x0
        for _ in range(intervals):
            state = np.array(step(state, torque, [], [])).ravel()
        errors.append(np.linalg.norm(state - exact))
    observed = np.log2(errors[0] / errors[1])
    assert observed == pytest.approx(2 * degree - 1, abs=0.3)


def lq_ocp(degree: int) -> uo.Ocp:
    ocp = uo.Ocp(horizon=HORIZON, dt=DT, transcription="collocation", degree=degree)
    x = ocp.state("x", 2)
    u = ocp.control("u")
    ocp.set_der(x, ca.DM(A) @ x + ca.DM(B) @ u)
    ocp.add_stage_cost(residual=ca.vertcat(x, u), weight=np.array([2.0, 1.0, 0.5]))
    ocp.add_terminal_cost(residual=x, weight=np.array([20.0, 10.0]))
    return ocp


def riccati(discrete: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, float]:
    """Finite-horizon discrete LQR of ``x⁺ = [A_d B_d] [x; u]`` (the lq_ocp costs), in numpy."""
    a_d, b_d = discrete[:, :2], discrete[:, 2:]
    q, r, p = np.diag([2.0, 1.0]), np.array([[0.5]]), np.diag([20.0, 10.0])
    gains = []
    for _ in range(HORIZON):
        gain = np.linalg.solve(r + b_d.T @ p @ b_d, b_d.T @ p @ a_d)
        p = q + a_d.T @ p @ (a_d - b_d @ gain)
        gains.append(gain)
    x, controls = x0.copy(), []
    for gain in reversed(gains):
        controls.append(-gain @ x)
        x = a_d @ x + b_d @ controls[-1]
    return np.array(controls), float(x0 @ p @ x0)


def augmented() -> np.ndarray:
    """Return the oscillator with its control held: ``[x; u]' = [[A, B], [0, 0]] [x; u]``."""
    matrix = np.zeros((3, 3))
    matrix[:2, :2], matrix[:2, 2:] = A, B
    return matrix


@pytest.mark.parametrize("solver", EXACT)
@pytest.mark.parametrize("degree", [1, 3])
def test_every_exact_backend_solves_the_collocation_lqr_to_the_riccati_solution(solver, degree):
    x0 = np.array([1.0, -0.5])
    controls, cost = riccati(pade_matrix(DT * augmented(), degree)[:2], x0)
    result = uo.solve(lq_ocp(degree), solver, x0=x0, options=TIGHT.get(solver))
    assert result.success, result.status
    np.testing.assert_allclose(result.controls, controls, rtol=1e-6, atol=1e-6)
    assert result.cost == pytest.approx(cost, rel=1e-6)
    # the judge rolls the plan out through the implicit step: the NLP's own states and cost
    judged_cost, violation = uo.score(lq_ocp(degree), result.controls, x0=x0)
    assert judged_cost == pytest.approx(result.cost, rel=1e-8) and violation < 1e-8
    np.testing.assert_allclose(
        lq_ocp(degree).rollout(result.controls, lq_ocp(degree).parameters(x0)), result.states, atol=1e-8
    )


def test_swarms_evaluate_the_same_discretisation():
    x0 = np.array([1.0, -0.5])
    controls, cost = riccati(pade_matrix(DT * augmented(), 2)[:2], x0)
    # the judge on the Riccati controls is the Riccati cost: the condensed cost is the collocation's
    assert uo.score(lq_ocp(2), controls, x0=x0)[0] == pytest.approx(cost, rel=1e-10)
    bounded = uo.Ocp(horizon=HORIZON, dt=DT, transcription="collocation", degree=2)
    x = bounded.state("x", 2)
    u = bounded.control("u", lower=-2.0, upper=2.0)  # the swarms need a box; the optimum is inside
    bounded.set_der(x, ca.DM(A) @ x + ca.DM(B) @ u)
    bounded.add_stage_cost(residual=ca.vertcat(x, u), weight=np.array([2.0, 1.0, 0.5]))
    bounded.add_terminal_cost(residual=x, weight=np.array([20.0, 10.0]))
    assert np.max(np.abs(controls)) < 2.0
    result = uo.solve(bounded, "igwo", x0=x0, options={"seed": 3})
    assert result.cost == pytest.approx(uo.score(bounded, result.controls, x0=x0)[0], rel=1e-12)
    assert cost - 1e-9 <= result.cost < 1.5 * cost


def test_a_collocation_tracking_problem_in_closed_loop_with_the_real_time_iteration():
    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=10, transcription="collocation", degree=2
    )
    shooting_problem = problem.replace(transcription="multiple_shooting", degree=None)
    x0 = problem.initial_state()
    runs = [uo.simulate(uo.NMPC(p, "sqp-rti"), x0, duration=6.0, seed=1) for p in (problem, shooting_problem)]
    errors = [np.hypot(*run.errors.T) for run in runs]
    assert all(run.failures == 0 for run in runs)
    # from rest onto the moving path, as the RK4 multiple-shooting controller does it
    assert errors[0][0] == 0.0 and errors[0][-1] < 0.1 and np.max(errors[0]) < 1.0
    assert np.max(np.abs(errors[0] - errors[1])) < 0.05
    collocated = uo.solve(problem, "ipopt", x0=x0, t0=0.0)
    shooting = uo.solve(
        problem.replace(transcription="multiple_shooting", degree=None), "ipopt", x0=x0, t0=0.0
    )
    # two discretisations of one ODE: close, not equal
    assert (
        0 < np.max(np.abs(collocated.controls - shooting.controls)) < 0.05 * np.max(np.abs(shooting.controls))
    )


@needs_compiler
def test_generated_c_of_a_collocation_problem_equals_the_virtual_machine(tmp_path):
    ocp = lq_ocp(3)
    x0 = np.array([1.0, -0.5])
    virtual = uo.solve(ocp, "ipopt", x0=x0)
    compiled = uo.solve(ocp, "ipopt", x0=x0, options={"compiled": True})
    np.testing.assert_allclose(compiled.controls, virtual.controls, rtol=1e-9, atol=1e-9)


@needs_compiler
def test_generated_c_of_a_collocation_tracking_problem_equals_the_virtual_machine(tmp_path):
    """The Newton solve of the implicit step is generated as C too (CasADi's fast_newton)."""
    from uuv_ocp import codegen

    problem = uo.TrackingProblem(
        uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4, transcription="collocation", degree=2
    )
    generated = codegen.generate_c(problem, tmp_path, population=8)
    assert set(generated.functions) >= {"cost", "cost_batch", "model_step", "rollout"}
    symbolic = codegen.symbolic_functions(problem, population=8)
    rng = np.random.default_rng(5)
    x0 = problem.initial_state()
    for name in ("model_step", "rollout", "cost"):
        reference = symbolic[name]
        inputs = [rng.normal(scale=0.1, size=reference.size_in(i)) for i in range(reference.n_in())]
        if name == "model_step":
            inputs[0] = x0 + inputs[0].ravel()
        for want, got in zip(reference.call(inputs), generated.functions[name].call(inputs), strict=True):
            np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-12)
    step = uo.generate_c(problem, tmp_path / "rti", functions=("nmpc_step",))
    assert "nmpc_step" in step.functions


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"degree": 3}, "degree is for transcription='collocation'"),
        ({"transcription": "collocation", "degree": 6}, "degree must be one of"),
        ({"transcription": "collocation", "substeps": 2}, "substeps must be 1"),
        ({"transcription": "pseudospectral"}, "transcription must be one of"),
    ],
)
def test_bad_transcriptions_are_refused_by_name(arguments, message):
    with pytest.raises(ValueError, match=message):
        uo.Ocp(**arguments)
    with pytest.raises(ValueError, match=message):
        uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), **arguments)
