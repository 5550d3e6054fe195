"""The typed backend protocol every solver implements, and interrupt handling shared by all."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from uuv_ocp.solvers.result import Iterate, SolveResult

# what CasADi reports when SIGINT arrives inside a plugin (checkInterrupted), by message or status
_INTERRUPT_MARKERS = ("KeyboardInterrupt", "Interrupted by user", "User_Requested_Stop", "user_interrupt")


@runtime_checkable
class Backend(Protocol):
    """What :class:`~uuv_ocp.control.mpc.NMPC` and :func:`~uuv_ocp.solve` call on a backend.

    A backend is built as ``factory(problem, options)`` (see
    :func:`~uuv_ocp.solvers.register_solver`) and never writes into the problem.
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
