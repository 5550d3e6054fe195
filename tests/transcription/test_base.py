"""The transcription strategy (transcription/base.py): a user's own one, in this one file.

The implicit trapezoidal rule (Crank–Nicolson) as a new transcription: one interval variable
``E`` (the end state) with the row ``E − x − h/2 (f(x, u) + f(E, u)) = 0``, and the condensed
step the same row solved by Newton.  Registered by name, it is taken by the Ocp, every exact
backend of the registry, the judge and a swarm; on a linear system the step is the (1, 1) Padé
approximant of the exponential, so the LQR's optimum is the discrete Riccati solution of those
matrices (an independent reference).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.transcription.test_collocation import (
    DT,
    EXACT,
    HORIZON,
    TIGHT,
    A,
    B,
    augmented,
    pade_matrix,
    riccati,
)
from uuv_ocp.transcription.base import Transcription, register_transcription, transcription_names


class Trapezoidal:
    """Implicit trapezoidal rule: second order, A-stable."""

    name = "trapezoidal"
    variable_kind = "E"
    row_kind = "trapezoid"

    def check_degree(self, degree, substeps):
        if degree is not None or substeps != 1:
            raise ValueError("the trapezoidal rule takes no degree and one substep")
        return 0

    def _residual(self, spec):
        end, x = ca.SX.sym("E", spec.state_dim), ca.SX.sym("x", spec.state_dim)
        u = ca.SX.sym("u", spec.control_size)
        ps, pg = ca.SX.sym("ps", spec.stage_dim), ca.SX.sym("pg", spec.global_dim)
        f = spec.dynamics
        row = end - x - spec.dt / 2 * (f(x, u, ps, pg) + f(end, u, ps, pg))
        return ca.Function("trapezoid", [end, x, u, ps, pg], [row])

    def step(self, spec):
        newton = ca.rootfinder("trapezoid_newton", "fast_newton", self._residual(spec), {"abstol": 1e-14})
        x, u = ca.SX.sym("x", spec.state_dim), ca.SX.sym("u", spec.control_size)
        ps, pg = ca.SX.sym("ps", spec.stage_dim), ca.SX.sym("pg", spec.global_dim)
        return ca.Function("model_step", [x, u, ps, pg], [newton(x, x, u, ps, pg)])

    def interval_size(self, spec):
        return spec.state_dim

    def interval(self, spec, step, variables, state, control, p_stage, p_global):
        return self._residual(spec)(variables, state, control, p_stage, p_global), variables

    def interval_guess(self, spec, states):
        return states[1:]


@pytest.fixture(scope="module", autouse=True)
def registered():
    if "trapezoidal" not in transcription_names():
        register_transcription(Trapezoidal())


def lq_ocp() -> uo.Ocp:
    ocp = uo.Ocp(horizon=HORIZON, dt=DT, transcription="trapezoidal")
    x = ocp.state("x", 2)
    u = ocp.control("u")
    ocp.set_der(x, ca.DM(A) @ x + ca.DM(B) @ u)
    ocp.add_stage_cost(residual=ca.vertcat(x, u), weight=np.array([2.0, 1.0, 0.5]))
    ocp.add_terminal_cost(residual=x, weight=np.array([20.0, 10.0]))
    return ocp


def crank_nicolson() -> np.ndarray:
    """``[A_d B_d]`` of the (1, 1) Padé approximant ``(I − M/2)⁻¹ (I + M/2)``, written directly."""
    half = DT * augmented() / 2
    discrete = np.linalg.solve(np.eye(3) - half, np.eye(3) + half)[:2]
    assert not np.allclose(discrete, pade_matrix(DT * augmented(), 1)[:2])  # not Radau's (0, 1)
    return discrete


@pytest.mark.parametrize("solver", EXACT)
def test_a_registered_transcription_is_solved_by_every_exact_backend(solver):
    x0 = np.array([1.0, -0.5])
    controls, cost = riccati(crank_nicolson(), x0)
    result = uo.solve(lq_ocp(), solver, x0=x0, options=TIGHT.get(solver))
    assert result.success, result.status
    np.testing.assert_allclose(result.controls, controls, rtol=1e-6, atol=1e-6)
    assert result.cost == pytest.approx(cost, rel=1e-6)
    judged, violation = uo.score(lq_ocp(), result.controls, x0=x0)  # through the Newton step
    assert judged == pytest.approx(result.cost, rel=1e-8) and violation < 1e-8


def test_registration_checks_the_protocol_and_the_name():
    assert isinstance(Trapezoidal(), Transcription)
    with pytest.raises(ValueError, match="registered already"):
        register_transcription(Trapezoidal())
    with pytest.raises(TypeError, match="must implement"):
        register_transcription(object())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="transcription must be one of"):
        uo.Ocp(transcription="pseudospectral")
    with pytest.raises(ValueError, match="no degree"):
        uo.Ocp(transcription="trapezoidal", degree=2)


def test_a_strategy_registered_again_under_its_name_gets_builds_of_its_own():
    class Other(Trapezoidal):
        """The same rule under another class: equal problems, another content key."""

    before = lq_ocp().spec().key
    register_transcription(Other(), overwrite=True)
    try:
        assert lq_ocp().spec().key != before
    finally:
        register_transcription(Trapezoidal(), overwrite=True)
    assert lq_ocp().spec().key == before
