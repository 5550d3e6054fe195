"""Exact backends agree with each other; the terminal fallback; failures are reported."""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.helpers_fossen import (
    exact_rollout,
    formulation_cost,
    formulation_violation,
    rk4,
    rk4_error_bound,
    rk4_rollout,
    s2_reference,
)

# every registered exact backend but the real-time iteration (one SQP step per call by default;
# tests/solvers/test_rti.py holds it to IPOPT's optimum in its converged mode): a new one is tested here
EXACT = [
    name for name in uo.available_solvers() if uo.solvers.REGISTRY.kind(name) == "exact" and name != "sqp-rti"
]
DT = 0.1  # s2_problem's sampling time and horizon (conftest)
HORIZON = 20


@pytest.fixture(scope="module")
def results(s2_problem, feasible_start):
    x0, t0 = feasible_start
    return {name: uo.solve(s2_problem, name, x0=x0, t0=t0) for name in EXACT}


@pytest.mark.parametrize("name", ["sqp", "fatrop"])
def test_exact_backends_reach_the_ipopt_optimum(results, name):
    """Three different NLP algorithms (interior point, SQP, structured interior point) agree."""
    reference = results["ipopt"]
    result = results[name]
    assert reference.success and result.success, result.status
    assert not result.terminal_relaxed
    assert result.cost == pytest.approx(reference.cost, rel=1e-6)
    # the optimum is flat along some control directions: sqp's plan differs by up to 3 N
    np.testing.assert_allclose(result.controls, reference.controls, atol=5.0)
    np.testing.assert_allclose(result.states, reference.states, atol=1e-3)


def check_dynamics_gaps(vehicle, states, controls, current=(0.0, 0.0)):
    """Planned states satisfy x_{k+1} = RK4(x_k, τ_k) of the independent numpy model."""
    predicted = np.array([rk4(vehicle, states[k], controls[k], DT, current) for k in range(len(controls))])
    np.testing.assert_allclose(states[1:], predicted, rtol=0, atol=1e-8)


@pytest.mark.parametrize("name", EXACT)
def test_optimum_is_feasible_by_independent_checks(s2_problem, feasible_start, results, name):
    x0, t0 = feasible_start
    result = results[name]
    vehicle = s2_problem.vehicle
    max_thrust = np.asarray(vehicle.max_thrust)
    assert result.controls.shape == (HORIZON, 3) and result.states.shape == (HORIZON + 1, 6)
    assert np.all(np.abs(result.controls) <= max_thrust * (1 + 1e-6))  # |τ| <= τ_max
    increments = np.diff(np.vstack([np.zeros(3), result.controls]), axis=0)  # u_prev = 0
    assert np.all(np.abs(increments) <= np.asarray(vehicle.max_thrust_rate) * DT + 1e-6 * max_thrust)
    np.testing.assert_allclose(result.states[0], x0, rtol=0, atol=1e-9)  # x_0 = x̂_0
    check_dynamics_gaps(vehicle, result.states, result.controls)  # multiple-shooting gaps closed
    terminal = s2_reference([t0 + HORIZON * DT])[0]  # x_N = x_R,N (analytic reference)
    np.testing.assert_allclose(result.states[-1], terminal, rtol=0, atol=1e-6)
    assert result.max_violation <= 1e-6


@pytest.mark.parametrize("name", EXACT)
def test_reported_cost_and_violation_are_the_formulation_on_an_independent_rollout(
    s2_problem, feasible_start, results, name
):
    """Cost and violation recomputed: docs/formulation.md in numpy on a numpy RK4 rollout."""
    x0, t0 = feasible_start
    result = results[name]
    states = rk4_rollout(s2_problem.vehicle, x0, result.controls, DT)
    scaled = result.controls / np.asarray(s2_problem.vehicle.max_thrust)
    reference = s2_reference(t0 + DT * np.arange(HORIZON + 1))
    cost = formulation_cost(s2_problem.weights, states, scaled, np.zeros(3), reference)
    assert result.cost == pytest.approx(cost, rel=1e-9)
    rate_bound = (
        np.asarray(s2_problem.vehicle.max_thrust_rate) * DT / np.asarray(s2_problem.vehicle.max_thrust)
    )
    violation = formulation_violation(states, scaled, np.zeros(3), reference[-1], rate_bound)
    assert result.max_violation == pytest.approx(violation, rel=1e-6, abs=1e-10)


