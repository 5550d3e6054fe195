"""MPPI (solvers/mppi.py) against analytic references: LQR, Gaussian posterior, bounds, seeds."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import new_solver
from uuv_ocp.solvers.mppi import MppiOptions

DT, HORIZON = 0.1, 6
Q = np.array([4.0, 1.0])  # weights of pos², vel² (stage and terminal)
R = 0.5  # weight of acc²
BOUND = 2.0  # |acc| <= 2 m/s²: never active at the optimum from X0 (max |u*| = 0.43)
X0 = np.array([1.0, -0.5])


def double_integrator(max_rate: float | None = None) -> uo.Ocp:
    """1-D double integrator, quadratic cost; RK4 is exact on it (A² = 0)."""
    ocp = uo.Ocp(horizon=HORIZON, dt=DT)
    pos, vel = ocp.state("pos"), ocp.state("vel")
    acc = ocp.control("acc", lower=-BOUND, upper=BOUND, max_rate=max_rate)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(pos, vel), weight=Q)
    ocp.add_stage_cost(residual=acc, weight=[R])
    ocp.add_terminal_cost(residual=ca.vertcat(pos, vel), weight=Q)
    return ocp


def discrete_model() -> tuple[np.ndarray, np.ndarray]:
    a = np.array([[1.0, DT], [0.0, 1.0]])
    b = np.array([[DT**2 / 2], [DT]])
    return a, b


def riccati_controls(x0: np.ndarray) -> np.ndarray:
    """Finite-horizon LQR by the backward Riccati recursion, written in numpy."""
    a, b = discrete_model()
    p, gains = np.diag(Q), []
    for _ in range(HORIZON):
        k = np.linalg.solve(R + b.T @ p @ b, b.T @ p @ a)
        p = np.diag(Q) + a.T @ p @ (a - b @ k)
        gains.append(k)
    x, controls = x0.copy(), []
    for k in reversed(gains):
        u = -k @ x
        controls.append(u)
        x = a @ x + b @ u
    return np.array(controls)


def condensed_quadratic(x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hessian H and minimiser u* of J(u) = Σ x_kᵀQx_k + R u_k² + x_NᵀQx_N (dense, numpy)."""
    a, b = discrete_model()
    n = HORIZON
    phi = np.vstack([np.linalg.matrix_power(a, k) for k in range(n + 1)])  # (2(n+1), 2)
    gamma = np.zeros((2 * (n + 1), n))
    for k in range(1, n + 1):
        for j in range(k):
            gamma[2 * k : 2 * k + 2, j] = (np.linalg.matrix_power(a, k - 1 - j) @ b).ravel()
    q_bar = np.kron(np.eye(n + 1), np.diag(Q))
    hessian = 2.0 * (R * np.eye(n) + gamma.T @ q_bar @ gamma)
    gradient = 2.0 * gamma.T @ q_bar @ phi @ x0
    return hessian, -np.linalg.solve(hessian, gradient)


def test_the_condensed_reference_is_the_riccati_lqr():
    """The two references of this file agree (so each checks the other's algebra)."""
    _, optimum = condensed_quadratic(X0)
    np.testing.assert_allclose(optimum, riccati_controls(X0).ravel(), rtol=1e-10, atol=1e-12)


def test_iterated_updates_tend_to_the_lqr_control():
    """λ → 0 with many samples: the MPPI mean reaches the LQR optimum (tolerance 1 % of max |u*|).

    Measured (seed 0): 0.66 % with 4096 samples, λ = 1e-4, σ = 0.02, 20 iterations; with
    64 samples and λ = 0.1 the error is several times larger, which the second assertion holds.
    """
    lqr = riccati_controls(X0)
    ocp = double_integrator()
    fine = {"samples": 4096, "iterations": 20, "temperature": 1e-4, "noise": 0.02, "smoothing": 0.0}
    fine["keep_best"] = False
    result = uo.solve(ocp, "mppi", x0=X0, options=fine)
    error = np.max(np.abs(result.controls - lqr)) / np.max(np.abs(lqr))
    assert result.success and result.details["returned"] == "mean"
    assert error <= 1e-2
    coarse = {**fine, "samples": 64, "temperature": 0.1}
    rough = uo.solve(ocp, "mppi", x0=X0, options=coarse)
    assert np.max(np.abs(rough.controls - lqr)) / np.max(np.abs(lqr)) > 2 * error


