"""The symbolic core: any Ocp, solved by every backend, against independent references."""

from __future__ import annotations

import sys

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler

DT = 0.1
HORIZON = 12
Q = np.diag([3.0, 2.0, 0.5, 0.4])
R = np.diag([0.2, 0.3])
QF = np.diag([10.0, 8.0, 1.0, 1.0])
TIGHT = {
    "ipopt": {"plugin_options": {"ipopt.tol": 1e-12}},
    "fatrop": {"plugin_options": {"fatrop.tol": 1e-12}},
    "sqp": {"plugin_options": {"tol_du": 1e-12, "tol_pr": 1e-12}},
}


def double_integrator(residual_form: bool) -> uo.Ocp:
    ocp = uo.Ocp(horizon=HORIZON, dt=DT)
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    x = ca.vertcat(pos, vel)
    if residual_form:
        ocp.add_stage_cost(residual=x, weight=np.diag(Q))
        ocp.add_stage_cost(residual=acc, weight=np.diag(R))
        ocp.add_terminal_cost(residual=x, weight=np.diag(QF))
    else:
        ocp.add_stage_cost(ca.bilin(ca.DM(Q), x, x) + ca.bilin(ca.DM(R), acc, acc))
        ocp.add_terminal_cost(ca.bilin(ca.DM(QF), x, x))
    return ocp


def riccati_lqr(x0: np.ndarray) -> tuple[np.ndarray, float]:
    """Finite-horizon discrete LQR of the double integrator, written in numpy.

    RK4 is exact on it (A² = 0): A_d = I + A dt, B_d = B dt + A B dt²/2.
    """
    a = np.zeros((4, 4))
    a[0, 2] = a[1, 3] = 1.0
    b = np.zeros((4, 2))
    b[2, 0] = b[3, 1] = 1.0
    a_d = np.eye(4) + a * DT
    b_d = b * DT + a @ b * DT**2 / 2
    p = QF
    gains = []
    for _ in range(HORIZON):
        k = np.linalg.solve(R + b_d.T @ p @ b_d, b_d.T @ p @ a_d)
        p = Q + a_d.T @ p @ (a_d - b_d @ k)
        gains.append(k)
    gains.reverse()
    x, controls = x0.copy(), []
    for k in gains:
        u = -k @ x
        controls.append(u)
        x = a_d @ x + b_d @ u
    return np.array(controls), float(x0 @ p @ x0)


@pytest.mark.parametrize("residual_form", [True, False])
@pytest.mark.parametrize("solver", ["ipopt", "fatrop", "sqp"])
def test_unconstrained_lq_problem_equals_the_riccati_lqr(solver, residual_form):
    x0 = np.array([1.0, -0.5, 0.3, 0.8])
    controls, cost = riccati_lqr(x0)
    res = uo.solve(double_integrator(residual_form), solver, x0=x0, options=TIGHT[solver])
    assert res.success
    np.testing.assert_allclose(res.controls, controls, rtol=1e-8, atol=1e-8)
    assert res.cost == pytest.approx(cost, rel=1e-8)
    assert res.states.shape == (HORIZON + 1, 4) and res.controls.shape == (HORIZON, 2)


def obstacle_ocp(radius: float = 0.6) -> uo.Ocp:
    ocp = uo.Ocp(horizon=20, dt=0.2)
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    goal = ocp.parameter("goal", 2)
    ref = ocp.parameter("ref", 2, stagewise=True)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(ca.sumsqr(pos - ref) + 0.1 * ca.sumsqr(acc))
    ocp.add_terminal_cost(10 * ca.sumsqr(pos - goal))
    ocp.subject_to(ca.sumsqr(pos - ca.DM([2.0, 0.1])) >= radius**2)
    ocp.subject_to(vel <= 1.5, soft=1e3)
    ocp.subject_to(vel >= -1.5)
    return ocp


def obstacle_data(ocp: uo.Ocp) -> dict:
    line = np.linspace(0.0, 4.0, ocp.horizon + 1)
    return {"goal": [4.0, 0.0], "ref": np.column_stack([line, np.zeros_like(line)])}


