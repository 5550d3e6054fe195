"""The outlined NLP (one Function per stage structure, MX calls) against the unrolled SX NLP.

Reference: CasADi's own derivative functions of the unrolled SX NLP (``nlpsol`` with
``expand=True``); the outlined NLP's come from MX AD through the stage Functions' calls.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.path_following import PathFollowingProblem
from uuv_ocp.solvers import new_solver
from uuv_ocp.transcription import outline as outline_module
from uuv_ocp.transcription.outline import REST, OutlineError, additive_terms, check_outlined, outline

#: the functions an interior-point plugin evaluates (ipopt's names; fatrop uses the same)
FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")


def _s2(horizon: int = 5) -> uo.TrackingProblem:
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=horizon, dt=0.1)


def _bluerov2_survey(horizon: int = 4) -> uo.TrackingProblem:
    """Return the BlueROV2 Heavy (12 states) on a lawnmower survey, as ``benchmarks.bench_rti``'s."""
    survey = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.4, depth=2.0)
    return uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(), survey, horizon=horizon, dt=0.1)


def _obstacles(horizon: int = 6) -> uo.TrackingProblem:
    """RexROV past a moving and a fixed obstacle (stage path constraints with parameters)."""
    reference = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line", t_end=30.0)
    crossing = uo.Obstacle.moving(lambda t: (3.0 + 0 * t, -2.1 + 0.3 * t), 0.3, margin=0.1)
    fixed = uo.Obstacle.circle((2.8, 1.0), 0.4, margin=0.1)
    return uo.TrackingProblem(
        uo.Vehicle.rexrov(), reference, horizon=horizon, terminal="cost", obstacles=[crossing, fixed]
    )


def _path(horizon: int = 6) -> PathFollowingProblem:
    """RexROV following a line with its path parameter (augmented state, other cost terms)."""
    line = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line", t_end=200.0)
    return PathFollowingProblem(uo.Vehicle.rexrov(), line, speed=0.5, horizon=horizon, dt=0.5)


PROBLEMS = {"s2": _s2, "bluerov2 survey": _bluerov2_survey, "obstacles": _obstacles, "path": _path}


def _variants(problem):
    """Return the NLPs (hard and soft) the fatrop backend builds for ``problem``."""
    return new_solver(problem, "fatrop", {}).variants


def _outlined(data):
    stages = [key[1] for key in data.variable_keys]
    rows = [key[1] for key in data.constraint_keys]
    return outline(data.nlp, stages, rows)


def _evaluate(function: ca.Function, arguments: list) -> list[ca.DM]:
    values = function(*arguments)
    return list(values) if isinstance(values, list | tuple) else [values]


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_outlined_nlp_functions_and_derivatives_equal_the_unrolled_ones(name):
    rng = np.random.default_rng(7)
    for data in _variants(PROBLEMS[name]()).values():
        outlined = _outlined(data)
        options = {"print_time": False, "ipopt.print_level": 0}
        unrolled = ca.nlpsol("unrolled", "ipopt", data.nlp, {**options, "expand": True})
        mx = ca.nlpsol("outlined", "ipopt", outlined.nlp, {**options, "expand": False})
        for entry in FUNCTIONS:
            reference, candidate = unrolled.get_function(entry), mx.get_function(entry)
            for _ in range(3):
                arguments = [
                    rng.standard_normal(reference.sparsity_in(i).shape) for i in range(reference.n_in())
                ]
                for a, b in zip(
                    _evaluate(reference, arguments), _evaluate(candidate, arguments), strict=True
                ):
                    # same structure (fatrop's detection, the Hessian's pattern), same values
                    assert a.sparsity() == b.sparsity(), f"{name}: {entry} sparsity differs"
                    a, b = np.array(a.nonzeros()), np.array(b.nonzeros())
                    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * (1 + np.abs(a).max(initial=0)))


def test_outlined_code_does_not_grow_with_the_horizon():
    """The number of distinct stage Functions is the same at N = 6 and N = 24; the middle one is shared."""
    counts = []
    for horizon in (6, 24):
        outlined = _outlined(_variants(_s2(horizon))["hard"])
        counts.append(len(outlined.groups))
        assert max(len(stages) for _, stages in outlined.groups) == horizon  # every stage's rows
        assert all(
            stage == REST or 0 <= stage <= horizon for _, stages in outlined.groups for stage in stages
        )
    assert counts[0] == counts[1] <= 6


def test_a_mis_grouped_stage_is_caught(monkeypatch):
    """A key that puts every part into one group (the first stage's rows, the costs, ...): refused."""
    monkeypatch.setattr(outline_module, "_group_key", lambda part: "one group")
    data = _variants(_s2(4))["hard"]
    with pytest.raises(OutlineError, match="was grouped with stage"):
        outline(data.nlp, [key[1] for key in data.variable_keys])


def test_a_reassembly_error_is_caught_at_random_points():
    data = _variants(_s2(4))["hard"]
    outlined = dict(_outlined(data).nlp)
    g = outlined["g"]
    order = list(range(g.numel()))
    order[3], order[4] = order[4], order[3]  # two rows swapped
    with pytest.raises(OutlineError, match="differs from the SX NLP"):
        check_outlined(data.nlp, {**outlined, "g": g[order]}, np.random.default_rng(0))
    assert check_outlined(data.nlp, _outlined(data).nlp, np.random.default_rng(0)) <= 1e-12


def test_additive_terms_sum_to_the_expression():
    x = ca.SX.sym("x", 3)
    expression = 2.5 * (x[0] ** 2 - (x[1] * x[2] + ca.sin(x[0]))) + (-(x[2] ** 3)) * 0.5 + 0.0
    terms = additive_terms(expression)
    assert len(terms) == 4
    function = ca.Function("f", [x], [expression, ca.sum1(ca.vertcat(*terms))])
    point = np.random.default_rng(1).standard_normal(3)
    whole, split = (float(v) for v in function(point))
    assert split == pytest.approx(whole, rel=1e-14)


def test_bad_arguments_are_refused_by_name():
    data = _variants(_s2(3))["hard"]
    with pytest.raises(ValueError, match="stages must have one entry per variable"):
        outline(data.nlp, [0])
    with pytest.raises(ValueError, match="row_stages must have one entry per row"):
        outline(data.nlp, [key[1] for key in data.variable_keys], [0])
    with pytest.raises(ValueError, match="nlp must be a dict of SX"):
        outline({"x": ca.MX.sym("x")}, [0])
