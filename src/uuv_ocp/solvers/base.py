"""The typed backend protocol every solver implements (checked by the registry), and interrupt handling."""

from __future__ import annotations

import abc
import inspect
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from uuv_ocp.solvers.result import Iterate, SolveResult

# what CasADi reports when SIGINT arrives inside a plugin (checkInterrupted), by message or status
_INTERRUPT_MARKERS = ("KeyboardInterrupt", "Interrupted by user", "User_Requested_Stop", "user_interrupt")


@runtime_checkable
class Backend(Protocol):
    """What :func:`~uuv_ocp.solve`, :class:`~uuv_ocp.control.mpc.NMPC` and the hybrids call on a backend.

    A backend is built as ``factory(problem, options)`` (see
    :func:`~uuv_ocp.solvers.register_solver`, which checks the factory's product against this
    protocol: :func:`check_backend`) and never writes into the problem.  ``solve`` never raises
    on a solver failure: it returns ``success=False`` with the reason in ``status``.

    Attributes
    ----------
    name : str
        The registered name.
    time_limited : bool
        Declared capability: ``True`` when ``solve`` also takes ``time_limit=seconds`` (a
        budget for that call, from the call; :class:`TimeLimited`).  A hybrid or multi-start
        with a ``deadline`` needs it of its halves; a backend without the attribute has not
        got it.

    Optional hook: ``reset()`` (no arguments), called by :meth:`NMPC.reset
    <uuv_ocp.control.mpc.NMPC.reset>` (and so before every :func:`~uuv_ocp.simulate` run of a
    warmed-up controller): forget whatever the backend keeps from one solve to the next (warm
    starts, solver memory), so that its next solve is the one a freshly built backend would
    take; what it built (compiled code, NLPs) stays.  ``sqp-rti``: its C steps' memory.
    """

    name: str

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
    ) -> SolveResult:
        """Solve the instance with parameter vector ``p``; never raise on a solver failure."""
        ...


@runtime_checkable
class TimeLimited(Backend, Protocol):
    """A :class:`Backend` that declares ``time_limited = True`` and takes ``time_limit=`` (s)."""

    time_limited: bool

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
    ) -> SolveResult:
        """Solve within ``time_limit`` seconds from the call (``None``: the backend's own deadline)."""
        ...


def takes_time_limit(backend: object) -> bool:
    """Whether ``backend`` declares the ``time_limit`` capability (``time_limited = True``)."""
    return getattr(backend, "time_limited", False) is True