@pytest.mark.parametrize("smoothing", [0.0, 0.6])
def test_one_update_is_the_mean_of_the_gaussian_posterior(smoothing):
    """On a quadratic J, E[w(ε) (W̄ + ε)] = (H/λ + C⁻¹)⁻¹ (H W*/λ + C⁻¹ W̄): Gaussian algebra.

    W are the scaled controls u / BOUND (no rate bound), so H_W = BOUND² H_u.  C is the
    prior covariance of ε over the horizon: σ² β^|i−j| for the stationary AR(1) noise of
    ``smoothing`` β (σ² I for β = 0).  λ is chosen so that the posterior is about as wide as
    the prior (many effective samples); the tolerance is a few Monte-Carlo standard errors of
    the weighted mean (σ_post / sqrt(ESS) ≈ 3e-4).
    """
    hessian, optimum = condensed_quadratic(X0)
    h_w, w_star = BOUND**2 * hessian, optimum / BOUND
    sigma, temperature = 0.05, 0.05
    nominal = np.zeros(HORIZON)  # the cold start holds u_prev = 0
    lags = np.abs(np.subtract.outer(np.arange(HORIZON), np.arange(HORIZON)))
    prior = np.linalg.inv(sigma**2 * smoothing**lags)
    precision = h_w / temperature + prior
    expected = np.linalg.solve(precision, h_w @ w_star / temperature + prior @ nominal)
    ocp = double_integrator()
    options = {"samples": 65536, "iterations": 1, "temperature": temperature, "noise": sigma}
    options["smoothing"] = smoothing
    result = uo.solve(ocp, "mppi", x0=X0, options={**options, "keep_best": False})
    got = result.controls.ravel() / BOUND
    assert np.max(np.abs(got - nominal)) > 0.03  # the update moved (not a trivial match)
    np.testing.assert_allclose(got, expected, atol=1e-3)  # measured: 3e-4 (seed 0)


def decode_in_numpy(coordinates: np.ndarray, previous: float, rate: float) -> np.ndarray:
    """Scaled controls from search coordinates, written independently: z_k at (w+1)/2 of its window."""
    plan = []
    for w in coordinates:
        low, high = max(-1.0, previous - rate), min(1.0, previous + rate)
        previous = low + (w + 1.0) / 2.0 * (high - low)
        plan.append(previous)
    return np.array(plan)


def test_every_sample_and_the_result_hold_box_and_rate_bounds():
    """Wide noise (σ = 3 in W) so clipping is active on most samples; every one is checked."""
    max_rate = 1.5  # m/s³: |Δacc| <= 0.15 m/s² per step, i.e. 0.075 in scaled units
    ocp = double_integrator(max_rate)
    solver = new_solver(ocp, "mppi", {"samples": 64, "iterations": 4, "noise": 3.0, "smoothing": 0.5})
    seen: list[np.ndarray] = []
    evaluate = solver._evaluate

    def spy(candidates, p):
        seen.append(candidates.copy())
        return evaluate(candidates, p)

    solver._evaluate = spy
    u_prev = 1.9  # close to the box: the box and the rate window both bind
    p = ocp.parameters(X0, u_prev=[u_prev])
    result = solver.solve(p)
    rate = max_rate * DT / BOUND
    samples = np.vstack(seen)
    assert samples.shape == (4 * 64, HORIZON)
    clipped = np.mean(np.abs(samples) == 1.0)
    assert clipped > 0.3  # the clip was exercised
    for w in samples:
        z = decode_in_numpy(w, u_prev / BOUND, rate)
        steps = np.diff(np.r_[u_prev / BOUND, z])
        assert np.all(np.abs(z) <= 1.0 + 1e-15) and np.all(np.abs(steps) <= rate * (1 + 1e-12))
    controls = result.controls.ravel()
    steps = np.diff(np.r_[u_prev, controls])
    assert np.all(np.abs(controls) <= BOUND * (1 + 1e-15))
    assert np.max(np.abs(steps)) <= max_rate * DT * (1 + 1e-12)
    assert result.details["violations"]["rate"] == 0.0 and result.details["violations"]["bound"] == 0.0