@pytest.mark.parametrize("solver", ["ipopt", "fatrop", "sqp"])
def test_constraints_hold_and_the_exact_solvers_agree(solver):
    ocp = obstacle_ocp()
    data = obstacle_data(ocp)
    u_prev = np.array([0.2, 0.0])
    res = uo.solve(ocp, solver, x0=[0.0, 0.0, 0.0, 0.0], parameters=data, u_prev=u_prev)
    assert res.success, res.status
    reference = uo.solve(ocp, "ipopt", x0=[0.0, 0.0, 0.0, 0.0], parameters=data, u_prev=u_prev)
    assert res.cost == pytest.approx(reference.cost, rel=1e-6)
    # independent checks on the returned plan: distance to the obstacle on nodes 1..N,
    # the control box and the rate bound (|u_0 - u_prev| included)
    distance = np.linalg.norm(res.states[1:, :2] - [2.0, 0.1], axis=1)
    assert np.all(distance >= 0.6 - 1e-6)
    assert np.all(np.abs(res.controls) <= 1.0 + 1e-9)
    increments = np.diff(np.vstack([u_prev, res.controls]), axis=0)
    assert np.all(np.abs(increments) <= 2.0 * 0.2 + 1e-7)
    assert np.max(np.abs(increments)) > 0.4 - 1e-6  # the rate bound is active
    assert np.all(res.states[1:, 2:] >= -1.5 - 1e-6)
    # the plan's states are the RK4 rollout of its controls (dynamics gaps closed)
    rollout = ocp.rollout(res.controls, ocp.parameters([0.0] * 4, data, u_prev))
    np.testing.assert_allclose(res.states, rollout, atol=1e-7)


def test_score_is_an_independent_evaluation_of_the_formulation():
    ocp = obstacle_ocp()
    data = obstacle_data(ocp)
    rng = np.random.default_rng(4)
    controls = rng.uniform(-0.2, 1.0, size=(ocp.horizon, 2))  # fast enough to break the speed limit
    cost, violation = uo.score(ocp, controls, x0=[0.0, 0.0, 0.0, 0.0], parameters=data)
    # the same objective in numpy with a hand-written RK4 of the double integrator
    x = np.zeros(4)
    states = [x]
    for u in controls:
        f = lambda s, u=u: np.concatenate([s[2:], u])  # noqa: E731
        k1 = f(x)
        k2 = f(x + 0.1 * k1)
        k3 = f(x + 0.1 * k2)
        k4 = f(x + 0.2 * k3)
        x = x + 0.2 / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        states.append(x)
    states = np.array(states)
    ref = np.asarray(data["ref"])
    expected = np.sum((states[:-1, :2] - ref[:-1]) ** 2) + 0.1 * np.sum(controls**2)
    expected += 10 * np.sum((states[-1, :2] - [4.0, 0.0]) ** 2)
    soft_excess = np.sum(np.maximum(0.0, states[1:, 2:] - 1.5))
    assert soft_excess > 0.1  # the soft speed limit is broken, so its penalty is tested
    expected += 1e3 * soft_excess  # the soft bound, exact L1
    assert cost == pytest.approx(expected, rel=1e-12)
    gaps = [
        0.36 - np.sum((states[1:, :2] - [2.0, 0.1]) ** 2, axis=1),
        -1.5 - states[1:, 2:].ravel(),
        np.abs(np.diff(np.vstack([np.zeros(2), controls]), axis=0)).ravel() - 0.4,  # rate: 2 * 0.2
    ]
    assert violation == pytest.approx(max(0.0, *[float(np.max(g)) for g in gaps]), rel=1e-12)


def test_terminal_equality_holds_and_the_swarm_sees_it_as_a_penalty():
    ocp = uo.Ocp(horizon=15, dt=0.2)
    pos = ocp.state("pos")
    vel = ocp.state("vel")
    acc = ocp.control("acc", lower=-2.0, upper=2.0)
    goal = ocp.parameter("goal")
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=acc)
    ocp.subject_to(pos == goal, at="terminal")
    ocp.subject_to(vel == 0, at="terminal")
    for solver in ("ipopt", "fatrop", "sqp"):
        res = uo.solve(ocp, solver, x0=[0.0, 0.0], parameters={"goal": 1.0})
        assert res.success and not res.terminal_relaxed
        np.testing.assert_allclose(res.states[-1], [1.0, 0.0], atol=1e-7)
    swarm = uo.solve(ocp, "pso", x0=[0.0, 0.0], parameters={"goal": 1.0})
    assert np.all(np.abs(swarm.controls) <= 2.0)
    fitness = swarm.details["fitness"]
    cost, violation = uo.score(ocp, swarm.controls, x0=[0.0, 0.0], parameters={"goal": 1.0})
    assert fitness == pytest.approx(cost + 1e4 * np.sum(np.abs(swarm.states[-1] - [1.0, 0.0])), rel=1e-9)


