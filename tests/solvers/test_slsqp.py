"""The SLSQP backend (uuv_ocp.solvers.slsqp): an exact backend over scipy, not CasADi's nlpsol.

Shown by name in ``uo.solve``, in a hybrid and in an NMPC loop, against IPOPT's optimum; its
``success`` is vouched for by the judge; options it does not honour are refused.
"""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.judge import FEASIBILITY_TOLERANCE


def double_integrator() -> uo.Ocp:
    """Drive a unit mass to 1 under |a| <= 1 and a rate bound: active bounds, known by IPOPT."""
    ocp = uo.Ocp(horizon=8, dt=0.2)
    pos = ocp.state("pos")
    vel = ocp.state("vel")
    acc = ocp.control("acc", lower=-1.0, upper=1.0, max_rate=4.0)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(pos - 1.0, 0.3 * acc))
    ocp.add_terminal_cost(residual=3 * (pos - 1.0))
    ocp.subject_to(vel <= 0.6)  # a path constraint that binds on the way
    return ocp


@pytest.fixture(scope="module")
def tiny():
    """RexROV on s2, N = 5, with the terminal equality."""
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5)


def test_slsqp_by_name_reaches_ipopts_optimum_on_an_ocp():
    ocp = double_integrator()
    assert "slsqp" in uo.available_solvers() and uo.solvers.REGISTRY.kind("slsqp") == "exact"
    reference = uo.solve(ocp, "ipopt", x0=[0.0, 0.0])
    result = uo.solve(ocp, "slsqp", x0=[0.0, 0.0])
    assert reference.success and result.success, result.status
    assert result.solver == "slsqp" and result.max_violation <= FEASIBILITY_TOLERANCE
    assert result.cost == pytest.approx(reference.cost, rel=1e-6)
    np.testing.assert_allclose(result.controls, reference.controls, atol=1e-3)


def test_slsqp_falls_back_to_the_soft_nlp_like_ipopt(tiny):
    x0 = tiny.reference.initial_state(0.0)  # at rest: the terminal equality is unreachable
    reference = uo.solve(tiny, "ipopt", x0=x0, t0=0.0)
    result = uo.solve(tiny, "slsqp", x0=x0, t0=0.0)
    assert result.success and result.terminal_relaxed and reference.terminal_relaxed
    assert [label for label, _, _ in result.details["attempts"]][:2] == ["hard", "soft"]
    assert result.cost == pytest.approx(reference.cost, rel=1e-6)


def test_slsqp_as_the_exact_half_of_a_hybrid():
    ocp = double_integrator()
    assert "igwo+slsqp" in uo.available_solvers()
    reference = uo.solve(ocp, "ipopt", x0=[0.0, 0.0])
    hybrid = uo.solve(ocp, "igwo+slsqp", x0=[0.0, 0.0], options={"swarm": {"seed": 1}})
    assert hybrid.solver == "igwo+slsqp" and hybrid.success, hybrid.status
    assert hybrid.cost == pytest.approx(reference.cost, rel=1e-6)
    assert "swarm_fitness" in hybrid.details
    timed = uo.solve(ocp, "igwo+slsqp", x0=[0.0, 0.0], options={"deadline": 30.0})
    assert timed.success and timed.details["deadline_hit"] is False


def test_slsqp_in_nmpc_gives_ipopts_closed_loop(tiny):
    x0 = tiny.reference.initial_state(0.0) + np.array([0.1, -0.1, 0.02, 0.0, 0.0, 0.0])
    runs = {name: uo.simulate(uo.NMPC(tiny, name), x0=x0, duration=0.4) for name in ("ipopt", "slsqp")}
    assert runs["slsqp"].failures == 0 and runs["ipopt"].failures == 0
    max_thrust = np.asarray(tiny.vehicle.max_thrust)
    np.testing.assert_allclose(
        runs["slsqp"].controls / max_thrust, runs["ipopt"].controls / max_thrust, atol=1e-3
    )


def test_slsqp_success_is_vouched_for_by_the_judge(tiny):
    """With a huge ``tol`` SLSQP declares success at once; the judge finds the plan infeasible."""
    ref = uo.Reference.paper("s2")
    x0 = ref.evaluate([3.0])[0] + np.array([0.05, -0.04, 0.02, 0.03, 0.01, -0.01])
    loose = uo.solve(tiny, "slsqp", x0=x0, t0=3.0, options={"tol": 1e6, "terminal_strategy": "hard-first"})
    first_status = loose.details["attempts"][0][1]
    assert first_status.startswith("Optimization terminated successfully")  # scipy's own word
    assert "judge finds the plan infeasible" in first_status
    # the soft NLP stops as early, its slacks short of the terminal residual: no relaxed plan either
    assert [label for label, _, _ in loose.details["attempts"]][:2] == ["hard", "soft"]
    assert not loose.success and loose.max_violation > FEASIBILITY_TOLERANCE


def test_slsqp_refuses_options_it_does_not_honour(tiny):
    for name in ("compiled", "plugin_options"):
        with pytest.raises(ValueError, match=rf"unknown options for solver 'slsqp': \['{name}'\]"):
            uo.get_solver(tiny, "slsqp", {name: False if name == "compiled" else {}})
    with pytest.raises(ValueError, match=r"options\['tol'\] of 'slsqp'"):
        uo.get_solver(tiny, "slsqp", {"tol": -1.0})


def test_slsqp_stops_at_the_deadline(tiny, monkeypatch):
    """A fake clock that jumps past the deadline at the first SLSQP iteration stops the attempt."""
    from uuv_ocp.solvers import watchdog

    now = [0.0]
    monkeypatch.setattr(watchdog, "now", lambda: now[0])
    backend = uo.new_solver(tiny, "slsqp", {"deadline": 1.0})
    objective = backend._oracle("hard", True).objective

    def late(w):
        now[0] += 10.0  # each evaluation "takes" 10 s
        return objective(w)

    backend._oracles[("hard", True)].objective = late
    p = uo.judge.instance_parameters(tiny, tiny.reference.initial_state(3.0), 3.0)
    result = backend.solve(p)
    assert not result.success and result.details["deadline_hit"] is True
    ((_, status, iterations),) = result.details["attempts"]
    assert status.startswith("stopped by the deadline") and iterations <= 1


def test_a_used_slsqp_solver_gives_a_fresh_ones_answer(tiny):
    """Its constraint cache is keyed on the instance too: no values of the previous p."""
    x0 = tiny.initial_state()
    p1 = tiny.parameters(x0, 0.0)
    p2 = tiny.parameters(x0 + np.array([0.2, -0.1, 0.05, 0.0, 0.0, 0.0]), 0.0)
    used = uo.new_solver(tiny, "slsqp")
    first = used.solve(p1)
    again = used.solve(p2, first.iterate)  # starts where the p1 solve stopped
    fresh = uo.new_solver(tiny, "slsqp").solve(p2, first.iterate)
    np.testing.assert_array_equal(again.controls, fresh.controls)
    assert again.iterations == fresh.iterations
