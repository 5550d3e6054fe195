"""Receding-horizon NMPC around any registered solver.

Warm starting is explicit: the controller keeps the last :class:`~uuv_ocp.solvers.Iterate`
and shifts it by one interval before the next solve (primal and, for exact solvers, duals;
for swarms the shifted best plan seeds the next population).  :meth:`NMPC.reset` forgets it,
so the same state and time always give the same control after a reset.

Fallback (documented contract; docs/solvers.md).  A fresh plan is applied when the backend
reports ``success``, its controls are finite and, on a problem with hard path constraints
(obstacles, state bounds: every hard constraint but the terminal equality), the judge
(:func:`uuv_ocp.judge.score_terms`) finds them violated by at most
:data:`~uuv_ocp.judge.FEASIBILITY_TOLERANCE` along the plan's rollout from the measured state.
The last test matters for the swarms, which hold path constraints only by a penalty, and for
a real-time iteration (``sqp-rti``), whose one QP holds the constraints linearised at the
warm start: a plan of it that the judge refuses is iterated further from that plan, on the
same instance (up to :data:`RTI_REFINEMENTS` calls of the backend's ``solve``, judged after
each, within the rest of the deadline), before the step gives up on it.  A plan a backend's
fast path gives (a :class:`~uuv_ocp.solvers.base.DeferredPlan`: ``sqp-rti``'s C step) is
judged on such problems too, and a refused one is refined the same way, so every plan applied
is judged.
Otherwise the step takes the *fallback*, the first admissible plan of

1. the shifted previous plan (the last applied plan, one interval on, last control repeated);
2. the *steady control* ramped to at the rate bound: the control that holds the reference's
   velocities (an Ocp: the measured ones) at the measured pose against the model's drift
   (damping, current, restoring forces), i.e. the least-squares solution of ``f_v(x, u) = 0``
   for the rows ``f_v`` of the dynamics the controls drive, clipped to the box;
3. on a tracking problem, the *braking control* ramped to at the rate bound: the control (in
   the box) whose driven velocity rates come closest to ``−ν / dt`` at the measured state,
   i.e. the hardest stop the box allows (a vehicle that no plan steers clear of an obstacle
   stops short of it instead of creeping on into it);
4. the last applied control held;

where admissible means: the judge finds the plan within the control box, the rate bound
against the last applied control and the hard path constraints (to ``FEASIBILITY_TOLERANCE``)
from the measured state.  When none is admissible, the one with the smallest violation is
applied.  The steady control does not steer back to the reference; it stops the error from
growing as fast as it would with no control or a stale one.  The step is counted in
``ClosedLoopResult.failures`` and the closed loop never stops on a solver failure; why the
fresh plan was refused is in ``StepRecord.message`` (the backend's status, its exception,
``"non-finite controls ..."`` or ``"path constraint violated ..."``) and which plan was
applied in ``StepRecord.fallback_source``.  ``KeyboardInterrupt`` (CasADi's, raised as a
``RuntimeError`` naming it, included) always propagates.  A backend whose ``solve`` returns
something other than a :class:`~uuv_ocp.solvers.SolveResult` is a broken plug-in, not a
failed solve: the step raises ``TypeError`` naming it.

Deadlines (backend option ``deadline``, seconds; see docs/solvers.md): a step whose backend
reports ``details["deadline_hit"]`` sets ``StepRecord.deadline_hit`` and is counted in
``ClosedLoopResult.deadline_misses``.  An exact solver (or a hybrid's exact stage) stopped by
the deadline reports ``success=False``, so the step takes the fallback above; a swarm stopped by
it returns its best plan so far, which is applied when feasible (``success``) — a swarm is an
anytime method, its plan is ready at the deadline.

Building: :meth:`NMPC.warm_up` runs what the first steps would build or compile (the cold
start's NLP, ``sqp-rti``'s C step, JIT code) on one instance and forgets it; :func:`simulate`
calls it before its loop, so that no timed step compiles.

One API: :meth:`NMPC.step` (state and time in, a :class:`StepRecord` out: the control to apply
and how it came about), or its two phases for real-time use, :meth:`NMPC.prepare` (before the
state is measured: the time, last control and data of the step; a
:class:`~uuv_ocp.solvers.base.Preparable` backend linearises then) and :meth:`NMPC.feedback`
(the measured state in, the record out).  ``step`` is the two phases with no time between
them, so it prepares nothing ahead: a Preparable backend's ``feedback`` takes the whole step by
its fastest path (``sqp-rti``'s C step: one C call from its resident warm start), other
backends' ``solve``.  A fast path's plan comes as a :class:`~uuv_ocp.solvers.base.DeferredPlan`:
the control at once, its warm start, :attr:`NMPC.plan` and :attr:`StepRecord.result` (the judge)
built only when read.  ``step_control`` and ``feedback_control`` are deprecated aliases of
``step(...).control`` and ``feedback(x).control``.

Non-finite numbers: a plan with a non-finite control is refused (the fallback above), and a
warm start with any non-finite number (plan, NLP primal or multipliers) is never kept, so a
step after a diverged solve starts cold, as after :meth:`NMPC.reset` (``sqp-rti`` drops such a
warm start itself too: its step then starts with its ``cold_start``).

Every applied control, fresh or fallback, is projected on the control box and on the rate
bound around the last applied control: the plant never sees a bound violated, whatever the
backend's tolerance.
"""