@pytest.mark.parametrize("name", EXACT)
def test_planned_states_agree_with_an_adaptive_integrator_to_the_rk4_error(
    s2_problem, feasible_start, results, name
):
    """Scipy's DOP853 (rtol 1e-12) on the numpy Fossen model vs the RK4 plan: RK4-sized error only."""
    x0, _ = feasible_start
    result = results[name]
    vehicle = s2_problem.vehicle
    exact = exact_rollout(vehicle, x0, result.controls, DT)
    bound = rk4_error_bound(vehicle, x0, result.controls, DT) + 1e-8  # + the NLP's gap tolerance
    assert np.all(np.abs(result.states - exact) <= bound)
    assert np.max(np.abs(result.states - exact)) > 1e-9  # RK4 is not exact: the test can see 1e-9


def test_soft_formulation_is_exact_when_the_hard_one_is_feasible(s2_problem, feasible_start, results):
    x0, t0 = feasible_start
    soft = uo.solve(s2_problem, "ipopt", x0=x0, t0=t0, options={"terminal_strategy": "soft"})
    assert not soft.terminal_relaxed
    assert soft.cost == pytest.approx(results["ipopt"].cost, rel=1e-6)


@pytest.mark.parametrize("name", EXACT)
def test_infeasible_terminal_equality_falls_back_to_the_soft_problem(s2_problem, name):
    x0 = uo.Reference.paper("s2").initial_state(0.0)  # at rest: x_N = x_R,N is unreachable
    result = uo.solve(s2_problem, name, x0=x0, t0=0.0)
    assert result.success
    assert result.terminal_relaxed
    assert result.status.startswith("soft_terminal")
    assert result.max_violation > 1e-3  # the residual is reported honestly


def test_fatrop_last_resort_retry_solves_what_its_fast_settings_do_not(s2_problem):
    """From rest, fatrop's fast mu_init = 1e-4 fails; the conservative retry succeeds.

    The retry reaches IPOPT's soft optimum.
    """
    x0 = uo.Reference.paper("s2").initial_state(0.0)
    result = uo.solve(s2_problem, "fatrop", x0=x0, t0=0.0)
    attempts = [variant for variant, _, _ in result.details["attempts"]]
    assert attempts == ["hard", "soft", "soft (robust)"]
    assert result.success and result.terminal_relaxed
    reference = uo.solve(s2_problem, "ipopt", x0=x0, t0=0.0)
    assert result.cost == pytest.approx(reference.cost, rel=1e-8)
    fast_only = uo.solve(
        s2_problem, "fatrop", x0=x0, t0=0.0, options={"plugin_options": {"fatrop.mu_init": 1e-4}}
    )
    # the same settings everywhere: the mu_init retry cannot help, only the IPOPT rescue from
    # fatrop's last iterate (the last stage of fatrop's fallback chain) solves it
    assert [variant for variant, _, _ in fast_only.details["attempts"]][-2:] == [
        "soft (robust)",
        "soft (rescue)",
    ]
    assert fast_only.cost == pytest.approx(reference.cost, rel=1e-8)


def test_warm_start_from_previous_result_converges_faster(s2_problem, feasible_start, results):
    x0, t0 = feasible_start
    again = uo.solve(s2_problem, "ipopt", x0=x0, t0=t0, warm_start=results["ipopt"].iterate)
    assert again.success
    assert again.iterations < results["ipopt"].iterations
    assert again.cost == pytest.approx(results["ipopt"].cost, rel=1e-8)