def test_build_is_explicit_cached_and_the_problem_immutable_after():
    ocp = double_integrator(True)
    assert ocp._spec is None  # declaring builds nothing
    built = ocp.build()
    assert ocp.build() is built
    with pytest.raises(ValueError, match="immutable"):
        ocp.state("extra")
    twin = double_integrator(True)
    assert twin.spec().key == ocp.spec().key
    other = double_integrator(False)
    assert other.spec().key != ocp.spec().key


def declared() -> tuple[uo.Ocp, ca.SX, ca.SX]:
    ocp = uo.Ocp(horizon=5, dt=0.1)
    x = ocp.state("x")
    u = ocp.control("u", lower=-1, upper=1)
    return ocp, x, u


def test_bad_declarations_raise_naming_the_problem():
    ocp, x, u = declared()
    with pytest.raises(ValueError, match="'x' is already declared"):
        ocp.state("x")
    with pytest.raises(ValueError, match="undeclared symbol"):
        ocp.subject_to(ca.SX.sym("stranger") <= 1)
    with pytest.raises(ValueError, match="comparison"):
        ocp.subject_to(x + 1)
    with pytest.raises(ValueError, match="at must be one of"):
        ocp.subject_to(x <= 1, at="middle")
    with pytest.raises(ValueError, match="must not depend on controls"):
        ocp.subject_to(u <= 1, at="terminal")
    with pytest.raises(ValueError, match="soft"):
        ocp.subject_to(x <= 1, soft=-1.0)
    with pytest.raises(ValueError, match="horizon"):
        uo.Ocp(horizon=0)
    with pytest.raises(ValueError, match="horizon"):
        uo.Ocp(horizon=10**9)
    with pytest.raises(ValueError, match="dt"):
        uo.Ocp(dt=float("nan"))
    with pytest.raises(ValueError, match="lower of control 'v'"):
        ocp.control("v", lower=2.0, upper=1.0)
    ocp.add_stage_cost(x**2)
    with pytest.raises(ValueError, match=r"\['x'\] have no dynamics"):
        uo.solve(ocp, "ipopt", x0=[0.0])


def test_bad_instance_data_raise_before_any_solve():
    ocp, x, u = declared()
    ocp.parameter("goal")
    ocp.parameter("track", 2, stagewise=True)
    ocp.set_der(x, u)
    ocp.add_stage_cost(x**2)
    good = {"goal": 1.0, "track": np.zeros((6, 2))}
    with pytest.raises(ValueError, match="'goal' is missing"):
        uo.solve(ocp, "ipopt", x0=[0.0], parameters={"track": good["track"]})
    with pytest.raises(ValueError, match=r"parameters\['track'\] must have shape \(6, 2\)"):
        uo.solve(ocp, "ipopt", x0=[0.0], parameters={**good, "track": np.zeros((4, 2))})
    with pytest.raises(ValueError, match="unknown name"):
        uo.solve(ocp, "ipopt", x0=[0.0], parameters={**good, "other": 1})
    with pytest.raises(ValueError, match="x0 must be finite"):
        uo.solve(ocp, "ipopt", x0=[float("inf")], parameters=good)
    with pytest.raises(ValueError, match=r"parameters\['goal'\] must be finite"):
        uo.solve(ocp, "ipopt", x0=[0.0], parameters={**good, "goal": float("nan")})
    with pytest.raises(ValueError, match="u_prev must lie inside"):
        uo.solve(ocp, "ipopt", x0=[0.0], parameters=good, u_prev=[5.0])


def test_swarms_refuse_unbounded_controls():
    with pytest.raises(ValueError, match="finite lower and upper bounds"):
        uo.solve(double_integrator(True), "igwo", x0=[1.0, 0.0, 0.0, 0.0])


def bounded_double_integrator() -> uo.Ocp:
    ocp = uo.Ocp(horizon=8, dt=0.2)
    pos = ocp.state("pos")
    vel = ocp.state("vel")
    acc = ocp.control("acc", lower=-1.0, upper=1.0, max_rate=4.0)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(pos - 1.0, 0.3 * acc))
    ocp.add_terminal_cost(residual=3 * (pos - 1.0))
    return ocp