from __future__ import annotations

import functools
import math
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, TypeVar

import casadi as ca
import numpy as np
from scipy.optimize import lsq_linear

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import FEASIBILITY_TOLERANCE, instance_parameters, score_terms
from uuv_ocp.solvers import REGISTRY, new_solver
from uuv_ocp.solvers.base import DeferredPlan, Preparable, reraise_interrupt
from uuv_ocp.solvers.result import Iterate, SolveResult
from uuv_ocp.solvers.rti import ClosedLoopEntry, CStepPlan
from uuv_ocp.tracking import SAMPLE_BLOCK, UNWRAP_STEP, TrackingProblem
from uuv_ocp.transcription.multiple_shooting import parameter_blocks

#: Linearisations of the steady control's least squares (the UUV models are affine in the
#: controls: the first one is exact; the others only matter for a model that is not).
STEADY_ITERATIONS = 3
#: Weight of the scaled controls' squares in the steady control's least squares: it only
#: breaks ties (more thrusters than driven rows), far below the residuals' (m/s², rad/s²) scale.
STEADY_REGULARISATION = 1e-10
#: Further ``solve`` calls (each the backend's ``iterations`` SQP steps) a real-time iteration's
#: plan gets when it breaks a path constraint, before the step falls back (module doc).
RTI_REFINEMENTS = 10
#: How :meth:`NMPC._refusal` starts the message of a plan the judge refuses.
PATH_VIOLATION = "path constraint violated"


@dataclass(frozen=True)
class StepRecord:
    """What one controller step returns: the control to apply and how it came about.

    Parameters
    ----------
    control : numpy.ndarray, shape (nu,)
        Control to apply (physical units: N, N, N·m for the RexROV).
    _result : SolveResult, DeferredPlan or None
        The solver's outcome, read as :attr:`result` (a backend's fast path gives a
        :class:`~uuv_ocp.solvers.base.DeferredPlan`, turned into its result when first read).
    fallback : bool
        Whether ``control`` comes from the fallback rather than the fresh solution.
    message : str
        Why the fallback was used: the backend's status, ``"exception: <type>: <message>"``
        when the backend raised, ``"non-finite controls (...)"`` or ``"path constraint
        violated by ... (...)"`` (with the backend's status); empty when the fresh solution is
        applied.
    deadline_hit : bool
        Whether the backend's ``deadline`` option stopped or outlasted this solve
        (``result.details["deadline_hit"]``; see the module doc).
    fallback_source : str
        Which fallback plan was applied (module doc): ``"shifted plan"``, ``"steady control"``,
        ``"braking control"``
        or ``"held control"``, with ``" (least violation)"`` appended when none was
        admissible; empty when the fresh solution is applied.
    fast_path : str
        The backend's fast path that gave the applied plan (``sqp-rti``: ``"resident C step"``
        or ``"prepared C step"``); empty when the plan came through ``solve`` (or a fallback).
    """

    control: np.ndarray
    _result: SolveResult | DeferredPlan | None = field(repr=False)
    fallback: bool
    message: str = ""
    deadline_hit: bool = False
    fallback_source: str = ""
    fast_path: str = ""

    @classmethod
    def _of_fast_path(cls, control: np.ndarray, plan: DeferredPlan) -> StepRecord:
        """Return ``StepRecord(control, plan, False, fast_path=plan.path)``, built without its ``__init__``.

        Every field set at once: the frozen ``__init__`` sets seven one by one (1.4 against 0.6 µs
        timeit, on every fast step of a closed loop; tests/control/test_mpc_fast_paths.py).
        """
        record = _NEW(cls)
        _SET(
            record,
            "__dict__",
            {**_FAST_DEFAULTS, "control": control, "_result": plan, "fast_path": plan.path},
        )
        return record

    @property
    def result(self) -> SolveResult | None:
        """The solver's result (``None`` if the solver raised); the judge's cost and violation included.

        After a fast path (:attr:`fast_path`) it is built on first read, from the copies the
        step kept: the same numbers at any later time, at the cost of the judge then (read it
        in the thread that steps the controller, or while it does not step).
        """
        outcome = self._result
        if isinstance(outcome, DeferredPlan):
            outcome = outcome.result()
            object.__setattr__(self, "_result", outcome)  # built once; the record stays frozen
        return outcome


#: The name of :class:`StepRecord` before the fast paths returned one too.
StepOutput = StepRecord
#: what :meth:`StepRecord._of_fast_path` uses: the fields of a fresh plan applied, in their order
_FAST_DEFAULTS = {
    "control": None,
    "_result": None,
    "fallback": False,
    "message": "",
    "deadline_hit": False,
    "fallback_source": "",
    "fast_path": "",
}
_NEW, _SET = object.__new__, object.__setattr__
_FLOAT = np.dtype(float)  # the dtype of the arrays the one-C-call step takes as they are