def test_solver_failure_is_reported_not_raised(s2_problem, feasible_start):
    x0, t0 = feasible_start
    result = uo.solve(
        s2_problem,
        "ipopt",
        x0=x0,
        t0=t0,
        options={"max_iter": 1, "terminal_strategy": "hard-first"},
    )
    assert not result.success
    assert result.status


def test_unknown_solver_lists_valid_names(s2_problem, feasible_start):
    x0, t0 = feasible_start
    with pytest.raises(ValueError, match="ipopt") as error:
        uo.solve(s2_problem, "newton", x0=x0, t0=t0)
    assert "newton" in str(error.value)


def test_unknown_option_raises(s2_problem, feasible_start):
    x0, t0 = feasible_start
    with pytest.raises(ValueError, match="bogus"):
        uo.solve(s2_problem, "ipopt", x0=x0, t0=t0, options={"bogus": 1})


@pytest.mark.parametrize("name", EXACT)
def test_unknown_option_error_lists_exactly_the_options_the_backend_reads(s2_problem, name):
    """The message lists the backend's ``option_names``: its declaration (the docs' table)."""
    from uuv_ocp.solvers import REGISTRY
    from uuv_ocp.solvers.catalog import declared_options

    backend = REGISTRY.factory(name)
    assert set(backend.option_names) == {option.name for option in declared_options(name)}
    with pytest.raises(ValueError, match="bogus") as error:
        backend(s2_problem, {"bogus": 1})
    assert str(error.value).endswith(f"valid: {sorted(backend.option_names)}")


def test_the_nlp_module_does_not_reach_up_to_its_backends():
    # the backends import NlpSolver from nlp; a lazy nlp.IpoptSolver (importlib in a module
    # __getattr__) closed that loop out of the import graph's sight, so it is gone
    from uuv_ocp.solvers import FatropSolver, IpoptSolver, SqpSolver, nlp

    assert (IpoptSolver.__module__, FatropSolver.__module__, SqpSolver.__module__) == (
        "uuv_ocp.solvers.ipopt",
        "uuv_ocp.solvers.fatrop",
        "uuv_ocp.solvers.sqp",
    )
    with pytest.raises(AttributeError):
        nlp.IpoptSolver  # noqa: B018


def test_available_solvers_lists_exact_backends():
    assert set(EXACT) <= set(uo.available_solvers())


def test_solver_specific_terminal_penalty_keeps_the_soft_problem_exact(s2_problem, feasible_start, results):
    x0, t0 = feasible_start
    soft = uo.solve(
        s2_problem, "ipopt", x0=x0, t0=t0, options={"terminal_strategy": "soft", "terminal_penalty": 1e6}
    )
    assert not soft.terminal_relaxed
    # ρ = 1e6 scales the slack multipliers: IPOPT's complementarity tolerance leaves ~2e-6
    assert soft.cost == pytest.approx(results["ipopt"].cost, rel=1e-5)
    with pytest.raises(ValueError, match="terminal_penalty"):
        uo.solve(s2_problem, "ipopt", x0=x0, t0=t0, options={"terminal_penalty": -1.0})


def test_failed_soft_solves_escalate_the_penalty(s2_problem):
    x0 = uo.Reference.paper("s2").initial_state(0.0)
    options = {"max_iter": 1, "penalty_escalation": [100.0, 1e4]}
    result = uo.solve(s2_problem, "ipopt", x0=x0, t0=0.0, options=options)
    variants = [attempt[0] for attempt in result.details["attempts"]]
    assert variants == ["hard", "soft", "soft_x100", "soft_x10000"]
    assert not result.success  # one iteration is not enough: reported, not raised
    sqp = uo.get_solver(s2_problem, "sqp")
    assert sqp._escalations == ["soft_x100", "soft_x10000"]


