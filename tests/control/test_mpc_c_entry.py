"""``NMPC.step``'s one-C-call entry gives, bit for bit, what the general path gives.

The entry (``uuv_ocp.solvers.rti.ClosedLoopEntry``: ``uuv_rti_closed_loop_step`` checks the
state and last control, writes the reference window, runs the resident step and projects the
first control) stands in for ``TrackingProblem._closed_loop_parameters`` + ``RtiSolver.feedback``
+ ``NMPC._admissible``.  The reference here is the general path itself, the same controller
class with the entry switched off (``_use_c_entry = False``), run on the same closed loop: the
controls, records, plans, warm starts and results must be equal with ``==``.  The loop takes the
steps the entry hands back to the general path too: a bad state and a bad last control (the
same ``ValueError``), a time off the sampling grid, a current, and steps whose QP is refused;
and the heading a turn or two away from the reference's branch (the window follows it).
"""

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.model import Vehicle6DOF
from uuv_ocp.solvers import rti

RTI = {"qpsol": "hpipm-ocp"}


def _s2():
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)
    start = problem.reference.initial_state(0.0) + np.array([0.3, -0.2, 0.1, 0.0, 0.0, 0.0])
    return problem, start


def _survey(thrusters):
    # the BlueROV2 Heavy survey of examples/bluerov2_depth.py (benchmarks.bench_rti), 0.5 m above
    survey = uo.Reference.lawnmower((0.0, 0.0), width=6.0, spacing=2.0, lanes=3, speed=0.3, depth=2.0)
    problem = uo.TrackingProblem(Vehicle6DOF.bluerov2_heavy(thrusters=thrusters), survey, horizon=20, dt=0.1)
    start = survey.initial_state(0.0)
    start[2] -= 0.5
    return problem, start


CASES = {
    "s2": _s2,
    "bluerov2 forces": lambda: _survey(False),
    "bluerov2 thrusters": lambda: _survey(True),
}


def _plant(problem):
    vehicle = problem.vehicle
    thrusters = getattr(vehicle, "thrusters", None) is not None
    dynamics = vehicle.thruster_dynamics if thrusters else vehicle.dynamics_function()
    step = uo.rk4_step(dynamics, problem.dt, 4)
    still = np.zeros(step.size1_in(2))
    return lambda x, u: np.array(step(x, u, still)).ravel()


def _same_iterate(a, b):
    if a is None or b is None:
        return a is b
    names = ("primal", "lam_x", "lam_g", "states", "scaled_controls")
    arrays = all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names)
    return arrays and a.variant == b.variant and a.terminal_relaxed == b.terminal_relaxed


def _same_result(a, b):
    if a is None or b is None:
        return a is b
    fields = ("cost", "max_violation", "success", "status", "iterations", "terminal_relaxed")
    same = all(getattr(a, f) == getattr(b, f) or (a is b) for f in fields)
    return same and np.array_equal(a.controls, b.controls) and np.array_equal(a.states, b.states)


