"""NMPC's one stepping API (control/mpc.py): step, and prepare/feedback, on any backend.

The resident C step of ``sqp-rti`` through ``step`` is in tests/solvers/test_rti.py; the judge and the
fallback in tests/control/test_mpc_fallback.py.  Here: how NMPC dispatches on the backend's protocol
(:class:`~uuv_ocp.solvers.base.Preparable` or not) and what the step record holds.
"""

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.solvers.base import DeferredPlan, Preparable
from uuv_ocp.solvers.result import Iterate, SolveResult


def _plan_result(problem, p, name="recording"):
    """Return a successful result whose plan holds 1 N (N·m) in every control (box, rate bound)."""
    spec = problem.spec()
    controls = np.ones((spec.horizon, spec.control_size))
    states = np.tile(np.asarray(p[spec.layout.x0], dtype=float), (spec.horizon + 1, 1))
    return SolveResult(
        solver=name,
        controls=controls,
        states=states,
        cost=0.0,
        max_violation=0.0,
        success=True,
        status="recorded",
        solve_time=0.0,
        iterations=1,
        evaluations=1,
        terminal_relaxed=False,
        iterate=Iterate(spec.scaled(controls), states),
    )


class _Recording:
    """A backend without phases: ``solve`` alone, recording the instances it is given."""

    name = "recording"

    def __init__(self, problem, options=None):
        self.problem = problem
        self.instances: list[np.ndarray] = []
        self.warm_starts: list[Iterate | None] = []

    def solve(self, p, warm_start=None, rng=None):
        self.instances.append(np.array(p))
        self.warm_starts.append(warm_start)
        return _plan_result(self.problem, p)


class _PrepareOnly(_Recording):
    """Half of :class:`Preparable` (a ``prepare`` but no ``feedback``): not a preparable backend."""

    name = "prepare-only"

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        self.prepared = 0

    def prepare(self, p, warm_start):
        self.prepared += 1


class _Plan(DeferredPlan):
    """A fast path's plan whose result counts how often it is built."""

    __slots__ = ("control", "path", "_result", "built")

    def __init__(self, result):
        self.control = result.controls[0]
        self.path = "test fast path"
        self._result = result
        self.built = 0

    def iterate(self):
        return self._result.iterate

    def result(self):
        self.built += 1
        return self._result


class _Fast(_Recording):
    """A preparable backend whose feedback always takes its fast path."""

    name = "fast"
    deadline = None

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        self.prepared, self.plans = [], []
        self.feedback_warm_starts = []

    def prepare(self, p, warm_start):
        self.prepared.append(np.array(p))

    def feedback(self, p, warm_start):
        self.feedback_warm_starts.append(warm_start)
        self.plans.append(_Plan(_plan_result(self.problem, p, self.name)))
        return self.plans[-1]


@pytest.fixture
def registered():
    """Register the test backends for one test and remove them afterwards."""
    for backend in (_Recording, _PrepareOnly, _Fast):
        REGISTRY.register(backend.name, backend, overwrite=True)
    yield
    for backend in (_Recording, _PrepareOnly, _Fast):
        REGISTRY._factories.pop(backend.name, None)


def test_a_backend_without_phases_takes_the_whole_step_in_feedback(s2_problem, registered):
    """``prepare`` solves nothing; ``feedback`` solves once, at the measured state: ``step``'s record.

    Two controllers on one closed loop, one stepped by the phases, the other by ``step``: the
    same instances (the measured state in them), warm starts and controls, bit for bit.
    """
    split, whole = uo.NMPC(s2_problem, "recording"), uo.NMPC(s2_problem, "recording")
    assert not isinstance(split.backend, Preparable)
    layout = s2_problem.spec().layout
    rng = np.random.default_rng(3)
    control = np.zeros(3)
    for k in range(4):
        t = k * s2_problem.dt
        x = s2_problem.reference.initial_state(t) + 0.01 * rng.standard_normal(6)
        split.prepare(t, control, np.zeros(2))
        assert len(split.backend.instances) == k  # nothing solved before the state is measured
        a = split.feedback(x)
        b = whole.step(x, t, control, np.zeros(2))
        assert len(split.backend.instances) == len(whole.backend.instances) == k + 1
        solved = split.backend.instances[-1]
        np.testing.assert_array_equal(solved, whole.backend.instances[-1])
        np.testing.assert_array_equal(solved[layout.x0], x)  # the measured state, not a guess
        warm = split.backend.warm_starts[-1]
        assert (warm is None) == (k == 0)
        if k:
            np.testing.assert_array_equal(warm.scaled_controls, whole.backend.warm_starts[-1].scaled_controls)
        assert not a.fallback and a.fast_path == "" and a.result.status == "recorded"
        np.testing.assert_array_equal(a.control, b.control)
        np.testing.assert_array_equal(a.control, a.result.controls[0])
        control = a.control


