"""Real-time iteration backend ``"sqp-rti"`` and the NMPC preparation/feedback phases."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.native.compile import CompilerNotFoundError, find_c_compiler
from uuv_ocp.solvers import REGISTRY, get_solver
from uuv_ocp.solvers.result import Iterate
from uuv_ocp.solvers.rti import HPIPM_DEFAULTS, RtiSolver, finite_warm_start
from uuv_ocp.solvers.rti_ocp import STOP_CONVERGED, STOP_MAX_ITER, ocp_qp_options

TIGHT_HPIPM = {"hpipm": {f"res_{k}_max": 1e-12 for k in "gbdm"}}
#: HPIPM's OCP-QP API tight enough for 1e-8 comparisons (1e-12 is out of its reach on this QP)
TIGHT_OCP = {"mode": "robust", **{f"tol_{k}": 1e-11 for k in ("stat", "eq", "ineq", "comp")}}
TIGHT = {"hpipm": TIGHT_HPIPM, "hpipm-ocp": TIGHT_OCP}
#: the C step without partial condensing (the default condenses N = 20 to 5 stages, "auto")
PLAIN = {"cond_horizon": 0}
QP_PATHS = pytest.mark.parametrize("qpsol", ["hpipm", "hpipm-ocp"])
#: the C step with HPIPM's partial condensing (5 stages): condensed in prepare, rhs in feedback
CONDENSED = {"cond_horizon": 5}
WITH_CONDENSING = pytest.mark.parametrize("qpsol", ["hpipm", "hpipm-ocp", "hpipm-ocp-condensed"])


def qp_options(path: str, tight: bool = False) -> dict:
    """``qpsol`` and ``qpsol_options`` of a test's QP path (``hpipm-ocp-condensed``: CONDENSED)."""
    if path == "hpipm-ocp-condensed":
        return {"qpsol": "hpipm-ocp", "qpsol_options": {**(TIGHT_OCP if tight else {}), **CONDENSED}}
    if path == "hpipm-ocp":
        return {"qpsol": path, "qpsol_options": {**(TIGHT_OCP if tight else {}), **PLAIN}}
    return {"qpsol": path, **({"qpsol_options": TIGHT[path]} if tight else {})}


def needs_compiler(qpsol: str) -> None:
    if qpsol.startswith("hpipm-ocp"):
        try:
            find_c_compiler()
        except CompilerNotFoundError:
            pytest.skip("no C compiler: qpsol='hpipm-ocp' falls back to 'hpipm'")


@pytest.fixture(scope="module")
def problem() -> uo.TrackingProblem:
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)


def ipopt_reference(problem, t: float) -> tuple[np.ndarray, object]:
    """Return the reference's state at ``t`` and IPOPT's tight optimum from it."""
    x0 = problem.reference.evaluate([t])[0]
    options = {"plugin_options": {"ipopt.tol": 1e-12, "ipopt.bound_relax_factor": 0.0}}
    reference = uo.solve(problem, "ipopt", x0=x0, t0=t, options=options)
    assert reference.success
    return x0, reference


def perturbed_states(
    data, primal: np.ndarray, seed: int, variant: str = "hard"
) -> tuple[np.ndarray, Iterate]:
    """Return ``primal`` with its states moved by 1e-4 (seeded) and the warm start holding it.

    Only states move: the controls stay inside their box.
    """
    w = primal.copy()
    free = data.state_index.ravel()
    w[free] += 1e-4 * np.random.default_rng(seed).standard_normal(free.size)
    warm = Iterate(
        scaled_controls=w[data.control_index], states=w[data.state_index], primal=w, variant=variant
    )
    return w, warm


@pytest.fixture(scope="module")
def instance(problem):
    return ipopt_reference(problem, 3.0)