_Method = TypeVar("_Method", bound=Callable[..., Any])


def _one_thread(method: _Method) -> _Method:
    """Refuse a second thread inside one controller's steps (a clear error, not a wrong control).

    A controller's warm start, plan and backend memory are one closed loop's state: two threads
    stepping it at once would interleave two loops.  Nested calls by the same thread (``step``
    inside ``warm_up``) pass; the check costs one non-blocking lock per call.
    """

    @functools.wraps(method)
    def guarded(self: NMPC, *args: Any, **kwargs: Any) -> Any:
        me = threading.get_ident()
        if self._stepping == me:
            return method(self, *args, **kwargs)
        if not self._step_lock.acquire(blocking=False):
            raise RuntimeError(
                f"NMPC.{method.__name__} was called while another thread is inside this controller "
                f"({self.solver_name}); a controller is one closed loop: give each thread its own NMPC"
            )
        self._stepping = me
        try:
            return method(self, *args, **kwargs)
        finally:
            self._stepping = None
            self._step_lock.release()

    return guarded  # type: ignore[return-value]


class NMPC:
    """Nonlinear MPC controller for any problem (an :class:`~uuv_ocp.ocp.Ocp` or a tracking preset).

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    solver : str
        Any name from :func:`uuv_ocp.available_solvers`.
    options : dict, optional
        Backend options.
    seed : int, optional
        Seed of the controller's ``numpy.random.Generator`` (swarm solvers).
    warm_start : bool
        Shift the previous solution into the next solve.
    """

    def __init__(
        self,
        problem: Transcribed,
        solver: str = "ipopt",
        *,
        options: dict[str, Any] | None = None,
        seed: int | None = None,
        warm_start: bool = True,
    ) -> None:
        self._step_lock = threading.Lock()  # see _one_thread
        self._stepping: int | None = None
        self.problem = problem
        self.solver_name = REGISTRY.resolve(solver)  # the registered spelling: "IPOPT" -> "ipopt"
        # a backend of its own: solver memory, buffers and warm starts are never shared
        self.backend = new_solver(problem, solver, options)
        if not callable(getattr(self.backend, "solve", None)):
            raise TypeError(
                f"solver {self.solver_name!r}: its factory returned a {type(self.backend).__name__}, which "
                "has no solve(p, warm_start, rng) method (see uuv_ocp.solvers.base.Backend)"
            )
        if seed is not None:
            seed = check.positive_int("seed", seed, minimum=0)
        self.seed = seed
        self.use_warm_start = check.boolean("warm_start", warm_start)
        self._rng = np.random.default_rng(seed)
        self._iterate: Iterate | None = None
        self._plan: np.ndarray | None = None
        self._pending: tuple[Any, ...] | None = None
        self._prepared_p: np.ndarray | None = None  # the instance prepare() linearised
        # the last plan a Preparable backend's fast path gave: kept instead of _iterate/_plan
        # (and handed back as the next warm start) until another path needs those (_materialize)
        self._deferred: DeferredPlan | None = None
        self._bounds: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # see _admissible
        self._path_constrained: bool | None = None  # whether fresh plans are judged (module doc)
        self._steady: tuple[ca.Function, np.ndarray] | None = None  # see _steady_control
        #: whether :meth:`step` may take its one-C-call entry (:meth:`_entry_step`); a private
        #: switch (tests compare the two paths bit for bit)
        self._use_c_entry = True
        #: whether :meth:`warm_up` has run (what the steps build is built)
        self.warmed_up = False
        #: the record of the last deprecated :meth:`step_control` / :meth:`feedback_control`
        #: step, ``None`` after one a fast path took (kept for their callers)
        self.last_output: StepRecord | None = None

    @property
    def backend(self) -> Any:
        """The controller's own backend (any registered solver's; see :mod:`uuv_ocp.solvers.base`)."""
        return self._backend

    @backend.setter
    def backend(self, backend: Any) -> None:
        # checked once here, not per step: a runtime protocol check costs tens of µs
        self._backend = backend
        self._preparable = isinstance(backend, Preparable)
        # the one-C-call step of this backend (:meth:`_entry_step`): None until decided, False
        # where it does not apply; its reference runs by sample block (first, last)
        self._entry: ClosedLoopEntry | bool | None = None
        self._entry_runs: dict[tuple[int, int], tuple[int, int, int, np.ndarray] | None] = {}
        #: the problem, dt, the bounds of t and the reference's end (_window_address's)
        self._entry_window: tuple[TrackingProblem, float, float, float, float] | None = None

    @_one_thread
    def reset(self) -> None:
        """Forget the warm start and the previous plan; restart the random generator; reset the backend.

        A backend with a ``reset()`` hook (:class:`~uuv_ocp.solvers.base.Backend`; ``sqp-rti``:
        its C steps' memory) is reset too: the next step is the one a new controller would take.
        """
        hook = getattr(self.backend, "reset", None)
        if callable(hook):
            hook()
        self._iterate = None
        self._plan = None
        self._deferred = None
        self._pending = None
        self._prepared_p = None
        self._rng = np.random.default_rng(self.seed)

    @_one_thread
    def warm_up(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> None:
        """Build and compile what the steps will need, on the instance of :meth:`step`; then reset.

        Runs a cold step and a warm step at state ``x`` and time ``t`` (the paths
        :meth:`step` takes in a closed loop: the cold start's NLP, ``sqp-rti``'s C step and its
        compiled judge, JIT code), then :meth:`reset`: the controller's next step is the one it
        would have taken without the warm-up.  :func:`~uuv_ocp.simulate` calls it before its
        loop, so that no timed step compiles.  What only an unusual step needs is still built
        on first use (``sqp-rti``: the escalated soft penalties, the other still-water flag).
        A failed step here is no error (the loop will report its own).
        """
        # a C compile inside says so on standard error (uuv_ocp.native.compile, SlowNotice)
        build = getattr(self.backend, "build", None)
        if callable(build):  # the whole fallback chain (robust retry, rescue), not just the used path
            build(
                instance_parameters(self.problem, x, t, u_prev=u_prev, current=current, parameters=parameters)
            )
        output = self.step(x, t, u_prev, current, parameters)
        self.step(x, t, output.control, current, parameters)
        self.reset()
        self.warmed_up = True

    @property
    def iterate(self) -> Iterate | None:
        """The warm start the next :meth:`step` will use (already shifted)."""
        if self._deferred is not None:
            return self._deferred.iterate().shift()
        return self._iterate

    @property
    def plan(self) -> np.ndarray | None:
        """The last fresh plan (physical controls, shape (N, nu)), shifted by each fallback step."""
        if self._deferred is not None:
            return self.problem.controls_from_scaled(self._deferred.iterate().scaled_controls)
        return self._plan

    def _materialize(self) -> None:
        """Turn the last fast path's plan into ``_iterate`` and ``_plan`` (the general path's)."""
        if self._deferred is not None:
            iterate = self._deferred.iterate()
            self._plan = self.problem.controls_from_scaled(iterate.scaled_controls)
            self._iterate = iterate.shift() if iterate.is_finite() else None  # as _accept
            self._deferred = None

    @_one_thread
    def step(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> StepRecord:
        """Solve at state ``x`` and time ``t``; return the control to apply and the step's record.

        ``current`` is a tracking problem's model current; ``parameters`` an Ocp's data.
        :meth:`prepare` then :meth:`feedback` with no time between them, so nothing is prepared
        ahead: the backend's feedback takes the whole step at the measured state by its
        fastest path (``sqp-rti``'s C step: one C call from its resident warm start; docs/
        solvers.md).  The controls, plans and warm starts are those of :meth:`prepare` +
        :meth:`feedback`.
        """
        self._pending = self._prepared_p = None  # a step replaces a prepared one
        if current is None and parameters is None and self._entry is not False and self._use_c_entry:
            record = self._entry_step(x, t, u_prev)
            if record is not None:
                return record
        p = instance_parameters(self.problem, x, t, u_prev=u_prev, current=current, parameters=parameters)
        return self._solve_step(p, u_prev)

    def _entry_step(self, x: object, t: object, u_prev: object) -> StepRecord | None:
        """:meth:`step` in one C call (:class:`~uuv_ocp.solvers.rti.ClosedLoopEntry`), or ``None``.

        The common case of a closed loop (docs/solvers.md): a tracking problem without hard path
        constraints, ``sqp-rti`` with its C step in ``mode="rti"`` and no deadline, the last step's
        resident plan as warm start, float64 arrays ``x`` and ``u_prev``, a float ``t`` on the
        sampling grid whose window the cached reference samples hold, no current, no model
        parameters.  The same numbers as the general path (the record, plan and warm start);
        ``None`` (nothing run) for anything else, a value the general path refuses included.
        """
        warm = self._deferred
        if type(warm) is not CStepPlan or not warm.all_finite or not self.use_warm_start:
            return None
        entry = self._entry
        if entry is None:
            entry = self._entry = self._build_entry()
        if entry is False or type(x) is not np.ndarray or type(u_prev) is not np.ndarray:
            return None
        assert isinstance(entry, ClosedLoopEntry)
        nx, nu, _, rows, _ = entry.layout
        if x.dtype is not _FLOAT or u_prev.dtype is not _FLOAT or x.shape != (nx,) or u_prev.shape != (nu,):
            return None
        window = self._window_address(t, nx, rows)
        if window is None:
            return None
        taken = entry.step(warm, x, u_prev, window)
        if taken is None:
            return None
        plan, values = taken
        if plan is None:  # not accepted: solve() from the shifted plan, as RtiSolver.feedback
            backend = self.backend
            return self._solve_step(values, u_prev, lambda: backend.solve(values, warm.iterate().shift()))
        if not plan.all_finite:  # the general path's judgement of a plan with a non-finite number
            return self._solve_step(plan.p, u_prev, lambda: plan)
        self._deferred = plan
        return StepRecord._of_fast_path(values.copy(), plan)

    def _build_entry(self) -> ClosedLoopEntry | bool:
        """Return the controller's :class:`~uuv_ocp.solvers.rti.ClosedLoopEntry` (``False``: none applies)."""
        problem, backend = self.problem, self.backend
        if (
            not isinstance(problem, TrackingProblem)
            or not callable(getattr(backend, "resident_step", None))
            or getattr(backend, "mode", None) != "rti"
            or not backend.resident_available
            or self.path_constrained
            or problem.dt > UNWRAP_STEP
        ):
            return False
        plan = problem._closed_loop_plan  # the layout TrackingProblem's own fast instance writes
        if plan is None:
            return False
        size, nx, nu, lows, highs, t_low, t_high, window_part, current_part, defaults, heading = plan
        template = np.zeros(size)
        template[current_part] = 0.0
        for part, value in defaults:
            template[part] = value
        # the still-water choice must read only the template's entries (the current)
        varying = np.zeros(size, dtype=bool)
        varying[: nx + nu] = varying[window_part] = True
        still_slice = getattr(backend, "_still_water_slice", None)
        if still_slice is not None and varying[still_slice].any():
            return False
        self._entry_window = (problem, problem.dt, t_low, t_high, problem.reference.t_end)
        if self._bounds is None:  # as _admissible gathers them
            spec = problem.spec()
            self._bounds = (spec.lower, spec.upper, spec.max_rate * spec.dt)
        return ClosedLoopEntry(
            backend,
            template,
            lows,
            highs,
            (nx, nu, window_part.start, problem.horizon + 1, heading),
            self._bounds,
        )

    def _window_address(self, t: object, nx: int, rows: int) -> int | None:
        """Address of the reference window at ``t`` in the problem's joined sample blocks, or ``None``.

        The rows ``TrackingProblem._window_from_samples`` copies when it cuts the window from a
        joined run (the same bounds on ``t``); ``None`` where it would not (its block loop or the
        reference's evaluation then give the window, by the general path).  The runs are kept
        here with their arrays, so that an address stays valid.
        """
        if not isinstance(t, float) or self._entry_window is None:
            return None
        problem, dt, t_low, t_high, t_end = self._entry_window
        t0 = float(t)
        if not (t_low <= t0 <= t_high and math.isfinite(t0)):
            return None
        first = round(t0 / dt)
        last = first + rows - 1
        if first * dt != t0 or last * dt > t_end:
            return None
        key = (first // SAMPLE_BLOCK, last // SAMPLE_BLOCK)
        runs = self._entry_runs
        if key not in runs:
            joined = problem._joined_blocks(*key)
            run = None
            if joined is not None:
                start_index, states = joined
                usable = states.dtype is _FLOAT and states.ndim == 2 and states.flags.c_contiguous
                if usable and states.shape[1] == nx:
                    run = (start_index, states.shape[0], states.ctypes.data, states)
            runs[key] = run
        run = runs[key]
        if run is None:
            return None
        start_index, count, address, _ = run
        if not (start_index <= first and last - start_index < count):
            return None
        return address + 8 * nx * (first - start_index)

    @_one_thread
    def prepare(
        self,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> None:
        """Run the preparation phase of the next step, before its state is measured.

        Stores the step's time, last control, current and parameters.  A backend with a
        preparation phase (:class:`~uuv_ocp.solvers.base.Preparable`; ``"sqp-rti"``:
        linearisation at the shifted previous iterate) runs it now, with the warm start's
        predicted first state standing in for the measurement; :meth:`feedback` then only
        solves the QP.  Other backends do all their work in :meth:`feedback`.  Without a warm
        start nothing is prepared; a preparation that raises is dropped (``KeyboardInterrupt``
        excepted), and :meth:`feedback` then solves afresh, reporting any failure as a step's
        failure.
        """
        self._materialize()
        self._pending = (t, u_prev, current, parameters)
        self._prepared_p = None
        warm = self._iterate if self.use_warm_start else None
        if not self._preparable or warm is None:
            return
        guess = warm.states[0]
        p = instance_parameters(self.problem, guess, t, u_prev=u_prev, current=current, parameters=parameters)
        try:
            self.backend.prepare(p, warm)
        except Exception as error:  # a failed preparation only costs speed: feedback solves afresh
            reraise_interrupt(error)
            return
        self._prepared_p = p

    @_one_thread
    def feedback(self, x: object) -> StepRecord:
        """Run the feedback phase: the measured state ``x`` in, the control and the step's record out.

        Uses the time, last control, current and parameters given to :meth:`prepare` (which
        must come first; ``ValueError`` otherwise).  A backend without a preparation phase
        takes the whole step here.
        """
        u_prev, p = self._measured_instance(x)
        return self._solve_step(p, u_prev)

    def _measured_instance(self, x: object) -> tuple[object | None, np.ndarray]:
        """Consume :meth:`prepare`'s arguments: the last control and the instance at state ``x``."""
        if self._pending is None:
            raise ValueError("NMPC.feedback(x) needs NMPC.prepare(t, u_prev, ...) first (or call step)")
        t, u_prev, current, parameters = self._pending
        # the instance is made (and x checked) before prepare()'s arguments are consumed: a bad
        # x raises and a retry with a good one still finds them
        if self._prepared_p is not None:  # the instance of prepare(), its guessed state replaced
            p = self.problem.with_state(self._prepared_p, x)
            self._prepared_p = None
        else:
            p = instance_parameters(self.problem, x, t, u_prev=u_prev, current=current, parameters=parameters)
        self._pending = None
        return u_prev, p

    def _solve_step(
        self, p: np.ndarray, u_prev: object | None, solve: Callable[[], Any] | None = None
    ) -> StepRecord:
        """Solve instance ``p`` and pick the control: the fresh plan's, or the fallback's.

        ``solve``: what gives the backend's outcome instead of its ``feedback`` or ``solve``
        (:meth:`_entry_step`'s rest of a step it began), called where they would be.
        """
        start = time.perf_counter()
        preparable = self._preparable
        try:
            if solve is not None:
                outcome = solve()
            elif preparable:
                # the last fast plan as it is (the backend shifts it: in C for sqp-rti's resident step)
                warm = self._deferred if self._deferred is not None else self._iterate
                outcome = self.backend.feedback(p, warm if self.use_warm_start else None)
            else:
                self._materialize()  # a fast plan of a Preparable backend set before this one
                warm = self._iterate if self.use_warm_start else None
                outcome = self.backend.solve(p, warm, rng=self._rng)
        except Exception as error:  # a backend crash must never stop a closed loop ...
            reraise_interrupt(error)  # ... but Ctrl-C (CasADi's too) always reaches the user
            result = None
            failure_reason = f"exception: {type(error).__name__}: {error}"
        else:
            if preparable and isinstance(outcome, DeferredPlan):
                finite = outcome.finite_control()  # a plug-in's NaN: no plan
                if finite and self._holds_path_constraints(outcome, p):  # judged where paths bind
                    self._deferred = outcome  # its iterate and plan are built when needed
                    control = self._admissible(outcome.control, u_prev)
                    return StepRecord._of_fast_path(control, outcome)
                # refused: refined and judged below, as a refused plan of solve() is
                outcome = outcome.result()
            if not isinstance(outcome, SolveResult):  # a broken plug-in, not a failed solve
                raise TypeError(
                    f"solver {self.solver_name!r} ({type(self.backend).__name__}) returned a "
                    f"{type(outcome).__name__} from {'feedback' if preparable else 'solve'}(); a backend "
                    "must return a uuv_ocp SolveResult"
                )
            result = outcome
            failure_reason = self._refusal(result, p)
            if failure_reason.startswith(PATH_VIOLATION) and preparable:
                result, failure_reason = self._refine(result, p, start)
        self._materialize()  # the previous fast plan (if any): what the fallback shifts
        late = result is not None and bool(result.details.get("deadline_hit", False))
        if not failure_reason:
            assert result is not None
            control = self._accept(result.controls, result.iterate, u_prev)
            return StepRecord(control, result, False, deadline_hit=late)
        fallback, source = self._fallback_control(p)
        control = self._admissible(fallback, u_prev)
        if late and result is not None and result.iterate.is_finite():
            # the stopped solve's progress warm-starts the next one (iterations carry on across
            # steps, as in real-time iteration schemes); its plan is not applied
            self._iterate = result.iterate.shift()
        elif self._iterate is not None:
            self._iterate = self._iterate.shift()
        return StepRecord(control, result, True, failure_reason, deadline_hit=late, fallback_source=source)

    def _refusal(self, result: SolveResult, p: np.ndarray) -> str:
        """Why the fresh plan of ``result`` is not applied (module doc), or ``""`` to apply it."""
        if not result.success:
            return str(result.status) or "failed (no status)"
        spec = self.problem.spec()
        controls = np.asarray(result.controls)
        if controls.shape != (spec.horizon, spec.control_size):
            return (
                f"controls of shape {controls.shape}, expected {(spec.horizon, spec.control_size)} "
                f"(the backend reported {result.status!r})"
            )
        if not np.all(np.isfinite(controls)):
            return f"non-finite controls (the backend reported {result.status!r})"
        if self.path_constrained:
            # judged here, whatever the backend reports (a plug-in's details included)
            violation = self._violations(controls, p)["constraint"]
            if not violation <= FEASIBILITY_TOLERANCE:
                return (
                    f"{PATH_VIOLATION} by {violation:.3g} > {FEASIBILITY_TOLERANCE:g} "
                    f"(the backend reported {result.status!r})"
                )
        return ""

    def _refine(self, result: SolveResult, p: np.ndarray, start: float) -> tuple[SolveResult, str]:
        """Iterate a real-time iteration's plan that breaks a path constraint until it holds.

        One QP holds the constraints linearised at the shifted warm start; the plan's rollout
        can leave them by the linearisation error (mm on the obstacle tutorial).  Further SQP
        steps from the plan, on the same instance, judged after each call, remove that error:
        at most :data:`RTI_REFINEMENTS` calls of the backend's ``solve`` (its ``iterations``
        steps each), within what is left of its deadline (from ``start``, ``perf_counter`` s).
        """
        reason = self._refusal(result, p)
        backend: Preparable = self.backend
        deadline = backend.deadline
        for _ in range(RTI_REFINEMENTS):
            time_limit = None if deadline is None else deadline - (time.perf_counter() - start)
            if time_limit is not None and time_limit <= 0:
                break
            try:
                refined = backend.solve(p, result.iterate, time_limit=time_limit)
            except Exception as error:  # the fallback handles it
                reraise_interrupt(error)
                break
            if not isinstance(refined, SolveResult):
                break
            result, reason = refined, self._refusal(refined, p)
            if not reason.startswith(PATH_VIOLATION):
                break
        return result, reason

    def _holds_path_constraints(self, plan: DeferredPlan, p: np.ndarray) -> bool:
        """Whether a fast path's plan passes the judge's path-constraint test (module doc)."""
        if not self.path_constrained:
            return True
        controls = self.problem.controls_from_scaled(plan.iterate().scaled_controls)
        return bool(self._violations(controls, p)["constraint"] <= FEASIBILITY_TOLERANCE)

    @property
    def path_constrained(self) -> bool:
        """Whether the problem has hard path constraints (every hard one but terminal equalities)."""
        if self._path_constrained is None:
            self._path_constrained = any(
                c.soft is None and not (c.place == "terminal" and np.all(c.equality))
                for c, _ in self.problem.spec().constraints
            )
        return self._path_constrained

    def _violations(self, plan: np.ndarray, p: np.ndarray) -> dict[str, float]:
        """Return the judge's largest violations of ``plan`` (physical, (N, nu)) on instance ``p``."""
        scaled = self.problem.spec().scaled(np.asarray(plan, dtype=float)).ravel()
        _, kinds = score_terms(self.problem, scaled, p)
        return kinds

    def feedback_control(self, x: object) -> np.ndarray:
        """Return ``feedback(x).control`` (deprecated: call that; the same control by the same path)."""
        warnings.warn(
            "NMPC.feedback_control(x) is deprecated: call NMPC.feedback(x).control",
            DeprecationWarning,
            stacklevel=2,
        )
        record = self.feedback(x)
        self.last_output = None if record.fast_path else record
        return record.control

    def step_control(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> np.ndarray:
        """Return ``step(x, t, ...).control`` (deprecated: call that; the same control by the same path)."""
        warnings.warn(
            "NMPC.step_control(x, t, ...) is deprecated: call NMPC.step(x, t, ...).control",
            DeprecationWarning,
            stacklevel=2,
        )
        record = self.step(x, t, u_prev, current, parameters)
        self.last_output = None if record.fast_path else record
        return record.control

    def _accept(self, plan: np.ndarray, iterate: Iterate, u_prev: object | None) -> np.ndarray:
        """Keep a fresh ``plan`` (physical controls) and its shifted warm start; the control to apply.

        A warm start with a non-finite number (e.g. a multiplier of an overflowed QP under
        finite controls) is not kept: the next step starts cold, as after :meth:`reset`.
        """
        self._plan = plan
        self._iterate = iterate.shift() if iterate.is_finite() else None
        return self._admissible(plan[0], u_prev)

    def _admissible(self, control: np.ndarray, u_prev: object | None) -> np.ndarray:
        """``control`` projected on the box and on the rate bound around ``u_prev``.

        Exact solvers hold both to their tolerance (~1e-8 relative); the projection makes the
        applied control hold them exactly, so the plant never sees a bound violated.
        """
        if self._bounds is None:  # the problem's box and rate step, gathered once
            spec = self.problem.spec()
            self._bounds = (spec.lower, spec.upper, spec.max_rate * spec.dt)
        lower, upper, step = self._bounds  # not written to: np.maximum/minimum make new arrays
        if u_prev is not None:
            previous = np.asarray(u_prev, dtype=float)
            low = previous - step  # fresh arrays, so the maxima below can be written into them
            np.maximum(lower, low, out=low)
            high = previous + step
            np.minimum(upper, high, out=high)
            np.maximum(low, high, out=high)  # the same operations as before, fewer temporaries
            return np.minimum(np.maximum(control, low), high)
        # np.clip's values (NaN included) without its dispatch, which costs more than the
        # arithmetic on a few controls
        return np.minimum(np.maximum(control, lower), np.maximum(lower, upper))

    def _fallback_control(self, p: np.ndarray) -> tuple[np.ndarray, str]:
        """Return the fallback's control and which plan it comes from (module doc); keep that plan.

        Candidates in order: the shifted previous plan, the steady control ramped to at the
        rate bound, on a tracking problem the braking control ramped to at the rate bound, the
        last control held; the first the judge finds admissible on ``p``
        (box, rate bound against the last applied control, hard path constraints), else the
        least violating.
        """
        spec = self.problem.spec()
        last = spec.physical(self.problem.previous_scaled(p))
        previous = self._plan

        def candidates() -> Iterator[tuple[str, np.ndarray]]:
            """Yield the plans in order, each built only when the ones before it were not admissible."""
            if previous is not None:
                yield "shifted plan", np.vstack([previous[1:], previous[-1:]])
            steady = self._steady_control(p, last)
            if steady is not None:
                yield "steady control", self._ramp(last, steady)
            if isinstance(self.problem, TrackingProblem):
                braking = self._steady_control(p, last, braking=True)
                if braking is not None:
                    yield "braking control", self._ramp(last, braking)
            yield "held control", np.tile(last, (spec.horizon, 1))

        best: tuple[float, str, np.ndarray] | None = None
        for source, plan in candidates():
            kinds = self._violations(plan, p)
            violation = max(kinds["bound"], kinds["rate"], kinds["constraint"])
            if violation <= FEASIBILITY_TOLERANCE:
                best = (violation, source, plan)
                break
            if best is None or violation < best[0]:  # NaN never replaces a number
                best = (violation, source, plan)
        else:
            assert best is not None
            best = (best[0], f"{best[1]} (least violation)", best[2])
        assert best is not None
        _, source, plan = best
        # only a solver's plan is carried on: the steady control is recomputed at every step
        # from the measured state, never replayed open loop
        self._plan = plan if source.startswith("shifted plan") else None
        return plan[0].copy(), source

    def _ramp(self, last: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Plan (N, nu) moving from ``last`` toward ``target`` at the rate bound, then holding it."""
        spec = self.problem.spec()
        step = spec.max_rate * spec.dt
        plan = np.empty((spec.horizon, spec.control_size))
        previous = last
        for k in range(spec.horizon):
            previous = np.clip(target, previous - step, previous + step)
            plan[k] = previous
        return plan

    @staticmethod
    def _steady_function(spec: Any) -> tuple[ca.Function, np.ndarray]:
        """Return ``(x, u, p) -> (f_v, ∂f_v/∂u)`` of the control-driven dynamics rows ``v``, and ``v``."""
        x = ca.SX.sym("x", spec.state_dim)
        u = ca.SX.sym("u", spec.control_size)
        parameters = ca.SX.sym("p", spec.layout.size)
        _, _, pg, nodes = parameter_blocks(spec, parameters)
        rate = spec.dynamics(x, u, nodes[0], pg)
        jacobian = ca.jacobian(rate, u)
        rows = np.unique(np.array(jacobian.sparsity().get_triplet()[0], dtype=int))
        if rows.size == 0:  # the controls drive nothing directly: nothing to hold
            rows = np.arange(spec.state_dim)
        function = ca.Function("steady_control", [x, u, parameters], [rate[rows], jacobian[rows, :]])
        return function, rows

    def _steady_control(self, p: np.ndarray, start: np.ndarray, braking: bool = False) -> np.ndarray | None:
        """Return the steady control of ``p`` (module doc), clipped to the box; ``None`` if not finite.

        ``braking``: the braking control instead (module doc): the rows ``f_v`` at the measured
        state are fitted to ``−x_v / dt`` (the driven velocities stopped within one interval).

        Least squares of ``f_v(x_s, u)`` over the control box, linearised at ``start`` (and
        relinearised, for a model not affine in the controls): ``f_v`` are the rows of the
        dynamics (at node 0, with its current) that depend on the controls, ``x_s`` the measured
        state with those rows replaced by the reference's (a tracking problem).
        """
        spec = self.problem.spec()
        if self._steady is None:
            with BUILD_LOCK:  # CasADi expressions are built here (uuv_ocp._concurrency)
                self._steady = self._steady_function(spec)
        function, rows = self._steady
        layout = getattr(getattr(self.problem, "vehicle", None), "layout", None)
        if braking and not set(rows.tolist()) <= set(getattr(layout, "velocities", ())):
            # −x_v/dt means "stop" only for velocity rows; a driven actuator state (a thruster's
            # lag) would be switched off and the vehicle left coasting: no braking control then
            return None
        state = np.array(p[spec.layout.x0], dtype=float)
        target = -state[rows] / spec.dt if braking else np.zeros(rows.size)
        if isinstance(self.problem, TrackingProblem) and not braking:  # hold the reference's velocities
            state[rows] = self.problem.parameter_parts(p)[1][0][rows]
        scale = spec.control_scale
        # the box in scaled controls z (u = centre + scale z): every column of the same order
        lower, upper = (spec.scaled_lower, spec.scaled_upper)
        regularisation = np.sqrt(STEADY_REGULARISATION) * np.eye(spec.control_size)
        z = np.clip(spec.scaled(np.asarray(start, dtype=float)), lower, upper)
        for _ in range(STEADY_ITERATIONS):
            values = function(state, spec.physical(z), p)
            residual, derivative = (np.array(value, dtype=float) for value in values)
            residual = residual.ravel() - target
            if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(derivative))):
                return None
            slope = derivative * scale  # d f_v / d z
            # f_v(z') ≈ residual + slope (z' − z): the box-constrained least squares of the model's
            # linearisation (exact for the UUV models, affine in the controls), ties broken
            # toward small controls by a tiny Tikhonov term (more thrusters than driven rows)
            solution = lsq_linear(
                np.vstack([slope, regularisation]),
                np.concatenate([slope @ z - residual.ravel(), np.zeros(spec.control_size)]),
                bounds=(lower, upper),
                method="bvls",
            )
            z = np.clip(solution.x, lower, upper)
        control = spec.physical(z)
        return control if np.all(np.isfinite(control)) else None