def test_half_a_preparable_backend_is_not_prepared(s2_problem, registered):
    """A backend with ``prepare`` but no ``feedback`` is no :class:`Preparable`: NMPC never calls it."""
    controller = uo.NMPC(s2_problem, "prepare-only")
    assert not isinstance(controller.backend, Preparable)
    x = s2_problem.reference.initial_state(0.0)
    for k in range(3):
        controller.prepare(k * s2_problem.dt, np.zeros(3), np.zeros(2))
        controller.feedback(x)
        controller.step(x, k * s2_problem.dt, np.zeros(3), np.zeros(2))
    assert controller.backend.prepared == 0 and len(controller.backend.instances) == 6


def test_a_fast_path_plan_is_applied_at_once_and_its_result_built_when_read(s2_problem, registered):
    """A :class:`DeferredPlan` from ``feedback``: its control applied, its result built on first read.

    The plan is handed back as the next warm start as it is (the backend shifts it);
    ``NMPC.iterate`` and ``NMPC.plan`` are built from it; ``prepare`` gets it as a shifted
    :class:`Iterate`.
    """
    controller = uo.NMPC(s2_problem, "fast")
    backend = controller.backend
    assert isinstance(backend, Preparable)
    x = s2_problem.reference.initial_state(0.0)
    first = controller.step(x, 0.0, np.zeros(3), np.zeros(2))
    plan = backend.plans[-1]
    assert first.fast_path == "test fast path" and not first.fallback and plan.built == 0
    np.testing.assert_array_equal(first.control, plan.control)
    assert first.result is first.result and plan.built == 1  # built once, on first read
    second = controller.step(x, 0.1, first.control, np.zeros(2))
    assert backend.feedback_warm_starts == [None, plan]  # handed back unshifted
    assert backend.prepared == []  # step prepares nothing ahead: no time between the phases
    np.testing.assert_array_equal(
        controller.iterate.scaled_controls, backend.plans[-1].iterate().shift().scaled_controls
    )
    np.testing.assert_array_equal(controller.plan, backend.plans[-1]._result.controls)
    controller.prepare(0.2, second.control, np.zeros(2))
    assert len(backend.prepared) == 1 and isinstance(backend.feedback_warm_starts[-1], _Plan)
    controller.feedback(x)
    assert isinstance(backend.feedback_warm_starts[-1], Iterate)  # what prepare was given, shifted
    assert backend.plans[1].built == 0  # nobody read the second step's result


def test_the_deprecated_aliases_warn_and_give_the_new_api_s_control(s2_problem, registered):
    """``step_control`` / ``feedback_control``: one DeprecationWarning saying what to call, same control."""
    old, new = uo.NMPC(s2_problem, "fast"), uo.NMPC(s2_problem, "fast")
    x = s2_problem.reference.initial_state(0.0)
    with pytest.warns(DeprecationWarning, match=r"call NMPC\.step\(x, t, \.\.\.\)\.control"):
        control = old.step_control(x, 0.0, np.zeros(3), np.zeros(2))
    np.testing.assert_array_equal(control, new.step(x, 0.0, np.zeros(3), np.zeros(2)).control)
    assert old.last_output is None  # a fast path took it (the old API's sign)
    old.prepare(0.1, control, np.zeros(2))
    new.prepare(0.1, control, np.zeros(2))
    with pytest.warns(DeprecationWarning, match=r"call NMPC\.feedback\(x\)\.control"):
        control = old.feedback_control(x)
    np.testing.assert_array_equal(control, new.feedback(x).control)


class _NanPlan(_Plan):
    """A broken plug-in's fast plan: its control is not a number."""

    __slots__ = ()

    def __init__(self, result):
        super().__init__(result)
        self.control = np.full_like(result.controls[0], np.nan)


class _NanFast(_Fast):
    name = "nan-fast"

    def feedback(self, p, warm_start):
        self.plans.append(_NanPlan(_plan_result(self.problem, p, self.name)))
        return self.plans[-1]


def test_a_fast_plan_that_is_not_a_number_is_never_applied(s2_problem):
    REGISTRY.register(_NanFast.name, _NanFast, overwrite=True)
    try:
        controller = uo.NMPC(s2_problem, "nan-fast")
        record = controller.step(s2_problem.reference.initial_state(0.0), 0.0, np.zeros(3), np.zeros(2))
    finally:
        REGISTRY._factories.pop(_NanFast.name, None)
    assert np.all(np.isfinite(record.control)) and not record.fast_path


def test_a_bad_state_in_feedback_keeps_the_preparation_for_a_retry(s2_problem, registered):
    controller = uo.NMPC(s2_problem, "fast")
    x = s2_problem.reference.initial_state(0.0)
    controller.prepare(0.0, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="x0"):
        controller.feedback(np.full(6, np.nan))
    record = controller.feedback(x)  # prepare()'s arguments were not consumed by the bad call
    assert np.all(np.isfinite(record.control))