def gauss_newton_qp(data, w: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
    """Return the Gauss–Newton QP at ``w``: the Hessian 2 JᵣᵀJᵣ, the gradient, ∂g/∂w and g.

    Independent of the backends: Jacobians by CasADi AD of the NLP's own expressions.
    """
    nlp, residual = data.nlp, data.residual
    jr = ca.Function("jr", [nlp["x"], nlp["p"]], [ca.jacobian(residual, nlp["x"])])
    jg = ca.Function("jg", [nlp["x"], nlp["p"]], [ca.jacobian(nlp["g"], nlp["x"]), nlp["g"]])
    gf = ca.Function("gf", [nlp["x"], nlp["p"]], [ca.gradient(nlp["f"], nlp["x"])])
    jacobian_r = np.array(jr(w, p))
    a, g = (np.array(v) for v in jg(w, p))
    return 2 * jacobian_r.T @ jacobian_r, np.array(gf(w, p)).ravel(), a, g.ravel()


def test_registered_as_exact_backend():
    assert "sqp-rti" in uo.available_solvers()
    assert REGISTRY.kind("sqp-rti") == "exact"
    assert "igwo+sqp-rti" in uo.available_solvers()  # a hybrid's exact half like the others


@QP_PATHS
def test_iterated_rti_reaches_the_full_solvers_optimum(problem, instance, qpsol):
    """Gauss–Newton iterated to convergence from the cold guess = IPOPT's KKT point (1e-8)."""
    needs_compiler(qpsol)
    x0, reference = instance
    options = {
        "mode": "converged",
        "tol": 1e-12,
        "cold_start": "converged",
        "qpsol": qpsol,
        "qpsol_options": TIGHT[qpsol],
    }
    result = uo.solve(problem, "sqp-rti", x0=x0, t0=3.0, options=options)
    assert result.success and result.status.endswith("converged")
    assert result.iterations > 2  # it really iterated from the held-state guess
    np.testing.assert_allclose(
        result.iterate.scaled_controls, reference.iterate.scaled_controls, rtol=0, atol=1e-8
    )
    assert result.cost == pytest.approx(reference.cost, rel=1e-8)


@WITH_CONDENSING
def test_one_iteration_is_one_gauss_newton_step(problem, instance, qpsol):
    """One RTI call = the Gauss–Newton QP step, solved here by a dense KKT system in numpy."""
    needs_compiler(qpsol)
    x0, reference = instance
    backend = get_solver(problem, "sqp-rti", qp_options(qpsol, tight=True))
    data = problem.build().hard
    w, warm = perturbed_states(data, reference.iterate.primal, seed=3)
    p = problem.parameters(x0, 3.0)
    result = backend.solve(p, warm)
    assert result.success and result.iterations == 1
    hessian, gradient, a, g = gauss_newton_qp(data, w, p)
    # active set of the QP guessed from IPOPT's multipliers at the nearby optimum (casadi's
    # sign convention: lam > 0 at an upper bound); those rows become equalities at that bound
    lam_g, lam_x = reference.iterate.lam_g, reference.iterate.lam_x
    equality = data.lbg == data.ubg
    active_g = ~equality & (np.abs(lam_g) > 1e-6)
    active_x = np.abs(lam_x) > 1e-6
    bound_g = np.where(lam_g > 0, data.ubg, data.lbg)
    bound_x = np.where(lam_x > 0, data.ubx, data.lbx)
    rows = equality | active_g
    identity = np.eye(w.size)
    constraint = np.vstack([a[rows], identity[active_x]])
    target = np.concatenate(
        [np.where(equality, data.lbg, bound_g)[rows] - g.ravel()[rows], bound_x[active_x] - w[active_x]]
    )
    n, m = hessian.shape[0], constraint.shape[0]
    kkt = np.block([[hessian, constraint.T], [constraint, np.zeros((m, m))]])
    # lstsq: box and rate bounds active on one control make the active rows dependent (the
    # step is still unique: H is positive definite on their null space)
    solution = np.linalg.lstsq(kkt, np.concatenate([-gradient, target]), rcond=None)[0]
    step = solution[:n]
    # the rest of the QP's constraints strictly feasible: a KKT point of the convex QP
    linear = g.ravel() + a @ step
    inactive = ~rows
    assert np.all(linear[inactive] < data.ubg[inactive] - 1e-9)
    assert np.all(linear[inactive] > data.lbg[inactive] + 1e-9)
    free_x = ~active_x
    assert np.all((w + step)[free_x] < data.ubx[free_x]) and np.all((w + step)[free_x] > data.lbx[free_x])
    assert active_g.any()  # the instance has an active rate bound: a real inequality QP
    np.testing.assert_allclose(result.iterate.primal, w + step, rtol=0, atol=1e-8)
    # the QP's multipliers (NLP order, CasADi's signs) make its Lagrangian stationary
    stationarity = hessian @ step + gradient + a.T @ result.iterate.lam_g + result.iterate.lam_x
    assert np.max(np.abs(stationarity)) <= 1e-6 * max(1.0, np.max(np.abs(gradient)))
    lam_g = result.iterate.lam_g
    assert np.all(lam_g[~equality & (linear < data.ubg - 1e-7)] <= 1e-6)  # > 0 only at an upper side
    assert np.all(lam_g[~equality & (linear > data.lbg + 1e-7)] >= -1e-6)


@pytest.fixture(scope="module")
def calm_instance(problem):
    """Return a state on the path at t = 20 s and IPOPT's optimum there (no inequality active)."""
    return ipopt_reference(problem, 20.0)


@pytest.mark.parametrize("cond_horizon", [0, 5])
def test_equality_first_solves_an_inactive_qp_exactly(problem, calm_instance, cond_horizon):
    """Without an active inequality the C step's QP is solved by one Riccati recursion.

    Checked against the dense KKT system of the QP with its equalities alone (numpy), its
    inequalities strictly inside, the Lagrangian stationary with zero inequality multipliers,
    and HPIPM's solution of the same QP (``equality_first=False``) within HPIPM's tolerance.
    """
    needs_compiler("hpipm-ocp")
    x0, reference = calm_instance
    data = problem.build().hard
    w, warm = perturbed_states(data, reference.iterate.primal, seed=5)
    p = problem.parameters(x0, 20.0)
    results, qp_iterations = {}, {}
    for first in (True, False):
        settings = {"cond_horizon": cond_horizon, "equality_first": first}
        backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp", "qpsol_options": settings})
        results[first] = backend.solve(p, warm)
        assert results[first].success and results[first].iterations == 1
        qp_iterations[first] = backend.ocp_step("hard", results[first].details["still_water"]).info[4]
    assert qp_iterations[True] == 0 and qp_iterations[False] > 0  # the Riccati path / HPIPM's
    hessian, gradient, a, g = gauss_newton_qp(data, w, p)
    equality = data.lbg == data.ubg
    constraint = a[equality]
    n, m = hessian.shape[0], constraint.shape[0]
    kkt = np.block([[hessian, constraint.T], [constraint, np.zeros((m, m))]])
    step = np.linalg.solve(kkt, np.concatenate([-gradient, data.lbg[equality] - g[equality]]))[:n]
    linear = g + a @ step
    assert np.all(linear[~equality] < data.ubg[~equality]) and np.all(linear[~equality] > data.lbg[~equality])
    assert np.all(w + step < data.ubx) and np.all(w + step > data.lbx)
    result = results[True]
    np.testing.assert_allclose(result.iterate.primal, w + step, rtol=0, atol=1e-9)
    lam_g, lam_x = result.iterate.lam_g, result.iterate.lam_x
    stationarity = hessian @ step + gradient + a.T @ lam_g + lam_x
    assert np.max(np.abs(stationarity)) <= 1e-9 * max(1.0, np.max(np.abs(gradient)))
    assert np.all(lam_g[~equality] == 0.0) and np.all(lam_x == 0.0)
    np.testing.assert_allclose(result.iterate.primal, results[False].iterate.primal, rtol=0, atol=1e-6)
    scale = max(1.0, np.max(np.abs(lam_g)))
    np.testing.assert_allclose(lam_g, results[False].iterate.lam_g, rtol=0, atol=1e-5 * scale)


@pytest.mark.parametrize("cond_horizon", [0, 5])
def test_x0_elimination_solves_the_qp_with_x0_in_its_box(problem, instance, cond_horizon):
    """x_0 out of HPIPM's QP (``eliminate_x0``, the default) gives the former QP's step and multipliers.

    The former QP keeps x_0 as a variable fixed by the box lbx = ubx (``eliminate_x0=False``);
    on an instance with an active rate bound (HPIPM's path: ``equality_first=False``), tight
    tolerances, the two steps agree to 1e-9 (1e-8 condensed) and both, with their multipliers
    (x_0's box ones by stationarity in the eliminated QP), are KKT points of the independently
    built Gauss–Newton QP.
    """
    needs_compiler("hpipm-ocp")
    x0, reference = instance
    data = problem.build().hard
    w, warm = perturbed_states(data, reference.iterate.primal, seed=3)
    p = problem.parameters(x0, 3.0)
    results = {}
    for eliminate in (True, False):
        settings = {**TIGHT_OCP, "cond_horizon": cond_horizon, "equality_first": False}
        settings["eliminate_x0"] = eliminate
        backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp", "qpsol_options": settings})
        results[eliminate] = backend.solve(p, warm)
        assert results[eliminate].success and results[eliminate].iterations == 1
        assert backend.ocp_step("hard", results[eliminate].details["still_water"]).info[4] > 0  # HPIPM's
    eliminated, boxed = results[True].iterate, results[False].iterate
    # condensed, HPIPM's own accuracy at these tolerances is the limit (2.3e-9 apart, measured)
    np.testing.assert_allclose(eliminated.primal, boxed.primal, rtol=0, atol=1e-8 if cond_horizon else 1e-9)
    # the multipliers are not unique here (a control at its box and its rate bound: dependent
    # active rows), so each set is checked as a KKT point of the QP, x_0's rows included
    initial = np.array([key[0] == "initial" for key in data.constraint_keys])
    assert np.max(np.abs(eliminated.lam_g[initial])) > 1e-3  # x_0's multipliers carry weight
    for result in results.values():
        assert_qp_kkt(data, w, p, result, tolerance=1e-8)


def assert_qp_kkt(data, w: np.ndarray, p: np.ndarray, result, tolerance: float = 1e-9) -> None:
    """Assert that ``result``'s step and multipliers are a KKT point of the Gauss–Newton QP at ``w``.

    Primal feasibility, stationarity of the Lagrangian, the multipliers' signs and
    complementarity (CasADi's convention: λ > 0 only at an active upper bound, λ < 0 only at an
    active lower bound), all computed independently of the backend: a convex QP's solution.
    """
    hessian, gradient, a, g = gauss_newton_qp(data, w, p)
    step = result.iterate.primal - w
    lam_g, lam_x = result.iterate.lam_g, result.iterate.lam_x
    linear, point = g + a @ step, w + step
    scale = max(1.0, np.max(np.abs(gradient)))
    for value, lower, upper, lam in ((linear, data.lbg, data.ubg, lam_g), (point, data.lbx, data.ubx, lam_x)):
        assert np.all(value >= lower - tolerance) and np.all(value <= upper + tolerance)
        assert np.all(np.abs(value - upper)[lam > tolerance * scale] <= tolerance)
        assert np.all(np.abs(value - lower)[lam < -tolerance * scale] <= tolerance)
    stationarity = hessian @ step + gradient + a.T @ lam_g + lam_x
    assert np.max(np.abs(stationarity)) <= tolerance * scale


def test_equality_first_solves_the_exact_penalty_qp(problem, calm_instance):
    """The soft NLP's QP: the slacks held at zero, each pair of slack rows one equality.

    Its solution where the penalty is exact (|ν| ≤ μ on every terminal row) is a KKT point of
    the soft QP, checked independently; HPIPM's solution of it (``equality_first=False``) agrees.
    """
    needs_compiler("hpipm-ocp")
    x0, _ = calm_instance
    p = problem.parameters(x0, 20.0)
    soft = problem.build().soft_variant(problem.spec().terminal_penalty)
    results, qp_iterations = {}, {}
    for first in (True, False):
        settings = {"equality_first": first, "cond_horizon": 0}
        options = {"terminal_strategy": "soft", "qpsol": "hpipm-ocp", "qpsol_options": settings}
        backend = get_solver(problem, "sqp-rti", options)
        cold = backend.solve(p, None)  # IPOPT on the soft NLP: a KKT point to start from
        assert cold.success and cold.iterate.variant == "soft"
        w, warm = perturbed_states(soft, cold.iterate.primal, seed=7, variant="soft")
        results[first] = backend.solve(p, warm)
        assert results[first].success and results[first].iterate.variant == "soft"
        qp_iterations[first] = backend.ocp_step("soft", results[first].details["still_water"]).info[4]
        assert_qp_kkt(soft, w, p, results[first], tolerance=1e-9 if first else 1e-6)
    assert qp_iterations[True] == 0 and qp_iterations[False] > 0
    np.testing.assert_allclose(results[True].iterate.primal, results[False].iterate.primal, rtol=0, atol=1e-6)
    assert np.all(results[True].iterate.primal[soft.terminal_slack_index] == 0.0)  # held at zero


def test_equality_first_holds_the_slacks_of_a_softened_range():
    """A soft position tube: its slacks held at zero, its two rows inequalities (not a pair)."""
    needs_compiler("hpipm-ocp")
    tube = uo.TrackingProblem(
        uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1, position_tube=0.5
    )
    x0, reference = ipopt_reference(tube, 20.0)
    data, p = tube.build().hard, tube.parameters(x0, 20.0)
    w, warm = perturbed_states(data, reference.iterate.primal, seed=9)
    backend = get_solver(tube, "sqp-rti", {"qpsol": "hpipm-ocp", "qpsol_options": {"cond_horizon": 0}})
    result = backend.solve(p, warm)
    assert result.success
    assert backend.ocp_step("hard", result.details["still_water"]).info[4] == 0  # the Riccati path
    assert_qp_kkt(data, w, p, result)


@WITH_CONDENSING
def test_prepare_then_feedback_equals_step(problem, monkeypatch, qpsol):
    """The prepared linearisation with the measured state patched in = linearising there."""
    needs_compiler(qpsol)
    reference = problem.reference
    split = uo.NMPC(problem, "sqp-rti", options=qp_options(qpsol))
    # another backend instance (other options key, same values) that never prepares
    whole = uo.NMPC(problem, "sqp-rti", options={"slack_tolerance": 1e-7, **qp_options(qpsol)})
    assert whole.backend is not split.backend
    monkeypatch.setattr(whole.backend, "prepare", None)
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    state, control = reference.initial_state(0.0), np.zeros(3)
    rng = np.random.default_rng(0)
    # condensed: feedback condenses the right-hand side alone, the fresh step all of it; the
    # same numbers in another order (measured 6.5e-9 N of an 800 N control)
    atol = 1e-7 if qpsol == "hpipm-ocp-condensed" else 1e-9
    prepared_feedbacks = 0
    for k in range(6):
        split.prepare(k * problem.dt, control)
        prepared_feedbacks += split.backend._prepared is not None
        measured = state + 1e-3 * rng.standard_normal(6)  # not the predicted state
        a = split.feedback(measured)
        b = whole.step(measured, k * problem.dt, control)
        assert not a.fallback and not b.fallback
        np.testing.assert_allclose(a.control, b.control, rtol=0, atol=atol)
        control = a.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    assert prepared_feedbacks == 5  # every step but the cold first one used its preparation
    with pytest.raises(ValueError, match="prepare"):
        split.feedback(state)


@QP_PATHS
def test_closed_loop_holds_box_and_rate_bounds(problem, qpsol):
    needs_compiler(qpsol)
    controller = uo.NMPC(problem, "sqp-rti", options={"qpsol": qpsol})
    run = uo.simulate(controller, x0=problem.reference.initial_state(0.0), duration=3.0)
    assert run.failures == 0
    limit = problem.max_thrust
    assert np.all(np.abs(run.controls) <= limit * (1 + 1e-12))
    rates = np.diff(np.vstack([np.zeros(3), run.controls]), axis=0)
    assert np.all(np.abs(rates) <= problem.spec().max_rate * problem.dt * (1 + 1e-9))


@pytest.mark.parametrize(
    ("options", "name"),
    [
        ({"mode": "fast"}, "options['mode']"),
        ({"iterations": 0}, "options['iterations']"),
        ({"tol": -1.0}, "options['tol']"),
        ({"qpsol": "nope"}, "options['qpsol']"),
        ({"qpsol_options": 3}, "options['qpsol_options']"),
        ({"cold_start": "warm"}, "options['cold_start']"),
        ({"qp_tolerance": 0.0}, "options['qp_tolerance']"),
        ({"plugin_options": {"a": 1}}, "options['plugin_options']"),
        ({"banana": 1}, "banana"),
        (
            {"qpsol": "hpipm-ocp", "qpsol_options": {"res_g_max": 1e-8}},
            "options['qpsol_options']['res_g_max']",
        ),
        ({"qpsol": "hpipm-ocp", "qpsol_options": {"mode": "fast"}}, "options['qpsol_options']['mode']"),
        ({"qpsol": "hpipm-ocp", "qpsol_options": {"iter_max": 0}}, "options['qpsol_options']['iter_max']"),
        ({"qpsol": "hpipm-ocp", "qpsol_options": {"tol_eq": -1.0}}, "options['qpsol_options']['tol_eq']"),
        ({"qpsol": "hpipm-ocp", "qpsol_options": {"tol_eq": math.inf}}, "options['qpsol_options']['tol_eq']"),
        (
            {"qpsol": "hpipm-ocp", "qpsol_options": {"cond_horizon": -1}},
            "options['qpsol_options']['cond_horizon']",
        ),
        (
            {"qpsol": "hpipm-ocp", "qpsol_options": {"warm_start": 1}},
            "options['qpsol_options']['warm_start']",
        ),
        (
            {"qpsol": "hpipm-ocp", "mode": "converged", "qpsol_options": {"loose_first_qp": "yes"}},
            "options['qpsol_options']['loose_first_qp']",
        ),
        (
            {"qpsol": "hpipm-ocp", "qpsol_options": {"equality_first": 0}},
            "options['qpsol_options']['equality_first']",
        ),
        (
            {"qpsol": "hpipm-ocp", "qpsol_options": {"eliminate_x0": 1}},
            "options['qpsol_options']['eliminate_x0']",
        ),
    ],
)
def test_bad_options_are_named(problem, options, name):
    with pytest.raises(ValueError, match=name.replace("[", r"\[").replace("]", r"\]")):
        get_solver(problem, "sqp-rti", options)


@QP_PATHS
def test_failed_qp_takes_the_nmpc_fallback(problem, monkeypatch, qpsol):
    """A QP that never succeeds (and no IPOPT rescue) fails softly: the loop goes on."""
    needs_compiler(qpsol)
    options = {"cold_start": "rti", "qpsol": qpsol}
    controller = uo.NMPC(problem, "sqp-rti", options=options)
    backend = controller.backend
    monkeypatch.setattr(backend, "robust_options", lambda: {})
    monkeypatch.setattr(backend, "qp_tolerance", 1e-300)  # no QP solution passes the test
    output = controller.step(problem.reference.initial_state(0.0), 0.0)
    assert output.fallback and "infeasible" in output.message
    # no plan yet: the steady control (NMPC's fallback), one rate step from the zero start
    assert output.fallback_source == "steady control"
    spec = problem.spec()
    assert np.all(np.abs(output.control) <= spec.max_rate * spec.dt * (1 + 1e-12))


def test_interrupt_inside_the_qp_propagates(problem, monkeypatch):
    controller = uo.NMPC(problem, "sqp-rti", options={"cold_start": "rti"})
    backend = controller.backend

    class Interrupting:
        def __call__(self, *args):
            raise RuntimeError("Error in Function::call: KeyboardInterrupt")

    monkeypatch.setattr(backend, "qp_step", lambda variant: Interrupting())
    with pytest.raises(KeyboardInterrupt):
        controller.step(problem.reference.initial_state(0.0), 0.0)


def test_interrupt_inside_the_c_step_propagates(problem, monkeypatch):
    needs_compiler("hpipm-ocp")
    controller = uo.NMPC(problem, "sqp-rti", options={"cold_start": "rti", "qpsol": "hpipm-ocp"})
    backend = controller.backend
    step = backend.ocp_step("hard", True)
    assert step is not None

    def interrupted(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(step, "iterate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        controller.step(problem.reference.initial_state(0.0), 0.0)


def test_sigint_during_c_steps_reaches_the_caller(problem):
    """A real Ctrl-C while the loop runs in the C step: raised at the next bytecode, not lost."""
    needs_compiler("hpipm-ocp")
    controller = uo.NMPC(problem, "sqp-rti", options={"cold_start": "rti", "qpsol": "hpipm-ocp"})
    x = problem.reference.initial_state(0.0)
    controller.step(x, 0.0)  # built outside the interrupted loop
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    steps = 0
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            for _ in range(100_000):
                controller.step(x, 0.0)
                steps += 1
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert 0 < steps < 100_000


def test_hpipm_ocp_without_compiler_warns_and_keeps_casadis_path(problem, monkeypatch, instance):
    x0, reference = instance
    monkeypatch.setenv("CC", "/nonexistent/cc")
    backend = RtiSolver(problem, {"qpsol": "hpipm-ocp"})  # a new instance: nothing built yet
    with pytest.warns(RuntimeWarning, match="hpipm-ocp' unavailable"):
        result = backend.solve(problem.parameters(x0, 3.0), reference.iterate)
    assert result.success and backend.qpsol == "hpipm" and result.iterations == 1


def test_soft_terminal_qp_in_c_equals_casadis(problem, instance):
    """The exact-penalty NLP (terminal slacks as stage N−1 inputs, one-sided boxes masked)."""
    needs_compiler("hpipm-ocp")
    x0, _ = instance
    # 4 m off the path: the terminal equality cannot be met within the horizon's 2 s
    p = problem.parameters(x0 + np.array([4.0, -4.0, 0.0, 0.0, 0.0, 0.0]), 3.0)
    results = []
    for qpsol in ("hpipm", "hpipm-ocp"):
        backend = get_solver(
            problem,
            "sqp-rti",
            {
                "terminal_strategy": "soft",
                "cold_start": "rti",
                "qpsol": qpsol,
                "qpsol_options": TIGHT[qpsol],
            },
        )
        results.append(backend.solve(p, None))
    a, b = results
    assert a.success and b.success and a.iterate.variant == b.iterate.variant == "soft"
    slacks = problem.build().soft_variant(problem.spec().terminal_penalty).terminal_slack_index
    assert np.max(a.iterate.primal[slacks]) > 1e-3  # the relaxation is active: the L1 term matters
    np.testing.assert_allclose(b.iterate.primal, a.iterate.primal, rtol=0, atol=1e-8)


#: s2 at t0 (s), the state and the last control (N, N, N m) of the 35th instance of the generated
#: ``nmpc_step``'s verification (``codegen.check_nmpc_step``, seed 0): on its cold exact-penalty QP
#: HPIPM in ``speed`` mode stopped at its 50 iterations (status max_iter) with the wheel's BLASFEO,
#: 1.2e-4 of the yaw moment's range off the QP's solution (min_step and 3.8e-5 with the native one)
STALLING_QP = (
    34.462682885875914,
    [
        17.24312474641494,
        -1.9246098258941204,
        -0.08061197718395235,
        0.4898463481028088,
        -0.07125450716216322,
        0.9804150132088314,
    ],
    [-726.9131713982279, -374.80870579765747, 302.28498569569206],
)


def exact_qp_step(data, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Return the step of the Gauss–Newton QP at ``w`` by qpOASES (an active-set solver: exact).

    Independent of HPIPM and of the C step's stage mapping: the dense QP of :func:`gauss_newton_qp`.
    """
    hessian, gradient, a, g = gauss_newton_qp(data, w, p)
    n, m = a.shape[1], a.shape[0]
    solver = ca.conic(
        "exact",
        "qpoases",
        {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity.dense(m, n)},
        {"printLevel": "none"},
    )
    solution = solver(
        h=hessian, g=gradient, a=a, lbx=data.lbx - w, ubx=data.ubx - w, lba=data.lbg - g, uba=data.ubg - g
    )
    assert solver.stats()["success"]
    return np.array(solution["x"]).ravel()


@pytest.mark.parametrize("library", ["wheel", "native"])
def test_a_qp_hpipm_does_not_solve_is_rescued_in_robust_mode(problem, monkeypatch, library):
    """A QP that HPIPM's ``speed`` mode does not solve is solved again in ``robust`` mode.

    Its last ``speed`` iterate was taken as the QP's solution: the generated ``nmpc_step`` then
    failed its verification against CasADi's conic HPIPM (robust mode) on this instance with
    the wheel's HPIPM, and passed with a native build, which the suite's native HPIPM test
    installs into the shared cache after the codegen test has run.  Both libraries now give
    the QP's solution, checked against qpOASES on the dense QP.
    """
    from uuv_ocp.judge import instance_parameters
    from uuv_ocp.native import hpipm
    from uuv_ocp.solvers.rti import nmpc_step_function

    needs_compiler("hpipm-ocp")
    if library == "native" and hpipm.installed() is None:
        pytest.skip("no native HPIPM built (uuv-ocp hpipm build)")
    monkeypatch.setenv(hpipm.HPIPM_ENV, library)  # read when the C step is built, at its first solve
    t0, x0, u_prev = (np.asarray(v, dtype=float) for v in STALLING_QP)
    _, backend = nmpc_step_function(problem)  # a new backend: the verification's, built now
    p = instance_parameters(problem, x0, float(t0), u_prev=u_prev)
    result = backend.solve(p, None)
    assert result.success and result.iterate.variant == "soft"
    info = backend.ocp_step("soft", False).info
    assert info[9] == 1 and info[5] == 0  # speed mode failed, the robust solve succeeded
    data = backend.variants["soft"]
    states, controls = problem.initial_guess(p)
    w = backend.compose_primal("soft", states, controls, problem.previous_scaled(p))
    exact = w + exact_qp_step(data, w, p)
    spec = problem.spec()
    expected = spec.physical(exact[np.asarray(data.control_index[0], dtype=int)])
    # measured 1.4e-10 of the range (the unrescued speed iterate: 1.2e-4, 3.8e-5 native)
    error = np.abs(result.controls[0] - expected) / (spec.upper - spec.lower)
    assert np.max(error) <= 1e-8


def test_automatic_qp_path(problem, monkeypatch):
    """``qpsol="auto"``: the C step with a compiler, CasADi's path under UUV_OCP_COMPILED=0."""
    monkeypatch.setenv("UUV_OCP_COMPILED", "0")
    assert RtiSolver(problem).qpsol == "hpipm"
    monkeypatch.setenv("UUV_OCP_COMPILED", "1")
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        assert RtiSolver(problem).qpsol == "hpipm"
    monkeypatch.delenv("CC")
    needs_compiler("hpipm-ocp")
    assert RtiSolver(problem).qpsol == "hpipm-ocp"
    # options written for CasADi's conic interface keep that path instead of failing
    conic = RtiSolver(problem, {"qpsol_options": {"hpipm": {"res_g_max": 1e-9}}})
    assert conic.qpsol == "hpipm" and conic.qpsol_options == {"hpipm": {"res_g_max": 1e-9}}
    assert RtiSolver(problem, {"qpsol_options": {"mode": "speed_abs"}}).qpsol == "hpipm-ocp"
    with pytest.raises(ValueError, match="qpsol_options"):
        RtiSolver(problem, {"qpsol": "hpipm-ocp", "qpsol_options": {"hpipm": {}}})


def test_c_step_options_without_the_c_step_are_checked_then_left_out(problem, instance, monkeypatch):
    """``qpsol="auto"`` where the C step is not built: its options warn and do not reach CasADi."""
    monkeypatch.setenv("UUV_OCP_COMPILED", "0")
    with pytest.raises(ValueError, match=r"options\['qpsol_options'\]\['iter_max'\]"):
        RtiSolver(problem, {"qpsol_options": {"iter_max": 0}})
    options = {"mode": "converged", "qpsol_options": {"loose_first_qp": False}, "slack_tolerance": 4e-7}
    with pytest.warns(RuntimeWarning, match="options of the C step"):
        backend = RtiSolver(problem, options)
    assert backend.qpsol == "hpipm" and backend.qpsol_options == HPIPM_DEFAULTS
    x0, reference = instance
    result = backend.solve(problem.parameters(x0, 3.0), reference.iterate)  # a warm, conic solve
    assert result.success and result.status.endswith("converged")


def test_numpy_integers_are_accepted_where_ints_are():
    """``iter_max`` and ``cond_horizon`` from numpy arrays (np.int64) are ints, stored as Python ints."""
    merged = ocp_qp_options(
        {"iter_max": np.int64(30), "cond_horizon": np.int32(4), "tol_stat": np.float64(1e-7)}, False
    )
    assert merged["iter_max"] == 30 and type(merged["iter_max"]) is int
    assert merged["cond_horizon"] == 4 and type(merged["cond_horizon"]) is int


def test_partial_condensing_auto_is_a_quarter_of_the_horizon_from_eight_stages():
    assert ocp_qp_options({}, False, 20)["cond_horizon"] == 5
    assert ocp_qp_options({}, True, 9)["cond_horizon"] == 2
    assert ocp_qp_options({}, False, 7)["cond_horizon"] == 0  # short horizons: not condensed
    assert ocp_qp_options({"cond_horizon": 0}, False, 20)["cond_horizon"] == 0
    with pytest.raises(ValueError, match="must be 'auto' or an int >= 0"):
        ocp_qp_options({"cond_horizon": "half"}, False, 20)


def test_the_c_step_is_judged_by_a_compiled_twin_of_the_judge(problem, instance):
    """With the C step the judge runs compiled; its cost and violation are the VM judge's."""
    needs_compiler("hpipm-ocp")
    x0, _ = instance
    backend = RtiSolver(problem, {"qpsol": "hpipm-ocp", "cold_start": "rti"})
    result = backend.solve(problem.parameters(x0, 3.0), None)
    assert backend.judge_terms is not None and backend.judge_terms.function.class_name() == "External"
    cost, violation = uo.score(problem, result.controls, x0, 3.0)  # CasADi's VM
    assert result.cost == pytest.approx(cost, rel=1e-12)
    assert result.max_violation == pytest.approx(violation, rel=1e-12, abs=1e-15)


def test_the_fast_feedback_gives_what_solve_gives(problem, monkeypatch):
    """``feedback`` straight from the C call = the same step through ``solve``'s bookkeeping.

    Two controllers on the same closed loop (measured states off the prediction), one with the
    fast path switched off: every control, cost, status and iterate equal, bit for bit.
    """
    needs_compiler("hpipm-ocp")
    reference = problem.reference
    fast = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    slow = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp", "slack_tolerance": 1e-7})
    calls = []
    original = fast.backend._feedback_in_c

    def counted(*args):
        result = original(*args)
        calls.append(result is not None)
        return result

    monkeypatch.setattr(fast.backend, "_feedback_in_c", counted)
    monkeypatch.setattr(slow.backend, "_feedback_in_c", lambda *a: None)
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    state, control = reference.initial_state(0.0), np.zeros(3)
    rng = np.random.default_rng(5)
    for k in range(12):
        measured = state + 1e-3 * rng.standard_normal(6)
        a = general_step(fast, measured, k * problem.dt, control, np.zeros(2))
        b = general_step(slow, measured, k * problem.dt, control, np.zeros(2))
        assert np.array_equal(a.control, b.control) and a.fallback == b.fallback
        ra, rb = a.result, b.result
        for name in ("cost", "max_violation", "status", "success"):
            assert getattr(ra, name) == getattr(rb, name), (k, name)
        assert ra.details["attempts"] == rb.details["attempts"]
        for name in ("primal", "lam_g", "lam_x"):
            assert np.array_equal(getattr(ra.iterate, name), getattr(rb.iterate, name)), (k, name)
        control = a.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    # every step but the cold first (nothing prepared: solve) took the fast path
    assert calls == [True] * 11


def test_a_failing_preparation_costs_speed_not_the_step(problem, monkeypatch):
    """A preparation that raises is dropped: the feedback solves afresh, as without one."""
    reference = problem.reference
    broken = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm", "cold_start": "rti"})
    plain = uo.NMPC(
        problem, "sqp-rti", options={"qpsol": "hpipm", "cold_start": "rti", "slack_tolerance": 1e-7}
    )

    def fails(*args):
        raise RuntimeError("uuv_rti_prepare: the linearisation failed")

    monkeypatch.setattr(broken.backend, "prepare", fails)
    monkeypatch.setattr(plain.backend, "prepare", None)  # never prepares
    state, control = reference.initial_state(0.0), np.zeros(3)
    for k in range(3):  # the two phases (step prepares nothing ahead: no time between them)
        a = general_step(broken, state, k * problem.dt, control)
        b = general_step(plain, state, k * problem.dt, control)
        assert not a.fallback and np.array_equal(a.control, b.control)
        control = a.control

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(broken.backend, "prepare", interrupted)
    with pytest.raises(KeyboardInterrupt):
        general_step(broken, state, 3 * problem.dt, control)


@pytest.mark.parametrize("mode", ["rti", "converged"])
def test_resident_steps_of_controllers_sharing_a_backend_equal_step(problem, mode):
    """Two controllers on one backend (one C step, one resident warm start) alternate in one thread.

    Each must give the controls and warm starts ``NMPC.step`` gives on its own measurements (a
    third controller on a backend of its own): the resident warm start is re-seeded whenever
    the other controller seeded it since.  A changed shift or a missing owner check fails it.
    """
    needs_compiler("hpipm-ocp")
    options = {"qpsol": "hpipm-ocp", "mode": mode}
    first, second = uo.NMPC(problem, "sqp-rti", options=options), uo.NMPC(problem, "sqp-rti", options=options)
    second.backend = first.backend  # shared on purpose (a controller owns its own otherwise)
    separate = {**options, "slack_tolerance": 1e-7}  # another options dict: another backend
    references = [uo.NMPC(problem, "sqp-rti", options=separate) for _ in range(2)]
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    rng = np.random.default_rng(17)
    # near the reference, 5 cm apart: both stay on the hard NLP, so they share one C step
    start = problem.reference.evaluate([1.0])[0]
    states = [start, start + np.array([0.05, -0.05, 0.0, 0.0, 0.0, 0.0])]
    controls = [np.zeros(3), np.zeros(3)]
    resident = 0
    for k in range(10):
        t = 1.0 + k * problem.dt
        for i, (lean, full) in enumerate(zip((first, second), references, strict=True)):
            measured = states[i] + 1e-3 * rng.standard_normal(6)
            control = lean.step(measured, t, controls[i], np.zeros(2))
            expected = general_step(full, measured, t, controls[i], np.zeros(2))
            assert lean._deferred is None or lean._deferred.variant == "hard"
            assert np.array_equal(control.control, expected.control), (k, i)
            assert np.array_equal(lean.plan, expected.result.controls), (k, i)
            assert np.array_equal(lean.iterate.primal, full.iterate.primal), (k, i)
            resident += control.fast_path == "resident C step"
            control = control.control
            controls[i] = control
            states[i] = np.array(plant(states[i], control, np.zeros(2))).ravel()
    # rti: all but the two cold first steps; converged: a step from near rest that does not
    # converge within max_iter goes through the general path (the same result, as checked)
    assert resident == 18 if mode == "rti" else resident >= 8


def test_resident_steps_of_an_ocp_with_a_path_constraint_equal_step():
    """``step`` on a user ``Ocp``: parameters, a non-convex path constraint, a soft bound.

    The resident C step must give the controls and plans of ``prepare`` + ``feedback`` bit for
    bit (on a backend of its own), and must run: every warm step is resident.
    """
    needs_compiler("hpipm-ocp")
    ocp = uo.Ocp(horizon=20, dt=0.2)
    pos, vel = ocp.state("pos", 2), ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    goal, ref = ocp.parameter("goal", 2), ocp.parameter("ref", 2, stagewise=True)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(ca.sumsqr(pos - ref) + 0.1 * ca.sumsqr(acc))
    ocp.add_terminal_cost(10 * ca.sumsqr(pos - goal))
    ocp.subject_to(ca.sumsqr(pos - ca.DM([2.0, 0.1])) >= 0.36)
    ocp.subject_to(vel <= 1.5, soft=1e3)
    line = np.linspace(0.0, 4.0, ocp.horizon + 1)
    data = {"goal": [4.0, 0.0], "ref": np.column_stack([line, np.zeros_like(line)])}
    lean = uo.NMPC(ocp, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    full = uo.NMPC(ocp, "sqp-rti", options={"qpsol": "hpipm-ocp", "slack_tolerance": 1e-7})
    state, control, resident = np.zeros(4), np.zeros(2), 0
    for k in range(12):
        record = lean.step(state, 0.0, control, parameters=data)
        expected = general_step(full, state, 0.0, control, parameters=data)
        assert np.array_equal(record.control, expected.control), k
        assert np.array_equal(lean.plan, expected.result.controls), k
        resident += record.fast_path == "resident C step"
        control = record.control
        # the double integrator held at `control` for one interval, exactly
        state = np.concatenate([state[:2] + 0.2 * state[2:] + 0.02 * control, state[2:] + 0.2 * control])
    assert resident == 11  # all but the cold first step


def test_resident_steps_refuse_bad_input_before_the_c_call(problem):
    """A bad state, time or last control on a warm resident step: ``ValueError`` naming it.

    Raised before the C step runs (its resident warm start is untouched): the next good step
    equals a controller's that never saw the bad input.
    """
    needs_compiler("hpipm-ocp")
    options = {"qpsol": "hpipm-ocp", "slack_tolerance": 3e-7}
    probed, clean = uo.NMPC(problem, "sqp-rti", options=options), uo.NMPC(problem, "sqp-rti", options=options)
    x = problem.reference.initial_state(0.0)
    for controller in (probed, clean):
        for k in range(3):  # cold, seeding, resident
            controller.step(x, k * problem.dt, np.zeros(3), np.zeros(2))
    assert probed._deferred is not None
    bad_state = x.copy()
    bad_state[0] = np.nan
    for call, name in (
        (lambda c: c.step(bad_state, 0.3, np.zeros(3)), "x0"),
        (lambda c: c.step(x, math.inf, np.zeros(3)), "t0"),
        (lambda c: c.step(x, 0.3, np.full(3, 1e9)), "u_prev"),
    ):
        with pytest.raises(ValueError, match=name):
            call(probed)
    a = probed.step(x, 0.3, np.zeros(3), np.zeros(2))
    b = clean.step(x, 0.3, np.zeros(3), np.zeros(2))
    assert np.array_equal(a.control, b.control) and a.fast_path == "resident C step"


def test_resident_seed_checks_its_sizes(problem):
    """``OcpQpStep.seed`` refuses vectors of the wrong size, naming the sizes expected."""
    needs_compiler("hpipm-ocp")
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp"})
    step = backend.ocp_step("hard")
    assert step is not None
    with pytest.raises(ValueError, match="seed needs w and lam_x of size"):
        step.seed(np.zeros(3), np.zeros(3), np.zeros(3), None)


def test_converged_mode_solves_only_its_first_qp_loosely(problem, instance):
    """``loose_first_qp``: a converged call's first QP has the rti mode's HPIPM settings.

    Two steps equal an rti-mode step then a tight one, bit for bit (tight throughout gives
    another point); a loose step never ends the iteration, however small, and none is taken
    where one step may be all there is; the converged point is the one of tight QPs
    throughout, to the step tolerance.
    """
    needs_compiler("hpipm-ocp")
    x0, reference = instance
    p = problem.parameters(x0, 3.0)
    data = problem.build().hard
    w = perturbed_states(data, reference.iterate.primal, seed=5)[0]
    steps = {}
    for name, options in {
        "rti": {},
        "loose": {"mode": "converged"},
        "tight": {"mode": "converged", "qpsol_options": {"loose_first_qp": False}},
    }.items():
        backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp", **options})
        steps[name] = backend.ocp_step("hard", backend._uses_still_water(p))
    lam_x, lam_g = np.zeros(data.lbx.size), np.zeros(data.lbg.size)

    def run(name, start, max_iter, tol=1e-10, budget=math.inf):
        return steps[name].iterate(start, p, lam_x, lam_g, False, max_iter, tol, 1e-6, budget)

    # two steps: an rti step, then a tight one from where it went (a GN QP ignores the duals)
    two = {name: run(name, w, 2) for name in ("loose", "tight")}
    assert two["loose"][3][3] == STOP_MAX_ITER
    by_hand = run("tight", run("rti", w, 1)[0], 1)[0]
    np.testing.assert_array_equal(two["loose"][0], by_hand)
    assert np.max(np.abs(two["tight"][0] - by_hand)) > 1e-12
    converged = {name: run(name, w, 50) for name in ("loose", "tight")}
    for name, (_, _, _, info) in converged.items():
        assert info[3] == STOP_CONVERGED, name
    np.testing.assert_allclose(converged["loose"][0], converged["tight"][0], rtol=0, atol=1e-9)
    # from the converged point the first step is tiny (QP noise: ~1e-8 in degenerate
    # directions, hence tol=1e-6): a tight one ends the iteration, a loose one cannot
    optimum = converged["tight"][0]
    assert run("tight", optimum, 50, tol=1e-6)[3][0] == 1
    again = run("loose", optimum, 50, tol=1e-6)[3]
    assert again[3] == STOP_CONVERGED and again[0] == 2
    # where one step may be all there is (max_iter=1, a deadline's budget) every QP is tight
    for limits in ({"max_iter": 1}, {"max_iter": 50, "budget": 1e-9}):
        single = run("loose", optimum, tol=1e-6, **limits)[3]
        assert single[3] == STOP_CONVERGED and single[0] == 1, limits


def general_step(controller: uo.NMPC, x, t, u_prev, current=None, parameters=None):
    """``NMPC.prepare`` then ``NMPC.feedback``: the step by the general path (no resident step)."""
    controller.prepare(t, u_prev, current, parameters)
    return controller.feedback(x)


def test_step_takes_the_resident_c_step_with_the_general_path_s_numbers(problem, monkeypatch):
    """``NMPC.step`` takes the resident C step by itself; its numbers are the general path's.

    ``step`` on s2 with the C step: every warm step is the resident one (``fast_path``), and
    its control, plan, warm start and (lazily built) result equal, bit for bit, those of
    ``prepare`` + ``feedback`` on a controller whose backend has no fast path (every step
    through ``solve``'s bookkeeping).  The deprecated ``step_control`` warns and gives the same
    control by the same path.  A failed step goes through ``solve`` and the same fallback.
    """
    needs_compiler("hpipm-ocp")
    reference = problem.reference
    stepper = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    full = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp", "slack_tolerance": 1e-7})
    lean = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp", "slack_tolerance": 2e-7})
    monkeypatch.setattr(full.backend, "_feedback_in_c", lambda *a: None)  # no prepared C step
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    state, control = reference.initial_state(0.0), np.zeros(3)
    rng = np.random.default_rng(9)
    paths = []
    for k in range(12):
        measured = state + 1e-3 * rng.standard_normal(6)
        c = stepper.step(measured, k * problem.dt, control, np.zeros(2))
        b = general_step(full, measured, k * problem.dt, control, np.zeros(2))
        with pytest.warns(DeprecationWarning, match=r"NMPC\.step\(x, t, \.\.\.\)\.control"):
            a = lean.step_control(measured, k * problem.dt, control, np.zeros(2))
        paths.append(c.fast_path)
        if c.fast_path:
            # the plan's arrays: views of one copy, not of the C step's buffers (the next call
            # writes those), found finite by one pass; the definition: each array's isfinite
            plan = stepper._deferred
            arrays = (plan.primal, plan.lam_x, plan.lam_g, plan.info, plan.control)
            assert plan.all_finite == all(np.isfinite(a).all() for a in arrays)
            assert plan.all_finite and finite_warm_start(plan) and plan.finite_control()
            step_memory = stepper.backend._ocp_steps[(plan.variant, plan.still_water)].outputs
            assert not any(np.shares_memory(a, step_memory) for a in arrays)
            spoiled = dataclasses.replace(plan, lam_g=np.r_[plan.lam_g[:-1], np.nan], all_finite=False)
            assert not finite_warm_start(spoiled) and spoiled.finite_control()
        assert b.fast_path == "" and (lean.last_output is None) == (c.fast_path != "")
        assert np.array_equal(c.control, b.control) and c.fallback == b.fallback, k
        assert np.array_equal(a, b.control), k
        assert np.array_equal(stepper.plan, b.result.controls)
        assert np.array_equal(c.result.controls, b.result.controls)
        assert np.array_equal(c.result.states, b.result.states)
        for field in ("cost", "max_violation", "success", "status", "iterations", "terminal_relaxed"):
            assert getattr(c.result, field) == getattr(b.result, field), (k, field)
        assert c.result.details["attempts"] == b.result.details["attempts"]
        for name in ("primal", "lam_g", "lam_x"):
            assert np.array_equal(getattr(stepper.iterate, name), getattr(full.iterate, name)), (k, name)
        control = c.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()
    assert paths == [""] + ["resident C step"] * 11  # all but the cold first step
    # a failed step: solve()'s fallback chain, then the controller's fallback
    for controller in (stepper, full):
        controller.backend.qp_tolerance = 1e-300
        controller.backend.robust_options = lambda: {}
        controller.backend.cold_start = "rti"  # no IPOPT for the cold retry either
    c = stepper.step(state, 12 * problem.dt, control, np.zeros(2))
    b = general_step(full, state, 12 * problem.dt, control, np.zeros(2))
    assert c.fallback and b.fallback and c.fast_path == ""
    assert np.array_equal(c.control, b.control) and c.message == b.message


def test_a_nan_in_the_qp_fails_the_success_test(problem, instance):
    """A QP whose step comes back NaN is a failed step, not one with violation 0.

    C's ``fmax`` (CasADi's ``fmax`` and ``mmax``) skips NaN, so a maximum alone passed a NaN
    step as feasible.  Reference: numpy's ``isfinite`` on the step HPIPM returned.
    """
    x0, reference = instance
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm"})
    data = problem.build().hard
    p = problem.parameters(x0, 3.0)
    h, grad, a, g = (
        np.array(v, dtype=float).ravel() for v in backend.linearisation("hard")(reference.iterate.primal, p)
    )
    step = backend.qp_step("hard")
    args = (reference.iterate.primal, data.lbx, data.ubx, data.lbg, data.ubg)
    d, _, _, violation = (np.array(v, dtype=float).ravel() for v in step(h, grad, a, g, *args))
    assert np.all(np.isfinite(d)) and violation[0] <= 1e-6  # the healthy QP passes
    # a NaN in the constraint Jacobian, as the linearisation at a diverged iterate gave (a NaN
    # bound of the QP is refused by CasADi before HPIPM runs)
    a[0] = np.nan
    d, _, _, violation = (np.array(v, dtype=float).ravel() for v in step(h, grad, a, g, *args))
    assert not np.all(np.isfinite(d))  # HPIPM did return a NaN step ...
    assert violation[0] == math.inf  # ... and the test refuses it


def test_a_non_finite_warm_start_restarts_cold(problem, instance):
    """A warm start with a NaN is dropped: ``solve`` from it is ``solve`` without one."""
    x0, reference = instance
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm"})
    p = problem.parameters(x0, 3.0)
    primal = reference.iterate.primal.copy()
    primal[-1] = np.nan
    data = problem.build().hard
    poisoned = Iterate(
        scaled_controls=primal[data.control_index], states=primal[data.state_index], primal=primal
    )
    assert not poisoned.is_finite() and reference.iterate.is_finite()
    cold, from_nan = backend.solve(p, None), backend.solve(p, poisoned)
    assert cold.success and from_nan.success
    assert from_nan.status == cold.status and from_nan.iterations == cold.iterations
    np.testing.assert_array_equal(from_nan.iterate.primal, cold.iterate.primal)
    assert backend.prepare(p, poisoned) is None  # nothing is linearised at it either


def test_a_nan_qp_step_in_the_loop_recovers_at_once(problem, monkeypatch):
    """One linearisation turned NaN mid-loop: that step restarts cold, the next are RTI again.

    What happened on the REMUS 100 with CasADi's HPIPM (a step from a diverged iterate): the
    NaN step passed as a success, the NMPC refused its controls and shifted its old warm start
    on, so every later step linearised at the same point, NaN again.  Reference for the
    recovered step: IPOPT's optimum of the same instance.
    """
    controller = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm"})
    backend = controller.backend
    original = backend.linearisation
    poisoned_calls = []

    class NanOnce:
        """The linearisation with a NaN in ``∂g/∂w`` on the call chosen below."""

        def __init__(self, function):
            self.function = function

        def __call__(self, *args):
            h, grad, a, g = (np.array(v, dtype=float) for v in self.function(*args))
            if poisoned_calls == [False]:
                a.ravel()[0] = np.nan
                poisoned_calls[0] = True
            return h, grad, a, g

    monkeypatch.setattr(backend, "linearisation", lambda *a: NanOnce(original(*a)))
    plant = uo.rk4_step(problem.vehicle.dynamics_function(), problem.dt, 10)
    reference = problem.reference
    state, control = reference.initial_state(0.0), np.zeros(3)
    for k in range(8):
        if k == 4:
            poisoned_calls.append(False)  # the RTI step of step 4 linearises to NaN
        record = controller.step(state, k * problem.dt, control)
        assert not record.fallback, (k, record.message)
        assert np.all(np.isfinite(record.control))
        attempts = [a.label for a in record.result.details["attempts"]]
        if k == 4:
            assert poisoned_calls == [True]
            # the NaN QP failed the RTI attempt (violation inf); the chain's IPOPT took the step
            first = record.result.details["attempts"][0]
            assert first.status == "QP solution infeasible (linearised violation inf > 1e-06)"
            assert len(attempts) > 1
            expected = uo.solve(problem, "ipopt", x0=state, t0=k * problem.dt, u_prev=control)
            assert record.result.details["attempts"][-1].status == "Solve_Succeeded"
            # the judge's cost of the soft NLP's plan (the sticky strategy's) against IPOPT's
            # on the hard NLP: measured 0.2 % above it
            assert expected.cost <= record.result.cost <= 1.01 * expected.cost
        elif k > 0:
            assert len(attempts) == 1, (k, attempts)  # one RTI step, no fallback chain
        assert controller.iterate is not None and controller.iterate.is_finite()
        control = record.control
        state = np.array(plant(state, control, np.zeros(2))).ravel()


def _path_constrained_ocp() -> uo.Ocp:
    """Return a double integrator with a stagewise reference, a non-convex path constraint, a soft bound."""
    ocp = uo.Ocp(horizon=12, dt=0.2)
    pos, vel = ocp.state("pos", 2), ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    ref = ocp.parameter("ref", 2, stagewise=True)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(ca.sumsqr(pos - ref) + 0.1 * ca.sumsqr(acc))
    ocp.subject_to(ca.sumsqr(pos - ca.DM([2.0, 0.1])) >= 0.36)
    ocp.subject_to(vel <= 1.5, soft=1e3)
    return ocp


@pytest.mark.parametrize("case", ["s2", "bluerov2", "path"])
def test_stage_data_called_per_stage_equal_the_horizon_function(case):
    """The stage data through one mapped function per distinct stage equal the unrolled horizon's.

    Reference: the horizon-wide SX function (``per_stage=False``, the former path) at random
    points, every variant, with and without the still-water substitution; bit for bit (the
    same operations), and the middle stages generated once (one ``map`` of N − 2 or N − 3).
    """
    from uuv_ocp.solvers.rti_ocp import ocp_qp_layout, stage_data_function

    if case == "s2":
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)
    elif case == "bluerov2":
        survey = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=2, speed=0.3, depth=2.0)
        problem = uo.TrackingProblem(uo.Vehicle6DOF.bluerov2_heavy(), survey, horizon=8, dt=0.1)
    else:
        problem = _path_constrained_ocp()
    rng = np.random.default_rng(29)
    # the soft terminal strategy's exact-penalty variant has structurally zero blocks (slacks)
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp", "terminal_strategy": "soft"})
    still_water = backend._still_water_slice  # noqa: SLF001 (the slice the backend substitutes)
    for name, data in backend.variants.items():
        layout = ocp_qp_layout(data, problem.spec().state_dim)
        for still in (None, still_water) if still_water is not None else (None,):
            horizon, offsets = stage_data_function(data, layout, 1.7, still, "h", per_stage=False)
            staged, staged_offsets = stage_data_function(data, layout, 1.7, still, "s")
            assert np.array_equal(offsets, staged_offsets)
            # dense, as the C step reads the blocks by offset (a structural zero would shift them)
            assert staged.nnz_out(0) == staged.numel_out(0) == horizon.nnz_out(0)
            for _ in range(2):
                w, p = rng.uniform(-1, 1, horizon.size1_in(0)), rng.uniform(-1, 1, horizon.size1_in(1))
                assert np.array_equal(np.array(horizon(w, p)), np.array(staged(w, p))), (name, still)
            maps = [f.name() for f in staged.find_functions() if f.name().startswith("map")]
            assert len(maps) == 1 and int(maps[0][3:].split("_")[0]) >= layout.horizon - 3, maps


def test_equality_first_auto_follows_the_cost_model(monkeypatch):
    """``equality_first="auto"``: on for s2 (N = 20 and 80), off for the BlueROV2 survey with native HPIPM.

    The flop estimate is checked against the closed form for constant stage sizes (N stages of
    nx lifted states, nu inputs; ne terminal equality rows), written out here; the decision
    needs no build (the linked HPIPM is patched).
    """
    import uuv_ocp.solvers.rti_ocp as rti_ocp

    def closed_form(n, nx, nu, ne):
        factor = nx**3 + nx * nx * nu + nu * nx * nx + nu * nu * nx / 2 + nx**3 / 2
        factor += nu**3 / 6 + nu * nu * nx / 2 + nx * nx * nu / 2
        solve = 2 * (nx * nu + nx * nx + nx * nu) + nu * nu
        return n * factor + (ne + 2) * n * solve

    survey = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=2, speed=0.3, depth=2.0)
    # s2 also at N = 80: the decision must not flip with the horizon (a bound on the total
    # flops, which grow with N, turned it off there: a step in the cost against N)
    s2 = uo.Reference.paper("s2")
    rexrov = uo.Vehicle.rexrov()
    cases = {("s2", n): (uo.TrackingProblem(rexrov, s2, horizon=n, dt=0.1), 9, 3, 6) for n in (20, 80)}
    cases["bluerov2", 20] = (
        uo.TrackingProblem(uo.Vehicle6DOF.bluerov2_heavy(), survey, horizon=20, dt=0.1),
        18,
        6,
        12,
    )
    decided = {}
    for (name, n), (problem, nx, nu, ne) in cases.items():
        backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp"})
        for variant, data in backend.variants.items():
            layout = rti_ocp.ocp_qp_layout(data, problem.spec().state_dim)
            if variant == "hard":  # constant stage sizes (the soft NLP's slacks sit at stage N - 1)
                expected = closed_form(n, nx, nu, ne)
                assert rti_ocp.equality_first_flops(layout, data) == pytest.approx(expected)
            for linked in ("native", "wheel"):
                native = linked == "native"
                monkeypatch.setattr(rti_ocp, "selected_hpipm", lambda native=native: native or None)
                options = rti_ocp.ocp_qp_options({}, False, n)
                resolved = rti_ocp.resolve_equality_first(options, layout, data)
                decided[name, n, variant, linked] = resolved["equality_first"]
                forced = rti_ocp.resolve_equality_first({**options, "equality_first": False}, layout, data)
                assert forced["equality_first"] is False
    assert decided == {
        (name, n, variant, linked): not (name == "bluerov2" and linked == "native")
        for name, n in cases
        for variant in ("hard", "soft")
        for linked in ("native", "wheel")
    }


@pytest.mark.parametrize("case", ["remus-path", "s2"])
def test_stage_data_from_the_rk4_sensitivity_equal_casadis_jacobian(case):
    """Stage data and CasADi-path linearisation from ``rk4_sensitivity`` equal AD's.

    Reference: the same stage data with ``casadi.jacobian`` of the whole constraint vector
    (``sensitivity=False``, the former path), every variant, at random points; to rounding
    (the operations differ in order).  The REMUS 100 path following (lifted rate controls, the
    path parameter, the path-end slacks, the path window's parameters) and the RexROV on s2.
    """
    from uuv_ocp.solvers.rti import qp_functions
    from uuv_ocp.solvers.rti_ocp import constraint_jacobian, ocp_qp_layout, stage_data_function

    problem: uo.TrackingProblem | uo.PathFollowingProblem
    if case == "s2":
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4, dt=0.1)
    else:
        path = uo.Reference.lawnmower((0.0, 0.0), width=150.0, spacing=60.0, lanes=2, speed=1.5, depth=10.0)
        problem = uo.PathFollowingProblem(uo.Remus100(), path, speed=1.5, horizon=3, dt=0.5)
    rng = np.random.default_rng(28)
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp", "terminal_strategy": "soft"})
    for name, data in backend.variants.items():
        assert data.shooting and data.rk4 is not None
        w, p = data.nlp["x"], data.nlp["p"]
        mine = ca.Function("mine", [w, p], [ca.densify(constraint_jacobian(data))])
        theirs = ca.Function("theirs", [w, p], [ca.densify(ca.jacobian(data.nlp["g"], w))])
        layout = ocp_qp_layout(data, problem.spec().state_dim)
        new, _ = stage_data_function(data, layout, 1.7, None, "new")
        old, _ = stage_data_function(data, layout, 1.7, None, "old", sensitivity=False)
        for _ in range(2):
            w0 = rng.uniform(-1, 1, w.numel())
            p0 = rng.uniform(-1, 1, p.numel())
            if case == "remus-path":  # a REMUS under way: the surge and the propeller of cruise
                w0[data.state_index[:, 6]] += 1.5
            a, b = np.array(mine(w0, p0)), np.array(theirs(w0, p0))
            np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-11 * np.abs(b).max(), err_msg=name)
            a, b = np.array(new(w0, p0)), np.array(old(w0, p0))
            np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-11 * np.abs(b).max(), err_msg=name)
            # CasADi's QP path (qpsol="hpipm") linearises with the same Jacobian
            (mine_qp, _, mine_a), (theirs_qp, _, theirs_a) = (
                qp_functions(data, None, 1.7, "lin", sensitivity=flag) for flag in (True, False)
            )
            a = np.array(ca.DM(mine_a, mine_qp(w0, p0)[2]))
            b = np.array(ca.DM(theirs_a, theirs_qp(w0, p0)[2]))
            np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-11 * np.abs(b).max(), err_msg=name)