def _step_both(controllers, *args):
    """Step both controllers; the records, or the ``ValueError`` messages when both raise."""
    out = []
    for controller in controllers:
        try:
            out.append(controller.step(*args))
        except ValueError as error:
            out.append(str(error))
    return out


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_entry_equals_the_general_path_bit_for_bit(case, monkeypatch):
    problem, start = CASES[case]()
    spec = problem.spec()
    entry, general = uo.NMPC(problem, "sqp-rti", options=RTI), uo.NMPC(problem, "sqp-rti", options=RTI)
    general._use_c_entry = False
    taken = []  # what the entry did at each call: None (not applied), "plan" or "refused"
    original = rti.ClosedLoopEntry.step

    def counted(self, *args):
        outcome = original(self, *args)
        taken.append(None if outcome is None else "plan" if outcome[0] is not None else "refused")
        return outcome

    monkeypatch.setattr(rti.ClosedLoopEntry, "step", counted)
    plant = _plant(problem)
    rng = np.random.default_rng(4)
    state, control = start.copy(), np.zeros(spec.control_size)
    projected = 0  # entry steps whose applied control is not the plan's first (the rate bound)
    refusals = {}
    for k in range(45):
        t, u_prev, extra = k * problem.dt, control, ()
        if k in (12, 13):  # a NaN state, then a last control outside the box: the general ValueError
            bad = state.copy() if k == 12 else u_prev.copy()
            bad[k % bad.size] = np.nan if k == 12 else spec.upper[0] + 1.0
            records = _step_both((entry, general), *((bad, t, u_prev) if k == 12 else (state, t, bad)))
            assert isinstance(records[0], str) and records[0] == records[1], records
            assert ("x0" if k == 12 else "u_prev") in records[0]
        if k == 20:
            t += 0.25 * problem.dt  # off the sampling grid: the window is evaluated
        if k in (36, 40):  # the same pose a turn or two away: the window moves to its branch
            state[problem._heading_index] += 2 * np.pi * (1 if k == 36 else -2)
        if k == 24:
            extra = (rng.normal(scale=0.05, size=spec.layout.entries["current"][1]),)  # a current
        saved = [(c.backend.qp_tolerance, c.backend.cold_start) for c in (entry, general)]
        if k in (30, 31):  # QPs refused: solve()'s fallback chain, then the controller's fallback
            for controller in (entry, general):
                controller.backend.qp_tolerance = 1e-300
                controller.backend.robust_options = lambda: {}  # no IPOPT (time)
                controller.backend.cold_start = "rti"
        before = len(taken)
        a, b = _step_both((entry, general), state, t, u_prev, *extra)
        if k in (30, 31):
            for controller, (tolerance, cold) in zip((entry, general), saved, strict=True):
                controller.backend.qp_tolerance, controller.backend.cold_start = tolerance, cold
                del controller.backend.robust_options
        if len(taken) > before:
            refusals[k] = taken[-1]
        assert np.array_equal(a.control, b.control), (k, a.control - b.control)
        assert a.control.base is None and b.control.base is None  # fresh arrays
        for name in ("fallback", "message", "deadline_hit", "fallback_source", "fast_path"):
            assert getattr(a, name) == getattr(b, name), (k, name)
        assert _same_iterate(entry.iterate, general.iterate), k
        assert (entry.plan is None and general.plan is None) or np.array_equal(entry.plan, general.plan), k
        assert _same_result(a.result, b.result), k
        if a.fast_path:  # the instance solved, every entry (the window's first row too)
            assert np.array_equal(entry._deferred.p, general._deferred.p), k
        if taken[before:] == ["plan"]:
            projected += not np.array_equal(a.control, entry._deferred.control)
        state = plant(state, a.control) + rng.normal(scale=1e-3, size=state.size)
        control = a.control
    # the entry took the loop's ordinary steps, refused the QP of step 30, and left the rest
    assert refusals.get(30) == "refused", refusals
    assert sum(v == "plan" for v in refusals.values()) >= 30, refusals
    assert 20 not in refusals and 24 not in refusals
    if case == "s2":  # the projection moved the plan's first control (by the QP's tolerance)
        assert projected > 0  # so its operations were compared too


@needs_compiler
def test_the_c_entry_is_not_taken_where_the_general_path_decides(monkeypatch):
    """A converged mode, a deadline or a hard path constraint keep the general path."""
    problem, start = _s2()
    obstacle = uo.Obstacle.circle((100.0, 100.0), 0.5)
    obstructed = uo.TrackingProblem(
        uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=10, dt=0.1, obstacles=[obstacle]
    )
    calls = []
    original = rti.ClosedLoopEntry.step
    monkeypatch.setattr(rti.ClosedLoopEntry, "step", lambda *a: calls.append(1) or original(*a))
    for chosen, options, expected in (
        (problem, {**RTI, "mode": "converged"}, False),
        (problem, {**RTI, "deadline": 1.0}, False),
        (obstructed, RTI, False),
        (problem, RTI, True),
    ):
        controller = uo.NMPC(chosen, "sqp-rti", options=options)
        state, control = start.copy(), np.zeros(3)
        calls.clear()
        for k in range(3):
            record = controller.step(state, k * chosen.dt, control)
            control = record.control
        assert bool(calls) == expected, options
    assert record.fast_path == "resident C step"  # the last loop's steps: the entry's plans


@needs_compiler
def test_an_interrupt_inside_the_entrys_fallback_solve_propagates(monkeypatch):
    """A QP the entry's C step refuses goes to ``solve``; Ctrl-C there reaches the caller."""
    problem, start = _s2()
    controller = uo.NMPC(problem, "sqp-rti", options=RTI)
    control = np.zeros(3)
    for k in range(3):
        control = controller.step(start, k * problem.dt, control).control
    assert isinstance(controller._entry, rti.ClosedLoopEntry)
    controller.backend.qp_tolerance = 1e-300  # the resident step is refused in C

    calls = []

    def interrupted(*args, **kwargs):
        calls.append(args)
        raise KeyboardInterrupt

    monkeypatch.setattr(controller.backend, "solve", interrupted)
    with pytest.raises(KeyboardInterrupt):
        controller.step(start, 3 * problem.dt, control)
    assert len(calls) == 1  # raised from the entry's own solve, not caught and taken again
