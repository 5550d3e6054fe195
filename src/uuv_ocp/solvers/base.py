"""The typed backend protocol every solver implements (checked by the registry), and interrupt handling."""

from __future__ import annotations

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