def _poison(step, w: np.ndarray, p: np.ndarray) -> None:
    """Run the raw C iteration (no Python guard) from a diverged point ``w * 1e30``.

    What a closed loop whose estimate diverged fed the C step: HPIPM's workspace then held
    NaN, and every later QP of that memory came out non-finite.
    """
    step.w[:] = w * 1e30
    step.p[:] = p
    step.lam_x[:] = 0.0
    step.lam_g[:] = 0.0
    a = step._pointers
    step._iterate(step.memory, a[0], a[1], 0, 1, 1e-8, 1e-6, math.inf, a[2], a[3], a[4])
    assert not math.isfinite(step.info[1])  # the diverged QP itself is refused (violation inf)


def test_a_diverged_qp_does_not_poison_the_later_c_steps(problem, instance):
    """After a QP at a diverged point, the C step's next QP equals the one it gave before.

    Before the fix every later QP of that memory was non-finite (violation inf): the benchmark's
    shared controller fell back to IPOPT at every step of every later run.  Reference: the
    same step's output before the diverged call, bit for bit.
    """
    needs_compiler("hpipm-ocp")
    x0, reference = instance
    backend = get_solver(problem, "sqp-rti", {"qpsol": "hpipm-ocp"})
    p = problem.parameters(x0, 3.0)
    step = backend.ocp_step("hard", backend._uses_still_water(p))
    assert step is not None
    w = reference.iterate.primal
    zeros_x, zeros_g = np.zeros(step.lam_x.size), np.zeros(step.lam_g.size)
    before = step.iterate(w, p, zeros_x, zeros_g, False, 1, 1e-8, 1e-6, math.inf)
    assert math.isfinite(before[3][1])
    diverged = step.iterate(w * 1e30, p, zeros_x, zeros_g, False, 1, 1e-8, 1e-6, math.inf)
    assert not math.isfinite(diverged[3][1])  # refused ...
    after = step.iterate(w, p, zeros_x, zeros_g, False, 1, 1e-8, 1e-6, math.inf)
    for got, expected in zip(after[:3], before[:3], strict=True):  # ... and forgotten
        np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(after[3][:6], before[3][:6])  # the timings (6-8) differ