def check_backend(backend: object, name: str) -> None:
    """Raise ``TypeError`` unless ``backend`` (an instance or a class) conforms to :class:`Backend`.

    Checks that ``solve`` is a method taking ``(p, warm_start, rng)``, that a declared
    ``time_limited = True`` goes with a ``time_limit`` keyword, and, for an instance, that
    ``name`` is a string.  Read once, when the backend is registered or first built.
    """
    kind = backend if isinstance(backend, type) else type(backend)
    solve = getattr(backend, "solve", None)
    if not callable(solve):
        raise TypeError(
            f"solver {name!r}: {kind.__name__} has no solve(p, warm_start, rng) method "
            "(the uuv_ocp.solvers.base.Backend protocol)"
        )
    try:
        signature = inspect.signature(solve)
    except (TypeError, ValueError):  # a builtin without a signature: nothing more to read
        return
    parameters = list(signature.parameters.values())
    if isinstance(backend, type) and parameters:
        parameters = parameters[1:]  # self of a plain function on the class
    variadic = any(q.kind is inspect.Parameter.VAR_POSITIONAL for q in parameters)
    positional = [
        q
        for q in parameters
        if q.kind in (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    ]
    if not variadic and len(positional) < 3:
        raise TypeError(
            f"solver {name!r}: {kind.__name__}.solve{signature} must take (p, warm_start, rng) "
            "(the uuv_ocp.solvers.base.Backend protocol)"
        )
    keywords = any(q.kind is inspect.Parameter.VAR_KEYWORD for q in parameters)
    if takes_time_limit(backend) and not (keywords or "time_limit" in signature.parameters):
        raise TypeError(
            f"solver {name!r}: {kind.__name__} declares time_limited = True but its "
            f"solve{signature} takes no time_limit keyword"
        )
    if not isinstance(backend, type) and not isinstance(getattr(backend, "name", None), str):
        raise TypeError(
            f"solver {name!r}: {kind.__name__} has no name attribute (a str; the Backend protocol)"
        )


class DeferredPlan(abc.ABC):
    """A fresh plan that a :class:`Preparable` backend's ``feedback`` took by a fast path.

    Its first control is there at once; its warm start and its :class:`SolveResult` (with the
    judge's cost and violation) are built only when asked for, from copies taken at the step:
    a closed loop that needs only the control pays for neither (for ``sqp-rti``'s C step they
    cost more than the C call itself: docs/benchmarks.md).  Implementations are immutable records.
    """

    __slots__ = ()

    #: the plan's first control (physical units, within the control box)
    control: np.ndarray
    #: which fast path took the step, e.g. ``"resident C step"`` (shown in the step's record)
    path: str

    def finite_control(self) -> bool:
        """Whether every entry of :attr:`control` is finite (NMPC refuses a plan whose control is not)."""
        return bool(np.isfinite(self.control).all())

    @abc.abstractmethod
    def iterate(self) -> Iterate:
        """Return the plan's warm start, unshifted: what ``result().iterate`` is."""

    @abc.abstractmethod
    def result(self) -> SolveResult:
        """Return the :class:`SolveResult` the backend's ``solve`` reports for this plan."""


@runtime_checkable
class Preparable(Protocol):
    """A backend with a real-time iteration's two phases (``"sqp-rti"``); what NMPC calls on it.

    :class:`~uuv_ocp.control.mpc.NMPC` checks ``isinstance(backend, Preparable)`` once, when the
    backend is set, and then calls these methods instead of ``solve`` alone:

    - ``prepare(p, warm_start)`` before the state is measured (``p``'s state part a guess:
      the warm start's first state); the backend keeps what it prepared for the next
      ``feedback``.  A preparation that raises only costs speed (NMPC drops it).
    - ``feedback(p, warm_start)`` with the measured instance: the step's plan, from the kept
      preparation where it applies, else the whole step by the backend's fastest path (a
      :class:`DeferredPlan`), else its ``solve``.  ``warm_start`` is the shifted
      :class:`Iterate`, or the :class:`DeferredPlan` the previous ``feedback`` returned (the
      backend shifts it itself).  A failure is a :class:`SolveResult` with ``success=False``.
    - ``solve(p, warm_start, time_limit=...)`` further iterations from a plan the judge refused,
      within what is left of ``deadline`` (seconds, ``None``: no deadline).
    """

    deadline: float | None

    def prepare(self, p: np.ndarray, warm_start: Iterate | None) -> object:
        """Prepare the step on instance ``p`` (its state a guess) from ``warm_start``; keep it."""
        ...

    def feedback(
        self, p: np.ndarray, warm_start: Iterate | DeferredPlan | None
    ) -> SolveResult | DeferredPlan:
        """Return the plan of the measured instance ``p``; never raise on a solver failure."""
        ...

    def solve(
        self,
        p: np.ndarray,
        warm_start: Iterate | None = None,
        rng: np.random.Generator | None = None,
        *,
        time_limit: float | None = None,
    ) -> SolveResult:
        """Solve instance ``p`` from ``warm_start``, stopping new iterations after ``time_limit`` s."""
        ...


def is_interrupt(error: BaseException | str) -> bool:
    """Whether an exception (or a plugin status) is a keyboard interrupt CasADi turned into text."""
    if isinstance(error, KeyboardInterrupt):
        return True
    text = error if isinstance(error, str) else f"{type(error).__name__}: {error}"
    return any(marker in text for marker in _INTERRUPT_MARKERS)


def reraise_interrupt(error: BaseException | str) -> None:
    """Raise :class:`KeyboardInterrupt` if ``error`` is one in disguise (CasADi's included)."""
    if is_interrupt(error):
        if isinstance(error, BaseException):
            raise KeyboardInterrupt(str(error)) from error
        raise KeyboardInterrupt(error)