def test_swarms_hybrids_and_a_plugin_work_on_any_ocp():
    ocp = bounded_double_integrator()
    x0 = [0.0, 0.0]
    optimum = uo.solve(ocp, "ipopt", x0=x0)
    for name in ("igwo", "gwo", "ssa", "pso"):
        res = uo.solve(ocp, name, x0=x0)
        assert np.all(np.abs(res.controls) <= 1.0)
        assert res.cost >= optimum.cost * (1 - 1e-9)
    hybrid = uo.solve(ocp, "pso+fatrop", x0=x0)
    assert hybrid.cost == pytest.approx(optimum.cost, rel=1e-7)

    class Clipped(uo.solvers.SqpSolver):
        """A plug-in exact backend (a registered subclass)."""

    uo.register_solver("plugin-sqp", Clipped, kind="exact", overwrite=True)
    try:
        assert "igwo+plugin-sqp" in uo.available_solvers()
        plug = uo.solve(ocp, "igwo+plugin-sqp", x0=x0)
        assert plug.cost == pytest.approx(optimum.cost, rel=1e-6)
    finally:
        uo.solvers.REGISTRY._factories.pop("plugin-sqp")
    with pytest.raises(ValueError, match="kind must be one of"):
        uo.register_solver("bad", Clipped, kind="quantum")


def test_nmpc_and_simulate_on_an_ocp_against_an_independent_plant():
    ocp = bounded_double_integrator()
    # the plant is the same double integrator written as a separate Function
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    plant = ca.Function("plant", [x, u], [ca.vertcat(x[1], u)])
    run = uo.simulate(uo.NMPC(ocp, "fatrop"), [0.0, 0.0], duration=6.0, plant=plant)
    assert run.failures == 0 and run.controls.shape == (30, 1)
    assert abs(run.states[-1, 0] - 1.0) < 1e-3  # settles on the set point
    assert np.all(np.abs(np.diff(np.r_[0.0, run.controls[:, 0]])) <= 4.0 * 0.2 + 1e-9)
    # the closed loop's states are the exact solution of ẍ = u under the held controls
    position, velocity = 0.0, 0.0
    for control in run.controls[:, 0]:
        position += velocity * 0.2 + 0.5 * control * 0.2**2
        velocity += control * 0.2
    assert run.states[-1] == pytest.approx([position, velocity], abs=1e-12)


@needs_compiler
def test_generated_c_of_an_ocp_equals_the_virtual_machine(tmp_path):
    ocp = bounded_double_integrator()
    code = uo.generate_c(ocp, tmp_path / "gen", functions=("cost", "rollout", "score_terms"))
    p = ocp.parameters([0.2, -0.1], u_prev=[0.5])
    rng = np.random.default_rng(2)
    for _ in range(5):
        scaled = rng.uniform(-1, 1, size=ocp.control_dim)
        for name in ("cost", "rollout", "score_terms"):
            compiled = code[name](scaled, p)
            symbolic = getattr(ocp.build(), name)(scaled, p)
            compiled = compiled if isinstance(compiled, (list, tuple)) else [compiled]
            symbolic = symbolic if isinstance(symbolic, (list, tuple)) else [symbolic]
            for a, b in zip(compiled, symbolic, strict=True):
                np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-14)


@needs_compiler
def test_all_c_igwo_step_on_an_ocp_equals_the_python_igwo(tmp_path, monkeypatch):
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    ocp = bounded_double_integrator()
    x0 = [0.0, 0.3]
    native = uo.get_solver(ocp, "igwo", {"compiled": True, "seed": 3})
    assert native.native is not None  # the SIMD kernel and the all-C step were built
    compiled = uo.solve(ocp, "igwo", x0=x0, options={"compiled": True, "seed": 3})
    python = uo.solve(ocp, "igwo", x0=x0, options={"compiled": False, "seed": 3})
    assert "compiled C step" in compiled.status
    np.testing.assert_allclose(compiled.controls, python.controls, rtol=1e-9, atol=1e-12)
    assert compiled.cost == pytest.approx(python.cost, rel=1e-9)


def test_swarms_compile_by_default_and_fall_back_with_one_warning(monkeypatch):
    from uuv_ocp.solvers.swarm import _compiled_default

    monkeypatch.delenv("UUV_OCP_COMPILED", raising=False)
    monkeypatch.setenv("CC", "/nonexistent/compiler")
    with pytest.warns(RuntimeWarning, match="virtual machine"):
        assert _compiled_default("auto") is False
    monkeypatch.setenv("CC", sys.executable)  # any executable counts as found
    assert _compiled_default("auto") is True
    monkeypatch.setenv("UUV_OCP_COMPILED", "0")
    assert _compiled_default("auto") is False
    with pytest.raises(ValueError, match="compiled"):
        _compiled_default("yes")