def test_reset_after_a_poisoned_c_step_gives_a_fresh_controller_s_steps(problem):
    """``NMPC.reset`` resets the backend: the next steps equal a new controller's, bit for bit.

    The C memory is poisoned by the raw C call (as a diverged run left it before the guard of
    the test above); without the backend's reset hook every later step failed its QP.
    """
    needs_compiler("hpipm-ocp")
    used = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    fresh = uo.NMPC(problem, "sqp-rti", options={"qpsol": "hpipm-ocp"})
    x = problem.reference.initial_state(0.0)

    def steps(controller: uo.NMPC) -> list:
        records, control = [], np.zeros(3)
        for k in range(4):
            record = controller.step(x, k * problem.dt, control)
            records.append(record)
            control = record.control
        return records

    steps(used)
    backend = used.backend
    p = problem.parameters(x, 0.0)
    assert backend._ocp_steps  # the hard and the soft NLP's C steps
    for (variant, _), step in backend._ocp_steps.items():
        _poison(step, backend._initial_point(variant, p, None)[0], p)
    used.reset()
    for got, expected in zip(steps(used), steps(fresh), strict=True):
        assert not got.fallback, got.message
        np.testing.assert_array_equal(got.control, expected.control)
        assert got.fast_path == expected.fast_path
        np.testing.assert_array_equal(got.result.iterate.primal, expected.result.iterate.primal)