def test_sqp_soft_solution_with_slack_curvature_is_exact_when_feasible(s2_problem, feasible_start, results):
    # the L1 + L2 penalty ρ Σ s + (μ/2) Σ s² keeps the exact-penalty property: zero slacks
    x0, t0 = feasible_start
    soft = uo.solve(s2_problem, "sqp", x0=x0, t0=t0, options={"terminal_strategy": "soft"})
    assert soft.success, soft.status
    assert not soft.terminal_relaxed
    assert soft.max_violation <= 1e-6
    assert soft.cost == pytest.approx(results["ipopt"].cost, rel=1e-6)


def test_sqp_soft_solve_on_an_untrackable_reference():
    # s8 at t = 2.6 s of the closed loop from rest (measured state and last control): with the
    # QRQP soft QPs, ρ escalation (100,) and no slack curvature, every attempt failed here
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s8"))
    x0 = [1.3211455157635184, 1.2426495015038603, 0.9845812466791346,
          0.7817968185531988, 0.001172168311532868, -0.2100982601165024]  # fmt: skip
    u_prev = [-63.56378872777059, 559.520718834077, -1036.8866131587417]
    options = {"terminal_strategy": "soft"}
    result = uo.solve(problem, "sqp", x0=x0, t0=2.6, u_prev=u_prev, options=options)
    assert result.success, result.details["attempts"]


def test_sqp_last_resort_blocksqp_solves_a_cycling_soft_step():
    # s8 at t = 17.6 s of the closed loop from rest (measured state and last control), cold
    # start: Gauss–Newton sqpmethod cycles on the soft NLP at ρ = 1e4, 1e6 and 1e8 (100
    # iterations each); the last-resort blockSQP retry solves it, to IPOPT's optimum
    import casadi as ca

    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s8"))
    x0 = [8.41395624566128, 4.947177579542833, -0.28499105239682054,
          0.9616330615256681, 0.0005822615287225845, -1.1238876018752015]  # fmt: skip
    u_prev = [1816.7022929977904, -1999.9999999757981, -204.99494203169775]
    solver = uo.get_solver(problem, "sqp", options={"terminal_strategy": "soft"})
    p = problem.parameters(x0, 17.6, u_prev=u_prev)
    result = solver.solve(p)
    attempts = result.details["attempts"]
    assert [a[0] for a in attempts] == ["soft", "soft_x100", "soft_x10000", "soft_x10000 (robust)"]
    assert result.success, attempts
    assert result.terminal_relaxed  # s8 is untrackable: the terminal slacks stay active
    data = solver.variants["soft_x10000"]
    nlp = data.nlp
    ipopt = ca.nlpsol("ipopt", "ipopt", nlp, {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes"})
    reference = ipopt(x0=result.iterate.primal, p=p, lbx=data.lbx, ubx=data.ubx, lbg=data.lbg, ubg=data.ubg)
    assert ipopt.stats()["success"]
    objective = ca.Function("f", [nlp["x"], nlp["p"]], [nlp["f"]])
    constraints = ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])
    g = np.asarray(constraints(result.iterate.primal, p)).ravel()
    assert np.all(g >= data.lbg - 1e-6) and np.all(g <= data.ubg + 1e-6)
    assert float(objective(result.iterate.primal, p)) == pytest.approx(float(reference["f"]), rel=1e-6)


@pytest.fixture(scope="module")
def still_water_pair(s2_problem):
    backend = uo.get_solver(s2_problem, "ipopt")
    data = backend.variants["hard"]
    return data, backend._still_water_nlp(data)


