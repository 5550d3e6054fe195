"""The closed loop's view of a problem (control/scenario.py): one loop for every kind."""

from __future__ import annotations

import inspect

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import uuv_ocp as uo
from uuv_ocp.control.scenario import scenario


def pendulum_ocp() -> uo.Ocp:
    """Return a torque-controlled damped pendulum whose damping is a global parameter."""
    ocp = uo.Ocp(horizon=10, dt=0.1)
    angle = ocp.state("angle")
    rate = ocp.state("rate")
    torque = ocp.control("torque", lower=-2.0, upper=2.0)
    damping = ocp.parameter("damping")
    ocp.set_der(angle, rate)
    ocp.set_der(rate, -ca.sin(angle) - damping * rate + torque)
    ocp.add_stage_cost(angle**2 + 0.1 * torque**2)
    return ocp


def test_every_problem_shares_one_instance_signature():
    # the judge and simulate call problem.instance_parameters without asking the kind
    ocp_signature = inspect.signature(uo.Ocp.instance_parameters)
    tracking_signature = inspect.signature(uo.TrackingProblem.instance_parameters)
    assert ocp_signature.parameters.keys() == tracking_signature.parameters.keys()
    ocp = pendulum_ocp()
    x0 = np.array([0.3, 0.0])
    assert np.array_equal(
        uo.judge.instance_parameters(ocp, x0, parameters={"damping": 0.5}),
        ocp.parameters(x0, {"damping": 0.5}),
    )
    with pytest.raises(ValueError, match="t0 is a TrackingProblem argument"):
        ocp.instance_parameters(x0, 1.0, parameters={"damping": 0.5})


def test_an_ocp_plant_is_its_own_dynamics_at_the_given_parameters():
    # checked against scipy's adaptive integrator on the same ODE written in numpy
    ocp = pendulum_ocp()
    run = scenario(
        ocp, t0=None, duration=1.0, plant=None, parameters={"damping": 0.5}, current=None, substeps=10
    )
    assert (run.t0, run.steps, run.current_dim, run.time_varying) == (0.0, 10, 0, False)
    assert run.state_names == ("angle", "rate")
    x0, torque = np.array([0.3, -0.1]), 0.7
    path = np.array(run.plant_step(x0, [torque], np.zeros(0)))

    def pendulum(_t: float, x: np.ndarray) -> list[float]:
        return [x[1], -np.sin(x[0]) - 0.5 * x[1] + torque]

    exact = solve_ivp(pendulum, (0.0, 0.1), x0, t_eval=0.01 * np.arange(1, 11), rtol=1e-12, atol=1e-12)
    assert path == pytest.approx(exact.y, abs=1e-9)
    assert np.all(np.isnan(run.reference(np.zeros(3))))


def test_a_closed_loop_on_an_ocp_records_its_state_names():
    run = uo.simulate(uo.NMPC(pendulum_ocp(), "ipopt"), [0.3, 0.0], duration=0.5, parameters={"damping": 0.5})
    assert run.state_names == ("angle", "rate") and run.states.shape == (6, 2)


def test_an_unknown_kind_of_problem_is_refused_by_name():
    with pytest.raises(ValueError, match=r"controller.problem must be an Ocp or a TrackingProblem.*dict"):
        scenario({}, t0=None, duration=1.0, plant=None, parameters=None, current=None, substeps=1)
