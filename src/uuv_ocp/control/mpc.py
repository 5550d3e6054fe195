"""Receding-horizon NMPC around any registered solver.

Warm starting is explicit: the controller keeps the last :class:`~uuv_ocp.solvers.Iterate`
and shifts it by one interval before the next solve (primal and, for exact solvers, duals;
for swarms the shifted best plan seeds the next population).  :meth:`NMPC.reset` forgets it,
so the same state and time always give the same control after a reset.

Fallback (documented contract): when a solve reports ``success=False`` or returns non-finite
controls, the controller applies the next control of its previous plan (the shifted plan) if
it has one, otherwise it holds the last applied control.  The step is counted in
``ClosedLoopResult.failures`` and the closed loop never stops on a solver failure; the
backend's status or exception is in ``StepOutput.message``.  ``KeyboardInterrupt`` (CasADi's,
raised as a ``RuntimeError`` naming it, included) always propagates.

Deadlines (backend option ``deadline``, seconds; see docs/solvers.md): a step whose backend
reports ``details["deadline_hit"]`` sets ``StepOutput.deadline_hit`` and is counted in
``ClosedLoopResult.deadline_misses``.  An exact solver (or a hybrid's exact stage) stopped by
the deadline reports ``success=False``, so the step takes the fallback above; a swarm stopped by
it returns its best plan so far, which is applied when feasible (``success``) — a swarm is an
anytime method, its plan is ready at the deadline.

Phases: :meth:`NMPC.step` is :meth:`NMPC.prepare` (before the state is measured: the
time, last control and data of the step; a real-time-iteration backend linearises then)
followed by :meth:`NMPC.feedback` (the measured state in, the control out).

Every applied control, fresh or fallback, is projected on the control box and on the rate
bound around the last applied control: the plant never sees a bound violated, whatever the
backend's tolerance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import instance_parameters
from uuv_ocp.solvers import REGISTRY, new_solver
from uuv_ocp.solvers.base import reraise_interrupt
from uuv_ocp.solvers.result import Iterate, SolveResult
from uuv_ocp.solvers.rti import ResidentPlan


@dataclass(frozen=True)
class StepOutput:
    """What one controller step returns.

    Parameters
    ----------
    control : numpy.ndarray, shape (3,)
        Control to apply (N, N, N·m).
    result : SolveResult or None
        The solver's result (``None`` if the solver raised).
    fallback : bool
        Whether ``control`` comes from the fallback rather than the fresh solution.
    message : str
        Why the fallback was used: the backend's status, or ``"exception: <type>: <message>"``
        when the backend raised (empty when the fresh solution is applied).
    deadline_hit : bool
        Whether the backend's ``deadline`` option stopped or outlasted this solve
        (``result.details["deadline_hit"]``; see the module doc).
    """

    control: np.ndarray
    result: SolveResult | None
    fallback: bool
    message: str = ""
    deadline_hit: bool = False


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
        self.problem = problem
        self.solver_name = REGISTRY.resolve(solver)  # the registered spelling: "IPOPT" -> "ipopt"
        # a backend of its own: solver memory, buffers and warm starts are never shared
        self.backend = new_solver(problem, solver, options)
        if seed is not None:
            seed = check.positive_int("seed", seed, minimum=0)
        self.seed = seed
        self.use_warm_start = check.boolean("warm_start", warm_start)
        self._rng = np.random.default_rng(seed)
        self._iterate: Iterate | None = None
        self._plan: np.ndarray | None = None
        self._pending: tuple[Any, ...] | None = None
        self._prepared_p: np.ndarray | None = None  # the instance prepare() linearised
        # the last plan of a step_control step taken by sqp-rti's C step from its resident warm
        # start (kept instead of _iterate/_plan until another path needs those: _materialize)
        self._resident: ResidentPlan | None = None
        self._token = object()  # this controller, as the owner of a C step's resident warm start
        self._bounds: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # see _admissible
        #: the last :meth:`feedback_control` step's output (None after a step by the C step alone)
        self.last_output: StepOutput | None = None

    def reset(self) -> None:
        """Forget the warm start and the previous plan; restart the random generator."""
        self._iterate = None
        self._plan = None
        self._resident = None
        self._pending = None
        self._prepared_p = None
        self._rng = np.random.default_rng(self.seed)

    @property
    def iterate(self) -> Iterate | None:
        """The warm start the next :meth:`step` will use (already shifted)."""
        if self._resident is not None:
            return self._from_resident()[1].shift()
        return self._iterate

    def _from_resident(self) -> tuple[np.ndarray, Iterate]:
        """Return the plan (physical controls) and unshifted iterate of the last resident C step."""
        assert self._resident is not None
        iterate = self.backend.resident_iterate(self._resident)
        return self.problem.controls_from_scaled(iterate.scaled_controls), iterate

    def _materialize(self) -> None:
        """Turn the plan of the last resident C step into ``_iterate`` and ``_plan``."""
        if self._resident is not None:
            self._plan, iterate = self._from_resident()
            self._iterate = iterate.shift()
            self._resident = None

    def step(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> StepOutput:
        """Solve at state ``x`` and time ``t`` and return the control to apply.

        ``current`` is a tracking problem's model current; ``parameters`` an Ocp's data.
        The same as :meth:`prepare` followed by :meth:`feedback` (with ``sqp-rti``'s C step, a
        warm step runs as one C call from the resident warm start, as :meth:`step_control`
        does, and the same :class:`StepOutput` is built from it).
        """
        start = time.perf_counter()
        resident = self._resident_plan(x, t, u_prev, current, parameters)
        if resident is not None:
            plan, p = resident
            result = self.backend.resident_result(p, plan, time.perf_counter() - start)
            return StepOutput(self._admissible(plan.control, u_prev), result, False)
        self.prepare(t, u_prev, current, parameters)
        return self.feedback(x)

    def prepare(
        self,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> None:
        """Run the preparation phase of the next step, before its state is measured.

        Stores the step's time, last control, current and parameters.  A backend with a
        preparation phase (``"sqp-rti"``: linearisation at the shifted previous iterate) runs
        it now, with the warm start's predicted first state standing in for the measurement;
        :meth:`feedback` then only solves the QP.  Other backends do all their work in
        :meth:`feedback`.  Without a warm start nothing is prepared; a preparation that raises
        is dropped (``KeyboardInterrupt`` excepted), and :meth:`feedback` then solves afresh,
        reporting any failure as a step's failure.
        """
        self._materialize()
        self._pending = (t, u_prev, current, parameters)
        self._prepared_p = None
        prepare = getattr(self.backend, "prepare", None)
        warm = self._iterate if self.use_warm_start else None
        if prepare is None or warm is None:
            return
        guess = warm.states[0]
        p = instance_parameters(self.problem, guess, t, u_prev=u_prev, current=current, parameters=parameters)
        try:
            prepare(p, warm)
        except Exception as error:  # a failed preparation only costs speed: feedback solves afresh
            reraise_interrupt(error)
            return
        self._prepared_p = p

    def feedback(self, x: object) -> StepOutput:
        """Run the feedback phase: the measured state ``x`` in, the control to apply out.

        Uses the time, last control, current and parameters given to :meth:`prepare` (which
        must come first; ``ValueError`` otherwise).
        """
        u_prev, p = self._measured_instance(x)
        return self._solve_step(p, u_prev)

    def _measured_instance(self, x: object) -> tuple[object | None, np.ndarray]:
        """Consume :meth:`prepare`'s arguments: the last control and the instance at state ``x``."""
        if self._pending is None:
            raise ValueError("NMPC.feedback(x) needs NMPC.prepare(t, u_prev, ...) first (or call step)")
        (t, u_prev, current, parameters), self._pending = self._pending, None
        if self._prepared_p is not None:  # the instance of prepare(), its guessed state replaced
            p = self.problem.with_state(self._prepared_p, x)
            self._prepared_p = None
        else:
            p = instance_parameters(self.problem, x, t, u_prev=u_prev, current=current, parameters=parameters)
        return u_prev, p

    def _solve_step(self, p: np.ndarray, u_prev: object | None) -> StepOutput:
        """Solve instance ``p`` and pick the control: the fresh plan's, or the fallback's."""
        warm = self._iterate if self.use_warm_start else None
        feedback = getattr(self.backend, "feedback", None)
        try:
            if feedback is not None:
                result = feedback(p, warm)
            else:
                result = self.backend.solve(p, warm, rng=self._rng)
        except Exception as error:  # a backend crash must never stop a closed loop ...
            reraise_interrupt(error)  # ... but Ctrl-C (CasADi's too) always reaches the user
            result = None
            failure_reason = f"exception: {type(error).__name__}: {error}"
        else:
            failure_reason = "" if result.success and np.all(np.isfinite(result.controls)) else result.status
        late = result is not None and bool(result.details.get("deadline_hit", False))
        if not failure_reason:
            control = self._accept(result.controls, result.iterate, u_prev)
            return StepOutput(control, result, False, deadline_hit=late)
        control = self._admissible(self._fallback_control(u_prev), u_prev)
        if late and result is not None and np.all(np.isfinite(result.iterate.scaled_controls)):
            # the stopped solve's progress warm-starts the next one (iterations carry on across
            # steps, as in real-time iteration schemes); its plan is not applied
            self._iterate = result.iterate.shift()
        elif self._iterate is not None:
            self._iterate = self._iterate.shift()
        return StepOutput(control, result, True, failure_reason, deadline_hit=late)

    def feedback_control(self, x: object) -> np.ndarray:
        """:meth:`feedback`'s control alone, by the shortest path the backend has.

        With ``sqp-rti``'s C step, a prepared step that succeeds goes from the C call straight
        to the control: the same control, warm start and plan as :meth:`feedback`, without the
        :class:`~uuv_ocp.solvers.SolveResult` and its judge (``uuv_ocp.score`` on :attr:`plan`
        gives the judge's numbers when wanted); :attr:`last_output` is then ``None``.  Every
        other step (the cold first one, a failed step, other backends) is :meth:`feedback`, whose
        :class:`StepOutput` (fallback, message, result) is kept in :attr:`last_output`.
        """
        u_prev, p = self._measured_instance(x)
        fast = getattr(self.backend, "feedback_in_c", None)
        step = None
        if fast is not None:
            try:
                step = fast(p, self._iterate if self.use_warm_start else None)
            except Exception as error:  # the general path below solves it again and reports it
                reraise_interrupt(error)
        if step is not None:  # finite by the C step's own test (else it returns None)
            prepared, primal, lam_x, lam_g, _ = step
            variant, backend = prepared.variant, self.backend
            iterate = backend.c_iterate(variant, primal, lam_x, lam_g, backend.relaxed(variant, primal))
            self.last_output = None
            return self._accept(self.problem.controls_from_scaled(iterate.scaled_controls), iterate, u_prev)
        self.last_output = self._solve_step(p, u_prev)
        return self.last_output.control

    def step_control(
        self,
        x: object,
        t: float = 0.0,
        u_prev: object | None = None,
        current: object | None = None,
        parameters: dict[str, Any] | None = None,
    ) -> np.ndarray:
        """Return the control to apply at state ``x`` and time ``t``, by the shortest path there is.

        The control, plan and warm start of :meth:`step`.  With ``sqp-rti``'s C step, a step
        from a warm start is one C call from the C step's resident copy of the last plan,
        shifted in C (:meth:`~uuv_ocp.solvers.rti.RtiSolver.resident_step`), with the
        instance built at the measured state at once: the measured state enters the
        linearisation directly instead of moving a prepared one (bit-equal to :meth:`step` on
        the loops of ``tests/test_rti.py``, where the prepared guess is the warm start's own
        first state).  :attr:`iterate` and :attr:`plan` are built from that plan when read;
        :attr:`last_output` is ``None``.  Every other step
        (the cold first one, a step the C step does not accept, other backends) is
        :meth:`prepare` then :meth:`feedback_control`, with its :class:`StepOutput` in
        :attr:`last_output`.
        """
        resident = self._resident_plan(x, t, u_prev, current, parameters)
        if resident is not None:
            self.last_output = None
            return self._admissible(resident[0].control, u_prev)
        self.prepare(t, u_prev, current, parameters)
        return self.feedback_control(x)

    def _resident_plan(
        self,
        x: object,
        t: float,
        u_prev: object | None,
        current: object | None,
        parameters: dict[str, Any] | None,
    ) -> tuple[ResidentPlan, np.ndarray] | None:
        """Take a step from the C step's resident warm start: its plan and instance, or ``None``.

        ``None`` (nothing taken, the warm start materialised) where the backend has no
        resident step or does not accept this one: the caller then runs the general path.
        """
        if not getattr(self.backend, "resident_available", False) or not self.use_warm_start:
            return None
        if self._resident is None and self._iterate is None:
            return None
        self._pending = self._prepared_p = None
        p = instance_parameters(self.problem, x, t, u_prev=u_prev, current=current, parameters=parameters)
        try:
            plan = self.backend.resident_step(p, self._iterate, self._resident, self._token)
        except Exception as error:  # the general path solves it again and reports it
            reraise_interrupt(error)
            plan = None
        if plan is None:
            self._materialize()
            return None
        self._resident, self._iterate = plan, None
        return plan, p

    @property
    def plan(self) -> np.ndarray | None:
        """The last fresh plan (physical controls, shape (N, nu)), shifted by each fallback step."""
        if self._resident is not None:
            return self._from_resident()[0]
        return self._plan

    def _accept(self, plan: np.ndarray, iterate: Iterate, u_prev: object | None) -> np.ndarray:
        """Keep a fresh ``plan`` (physical controls) and its shifted warm start; the control to apply."""
        self._plan = plan
        self._iterate = iterate.shift()
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
            lower = np.maximum(lower, previous - step)
            upper = np.minimum(upper, previous + step)
        # np.clip's values (NaN included) without its ~5 µs of dispatch
        return np.minimum(np.maximum(control, lower), np.maximum(lower, upper))

    def _fallback_control(self, u_prev: object | None) -> np.ndarray:
        if self._plan is not None and self._plan.shape[0] > 1:
            self._plan = np.vstack([self._plan[1:], self._plan[-1:]])
            return self._plan[0].copy()
        spec = self.problem.spec()
        return np.zeros(spec.control_size) if u_prev is None else np.asarray(u_prev, dtype=float)
