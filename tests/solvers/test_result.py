"""Typed records of one solve (uuv_ocp.solvers.result): Attempt, SolveDetails, Variant, Stage."""

import dataclasses

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers.result import (
    Attempt,
    AttemptSummary,
    SolveDetails,
    SolveResult,
    Stage,
    Variant,
)


def test_variant_is_its_spelling_and_knows_its_penalty():
    assert Variant.escalated(100.0) == "soft_x100" and Variant("soft_x100").penalty_factor == 100.0
    assert Variant("soft").soft and Variant("soft").penalty_factor == 1.0
    assert not Variant("hard").soft and Variant("hard").penalty_factor is None
    with pytest.raises(ValueError, match="variant must be"):
        Variant("sofft")
    with pytest.raises(ValueError, match="variant must be"):
        Variant("soft_x-1")


def test_details_are_frozen_fields_and_a_mapping_of_the_reported_ones():
    details = SolveDetails(deadline_hit=False, extra={"fitness": 2.0})
    assert details["deadline_hit"] is False and details.deadline_hit is False
    assert dict(details) == {"deadline_hit": False, "fitness": 2.0}
    assert "attempts" not in details and details.get("c_time") is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        details.deadline_hit = True  # type: ignore[misc]
    with pytest.raises(TypeError):
        details["deadline_hit"] = True  # type: ignore[index]
    changed = details.replace(c_time=0.5, chosen=1)
    assert changed.c_time == 0.5 and changed["chosen"] == 1 and "c_time" not in details


def test_a_plain_mapping_of_a_plugin_becomes_details():
    result = SolveResult(
        solver="mine",
        controls=np.zeros((1, 1)),
        states=np.zeros((2, 1)),
        cost=0.0,
        max_violation=0.0,
        success=True,
        status="ok",
        solve_time=0.0,
        iterations=0,
        evaluations=0,
        terminal_relaxed=False,
        iterate=uo.Iterate(np.zeros((1, 1)), np.zeros((2, 1))),
        details={"deadline_hit": True, "attempts": [("hard", "ok", 3)], "mine": 1},
    )
    assert isinstance(result.details, SolveDetails) and result.details.deadline_hit is True
    assert result.details.attempts == (AttemptSummary("hard", "ok", 3),) and result.details["mine"] == 1


def test_an_exact_solve_reports_typed_attempts(tiny_problem):
    result = uo.solve(tiny_problem, "ipopt", x0=tiny_problem.reference.initial_state(0.0))
    assert isinstance(result.details, SolveDetails)
    (first, *_) = result.details.attempts
    assert isinstance(first, AttemptSummary) and first.label == "hard" and first.iterations > 0
    assert result.details.deadline_hit is False and isinstance(result.details.still_water, bool)


def test_attempt_labels_name_the_stage():
    attempt = Attempt(
        variant=Variant("soft_x100"),
        stage=Stage.ROBUST,
        still_water=False,
        primal=np.zeros(2),
        lam_g=np.zeros(1),
        lam_x=np.zeros(2),
        success=False,
        status="failed",
        iterations=4,
        evaluations=5,
        solver_time=0.1,
    )
    assert attempt.summary() == ("soft_x100 (robust)", "failed", 4)
    assert Stage.PLAIN.suffix == "" and Stage.RESCUE.suffix == " (rescue)"


@pytest.fixture(scope="module")
def tiny_problem():
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