def test_still_water_nlp_has_the_derivatives_of_the_general_nlp_at_zero_current(
    s2_problem, feasible_start, still_water_pair
):
    """Same f, g, constraint Jacobian and Lagrangian Hessian at zero current, fewer operations.

    The current terms are gone, not hidden.
    """
    import casadi as ca

    data, still = still_water_pair
    x0, t0 = feasible_start
    p = s2_problem.parameters(x0, t0)
    rng = np.random.default_rng(3)
    w = rng.normal(size=data.lbx.size)
    lam_g = rng.normal(size=data.lbg.size)

    def derivatives(nlp):
        lagrangian = nlp["f"] + ca.dot(ca.SX(lam_g), nlp["g"])
        hessian = ca.hessian(lagrangian, nlp["x"])[0]
        jacobian = ca.jacobian(nlp["g"], nlp["x"])
        function = ca.Function("d", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"], jacobian, hessian])
        return function, [np.array(ca.densify(value)) for value in function(w, p)]

    general, general_values = derivatives(data.nlp)
    special, special_values = derivatives(still)
    for a, b in zip(general_values, special_values, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-9)
    assert special.n_instructions() < 0.8 * general.n_instructions()


@pytest.mark.parametrize("name", EXACT)
def test_still_water_specialisation_reaches_the_general_optimum(s2_problem, feasible_start, results, name):
    x0, t0 = feasible_start
    assert results[name].details["still_water"]
    general = uo.solve(s2_problem, name, x0=x0, t0=t0, options={"still_water": False})
    assert not general.details["still_water"]
    assert general.success
    assert results[name].cost == pytest.approx(general.cost, rel=1e-9)
    np.testing.assert_allclose(results[name].controls, general.controls, atol=1e-6 * 2000)


def test_a_current_in_the_model_uses_the_general_nlp(s2_problem, feasible_start, results):
    x0, t0 = feasible_start
    current = np.array([0.3, -0.2])
    with_current = uo.solve(s2_problem, "fatrop", x0=x0, t0=t0, current=current)
    assert with_current.success and not with_current.details["still_water"]
    # the plan obeys the numpy model under that current (gaps, and an adaptive integrator to
    # the RK4 error), and it differs from still water
    vehicle = s2_problem.vehicle
    check_dynamics_gaps(vehicle, with_current.states, with_current.controls, current)
    exact = exact_rollout(vehicle, x0, with_current.controls, DT, current)
    bound = rk4_error_bound(vehicle, x0, with_current.controls, DT, current) + 1e-8
    assert np.all(np.abs(with_current.states - exact) <= bound)
    assert np.max(np.abs(with_current.controls - results["fatrop"].controls)) > 10.0
    reference = uo.solve(s2_problem, "ipopt", x0=x0, t0=t0, current=current)
    assert with_current.cost == pytest.approx(reference.cost, rel=1e-6)


def test_still_water_option_is_validated(s2_problem):
    with pytest.raises(ValueError, match="still_water"):
        uo.get_solver(s2_problem, "fatrop", {"still_water": "yes"})


# ------------------------------------------------------------------ failures say what happened
@pytest.mark.parametrize("name", EXACT)
def test_failed_exact_solve_reports_the_rollout_of_its_controls(s2_problem, name):
    """A failed solve's states are the model's states under its controls (numpy RK4, not the NLP's).

    From rest with the terminal equality and two iterations per attempt nothing converges; the
    NLP's states of such an iterate miss the dynamics by 0.35–2.3 (issue 31).
    """
    x0 = np.zeros(6)
    result = uo.solve(s2_problem, name, x0=x0, t0=0.0, options={"max_iter": 2})
    assert not result.success
    expected = rk4_rollout(s2_problem.vehicle, x0, result.controls, DT)
    np.testing.assert_allclose(result.states, expected, rtol=0, atol=1e-9)
    # the warm start keeps the NLP's own states (shifted into the next solve)
    assert result.iterate.states.shape == result.states.shape


def test_sqp_failure_statuses_name_what_stopped_each_attempt(s2_problem):
    """``blocksqp`` (sqp's last resort) reports no ``return_status``: its unified status is translated."""
    result = uo.solve(s2_problem, "sqp", x0=np.zeros(6), t0=0.0, options={"max_iter": 2})
    statuses = [status for _, status, _ in result.details["attempts"]]
    assert not result.success and "unknown" not in result.status
    assert all(status and "unknown" not in status for status in statuses)
    assert statuses[-1] == "blocksqp: Maximum_Iterations_Exceeded"


def test_plugin_status_falls_back_on_casadis_unified_status():
    from uuv_ocp.solvers.nlp import plugin_status

    assert plugin_status("ipopt", {"return_status": "Solve_Succeeded"}) == "Solve_Succeeded"
    assert plugin_status("blocksqp", {"unified_return_status": "SOLVER_RET_NAN"}) == "blocksqp: NaN_Detected"
    assert plugin_status("x", {"success": False}) == "x: failed without a status"
    assert plugin_status("x", {}) == "x: no status reported"


# ------------------------------------------------------------------------ tolerance on an LQR
def lqr_ocp_and_reference(horizon: int = 20, dt: float = 0.1):
    """Return an unconstrained discrete LQR as a ``uo.Ocp``, its x0, and its optimum by a dense solve.

    ẋ = A x + B u is linear, so RK4 over ``dt`` is exactly ``x⁺ = A_d x + B_d u`` with the
    4th-order Taylor polynomials below; condensing ``x = Φ x₀ + Γ u`` gives the normal equations.
    """
    a = np.array([[0.0, 1.0], [-2.0, -0.3]])
    b = np.array([[0.0], [1.0]])
    q, r, terminal = np.diag([10.0, 1.0]), np.array([[0.1]]), np.diag([50.0, 5.0])
    ocp = uo.Ocp(horizon=horizon, dt=dt, integrator="rk4", substeps=1)
    x = ocp.state("x", 2)
    u = ocp.control("u", 1)
    ocp.set_der(x, ca.mtimes(ca.DM(a), x) + ca.mtimes(ca.DM(b), u))
    ocp.add_stage_cost(residual=ca.vertcat(x, u), weight=[10.0, 1.0, 0.1])
    ocp.add_terminal_cost(residual=x, weight=[50.0, 5.0])
    x0 = np.array([1.0, -0.5])
    ha, eye = dt * a, np.eye(2)
    a_d = eye + ha + ha @ ha / 2 + ha @ ha @ ha / 6 + ha @ ha @ ha @ ha / 24
    b_d = dt * (eye + ha / 2 + ha @ ha / 6 + ha @ ha @ ha / 24) @ b
    phi = np.vstack([np.linalg.matrix_power(a_d, k) for k in range(horizon + 1)])
    gamma = np.zeros((2 * (horizon + 1), horizon))
    for k in range(horizon + 1):
        for j in range(k):
            gamma[2 * k : 2 * k + 2, j : j + 1] = np.linalg.matrix_power(a_d, k - 1 - j) @ b_d
    weights = np.kron(np.eye(horizon + 1), q)
    weights[-2:, -2:] = terminal
    hessian = gamma.T @ weights @ gamma + np.kron(np.eye(horizon), r)
    optimum = np.linalg.solve(hessian, -gamma.T @ weights @ phi @ x0)
    return ocp, x0, optimum


@pytest.mark.parametrize(
    ("name", "options", "tolerance"),
    [
        ("ipopt", {}, 1e-6),
        ("fatrop", {}, 1e-6),
        # sqp's documented default gap (docs/solvers.md, "sqp's tolerance"): 1.3e-3 on this LQR
        ("sqp", {}, 2e-3),
        ("sqp", {"levenberg_marquardt": 0.0}, 1e-6),
        ("sqp", {"plugin_options": {"tol_du": 1e-9}}, 1e-6),
    ],
)
def test_exact_backends_reach_the_lqr_optimum_to_their_documented_tolerance(name, options, tolerance):
    """Controls of an LQR against its dense solve: 1e-6 for ipopt, fatrop and sqp's tight settings."""
    ocp, x0, optimum = lqr_ocp_and_reference()
    result = uo.solve(ocp, name, x0=x0, options=options)
    assert result.success
    np.testing.assert_allclose(result.controls.ravel(), optimum, rtol=0, atol=tolerance)