def test_same_seed_same_plan_different_seed_different_plan():
    ocp = double_integrator()
    options = {"samples": 32, "iterations": 2}
    first = uo.solve(ocp, "mppi", x0=X0, options={**options, "seed": 3})
    again = uo.solve(ocp, "mppi", x0=X0, options={**options, "seed": 3})
    other = uo.solve(ocp, "mppi", x0=X0, options={**options, "seed": 4})
    np.testing.assert_array_equal(first.controls, again.controls)
    assert np.max(np.abs(first.controls - other.controls)) > 1e-6
    solver = new_solver(ocp, "mppi", options)
    p = ocp.parameters(X0)
    by_generator = solver.solve(p, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(by_generator.controls, first.controls)  # the seed is default_rng(seed)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("samples", 1),
        ("iterations", 0),
        ("temperature", 0.0),
        ("temperature", -1.0),
        ("noise", -0.1),
        ("noise", [0.1, 0.0]),
        ("noise", [[1.0, 2.0], [2.0, 1.0]]),  # symmetric, not positive definite
        ("smoothing", 1.0),
        ("seed", -1),
        ("deadline", 0.0),
        ("compiled", "yes"),
    ],
)
def test_bad_options_raise_naming_the_parameter(name, value):
    with pytest.raises(ValueError, match=rf"options\['{name}'\] of 'mppi'"):
        new_solver(double_integrator(), "mppi", {name: value})
    with pytest.raises(ValueError, match=rf"MppiOptions\.{name}"):
        MppiOptions(**{name: value})


def test_noise_of_the_wrong_size_for_the_problem_is_refused():
    with pytest.raises(ValueError, match=r"options\['noise'\] of 'mppi' must have one std per control \(1\)"):
        new_solver(double_integrator(), "mppi", {"noise": [0.1, 0.2]})


def test_mppi_warm_starts_an_exact_solver_and_runs_a_closed_loop():
    """``"mppi+fatrop"`` reaches the exact optimum; NMPC with MPPI holds the rate bound."""
    ocp = double_integrator(max_rate=4.0)
    optimum = uo.solve(ocp, "fatrop", x0=X0)
    hybrid = uo.solve(ocp, "mppi+fatrop", x0=X0)
    assert hybrid.solver == "mppi+fatrop" and hybrid.cost == pytest.approx(optimum.cost, rel=1e-7)
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    plant = ca.Function("plant", [x, u], [ca.vertcat(x[1], u)])
    run = uo.simulate(uo.NMPC(ocp, "mppi", seed=1), X0, duration=2.0, plant=plant)
    assert run.failures == 0
    assert np.max(np.abs(np.diff(np.r_[0.0, run.controls[:, 0]]))) <= 4.0 * DT * (1 + 1e-12)
    assert abs(run.states[-1, 0]) < abs(X0[0])  # it regulates toward the origin


def test_candidates_are_distinct_samples_and_feed_a_hybrid():
    """``candidates=k``: the returned plan first, then samples farther than the distance in W.

    W of each plan is recomputed here from the plan by inverting the decode (u_prev = 0, no
    rate bound: W are the scaled controls), independently of the package's encode.
    """
    ocp = double_integrator()
    options = {"samples": 64, "iterations": 3, "candidates": 4, "candidate_metric": "controls"}
    options["candidate_distance"] = 0.05
    result = uo.solve(ocp, "mppi", x0=X0, options=options)
    plans = result.details["candidates"]
    assert len(plans) == 4
    np.testing.assert_allclose(plans[0], result.iterate.scaled_controls)
    for i in range(4):
        for j in range(i):
            assert np.sqrt(np.mean((plans[i] - plans[j]) ** 2)) > 0.05
    hybrid = uo.solve(ocp, "mppi+fatrop", x0=X0, options={"candidates": 3, "swarm": {"samples": 64}})
    rows = hybrid.details["candidates"]
    assert [row["start"] for row in rows] == ["swarm 0", "warm start", "swarm 1"]
    assert hybrid.cost == pytest.approx(min(row["cost"] for row in rows if row["success"]), rel=1e-12)


def test_a_deadline_stops_between_iterations_with_a_plan_holding_the_bounds():
    ocp = double_integrator(max_rate=1.5)
    solver = new_solver(ocp, "mppi", {"samples": 64, "iterations": 1000})
    result = solver.solve(ocp.parameters(X0), time_limit=1e-3)
    assert result.details["deadline_hit"] and result.status.startswith("deadline: 0.001 s reached after")
    assert 1 <= result.iterations < 1000 and result.evaluations == result.iterations * 64 + 1
    steps = np.diff(np.r_[0.0, result.controls.ravel()])
    assert np.max(np.abs(steps)) <= 1.5 * DT * (1 + 1e-12)
    full = solver.solve(ocp.parameters(X0), time_limit=None)
    assert not full.details["deadline_hit"] and full.iterations == 1000