def test_compare_ranks_feasible_rows_first_and_reports_violations_by_kind():
    ocp = obstacle_ocp()
    data = obstacle_data(ocp)
    rows = uo.compare(ocp, ["pso", "ipopt", "sqp"], x0=[0.0, 0.0, 0.0, 0.0], parameters=data, seed=1)
    by_name = {row.solver: row for row in rows}
    assert [row.solver for row in rows] == ["pso", "ipopt", "sqp"]  # input order kept
    for row in rows:
        plan = uo.solve(ocp, row.solver, x0=[0.0] * 4, parameters=data) if row.solver != "pso" else None
        if plan is not None:  # the obstacle clearance recomputed from the plan (m²)
            clearance = np.sum((plan.states[1:, :2] - [2.0, 0.1]) ** 2, axis=1) - 0.36
            assert row.violations["constraint"] == pytest.approx(max(0.0, -clearance.min()), abs=1e-9)
        assert row.feasible == (max(row.violations.values()) <= 1e-6)
    ranked = sorted(rows, key=lambda row: row.rank)
    feasible = [row.feasible for row in ranked]
    assert feasible == sorted(feasible, reverse=True)  # feasible rows first
    costs = [row.cost for row in ranked if row.feasible]
    assert costs == sorted(costs)
    assert by_name["ipopt"].ratio == pytest.approx(1.0, rel=1e-6)
    table = uo.format_comparison(rows)
    assert table.splitlines()[1].split()[1] in ("ipopt", "sqp")


def test_fatrop_stalling_on_an_obstacle_is_finished_by_ipopt_from_its_iterate():
    """Finish fatrop's stalled solves next to an obstacle with IPOPT from its iterate, at once.

    Fatrop reaches the optimum but stalls (dual infeasibility under a large inertia-correction
    regularisation); the rescue converges to the optimum IPOPT finds on its own.
    """
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line")
    rock = uo.Obstacle.circle((5.0, 0.2), 1.0, margin=1.0)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), line, horizon=20, terminal="cost", obstacles=[rock])
    x0 = np.array([2.5, 0.0, 0.0, 0.5, 0.0, 0.0])
    fatrop = uo.solve(problem, "fatrop", x0=x0, t0=5.0)
    ipopt = uo.solve(problem, "ipopt", x0=x0, t0=5.0)
    assert fatrop.success and fatrop.max_violation <= 1e-6
    # the stall is recognised at once (fatrop's iteration limit, a feasible plan): no robust
    # retry that would stall the same way first
    assert [name for name, _, _ in fatrop.details["attempts"]] == ["hard", "hard (rescue)"]
    assert fatrop.cost == pytest.approx(ipopt.cost, rel=1e-8)
    assert np.min(rock.signed_distance(fatrop.states[1:])) >= -1e-6


def test_a_one_sided_soft_constraint_has_no_rows_on_its_infinite_side():
    """``vel <= 1.5`` (soft) gets its upper rows only; the plan is the two-sided one's.

    Reference: the same Ocp with the soft constraint written ``-1e3 <= vel <= 1.5`` (a finite
    side that never binds: rows on both sides, as every soft constraint had before), IPOPT.
    """
    results, rows = {}, {}
    for lower in (-np.inf, -1e3):
        ocp = uo.Ocp(horizon=20, dt=0.2)
        pos = ocp.state("pos", 2)
        vel = ocp.state("vel", 2)
        acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
        ocp.set_der(pos, vel)
        ocp.set_der(vel, acc)
        ocp.add_stage_cost(ca.sumsqr(pos - ca.DM([4.0, 0.0])) + 0.1 * ca.sumsqr(acc))
        ocp.bounded(lower, vel, 1.5, soft=1e3)  # binds: the goal is 4 m away, 4 s to get there
        results[lower] = uo.solve(ocp, "ipopt", x0=[0.0] * 4, options=TIGHT["ipopt"])
        keys = ocp.build().hard.constraint_keys
        rows[lower] = sorted({key[0] for key in keys if key[0].startswith("c0")})
    assert rows[-np.inf] == ["c0_upper"] and rows[-1e3] == ["c0_lower", "c0_upper"]
    one, two = results[-np.inf], results[-1e3]
    assert one.success and two.success
    assert np.max(one.states[:, 2:]) == pytest.approx(1.5, abs=1e-6)  # the bound binds
    np.testing.assert_allclose(one.controls, two.controls, rtol=0, atol=1e-7)
    assert one.cost == pytest.approx(two.cost, rel=1e-9)
