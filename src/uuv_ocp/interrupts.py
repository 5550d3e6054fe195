"""Ctrl-C that CasADi swallowed, delivered at the next safe point.

CasADi's SWIG wrappers pick an overload by trying argument conversions and treat *any*
exception raised meanwhile as "this overload does not fit", ``KeyboardInterrupt`` included: a
Ctrl-C that lands while a problem is being built symbolically (``casadi.plus`` converting its
arguments, measured: about 1 SIGINT in 6 during a campaign of short trials) vanishes, and the
run goes on as if nothing had happened.

:func:`remember_interrupts` wraps the current SIGINT handler so that every SIGINT is also
remembered; :func:`check_interrupt` raises ``KeyboardInterrupt`` for one that was remembered but
never reached Python code.  Long jobs call it between units of work (every closed-loop step,
every trial, every reference).  SIGINT is process-wide, so is the memory of it: one event,
set only by the handler and cleared where a ``KeyboardInterrupt`` is handled.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

_PENDING = threading.Event()


@contextlib.contextmanager
def remember_interrupts() -> Iterator[None]:
    """Remember every SIGINT while the block runs (main thread only; an ignored SIGINT stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # SIG_IGN or SIG_DFL: the user's choice, not ours to change
        yield
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        _PENDING.set()
        previous(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    except KeyboardInterrupt:
        _PENDING.clear()  # it reached Python: handled here, not again later
        raise
    finally:
        signal.signal(signal.SIGINT, previous)


def check_interrupt() -> None:
    """Raise ``KeyboardInterrupt`` if a SIGINT was remembered but swallowed on its way."""
    if _PENDING.is_set():
        _PENDING.clear()
        raise KeyboardInterrupt("Ctrl-C (it arrived inside CasADi, which swallowed it)")


def interrupt_handled() -> None:
    """Forget the remembered SIGINT: the ``KeyboardInterrupt`` it raised was caught and acted on."""
    _PENDING.clear()
