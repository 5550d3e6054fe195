"""A watched plugin call: an NLP plugin that cannot be stopped from inside runs in a child process.

CasADi 3.8's ``fatrop`` (and ``blocksqp``) call no iteration callback and take no time limit,
and fatrop can loop for good inside one iteration: on a BlueROV2 Heavy holding station in a
1.5 m/s current its restoration phase's search direction never returned (16 min inside
``libfatrop``, ``max_iter`` never reached because the iteration never ended).  Nothing inside the
process can stop a C++ loop, so such a plugin runs in a forked worker process that the caller
can kill.

The worker is forked once (it inherits the built ``nlpsol`` Functions, nothing is rebuilt) and
then serves one call per request over pipes, so a call costs two pipe round trips, not a fork.
Its file descriptor 1 is a pipe to the caller: the plugin's own iteration lines (fatrop at
``print_level`` 5: one line per iteration, restoration included) are its progress report, read
as they come.  The caller kills the worker (``SIGKILL``) when

- the deadline has passed (``at``, a :func:`now` time),
- the plugin printed more than ``max_iter`` iterations (restoration iterations count, as in
  IPOPT's ``max_iter``; fatrop's own limit counts only the others), or
- no iteration line came for ``stall`` seconds (one iteration that never ends);

the call then raises :class:`Stopped` and the next call forks a fresh worker.  ``KeyboardInterrupt``
in the caller kills the worker and propagates.  Where ``os.fork`` is missing (Windows) nothing is
watched: the plugin runs in the calling process.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import pickle
import re
import select
import signal
import struct
import sys
import time
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

#: the clock of deadlines and stall limits (tests replace it to expire a deadline on cue)
now: Callable[[], float] = time.perf_counter

# an iteration line of fatrop's output: the iteration number, "r" in the restoration phase
_ITERATION_LINE = re.compile(rb"^\s*(\d+)r?\s+[-+0-9.eE]+\s")
_HEADER = struct.Struct("<Q")
CAN_WATCH = hasattr(os, "fork")


class Stopped(Exception):
    """The watched call was stopped; ``reason`` is ``"deadline"``, ``"max_iter"`` or ``"stall"``."""

    def __init__(self, reason: str, iterations: int, message: str) -> None:
        super().__init__(message)
        self.reason = reason
        self.iterations = iterations


class CrashedWorker(Exception):
    """The worker died without an answer (a signal inside the plugin, or a lost pipe)."""


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]


def _read_exactly(fd: int, size: int) -> bytes:
    chunks = []
    while size:
        chunk = os.read(fd, size)
        if not chunk:
            raise EOFError
        chunks.append(chunk)
        size -= len(chunk)
    return b"".join(chunks)


def _kill(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)


class Worker:
    """One forked process serving ``functions[key](*args)`` calls (see module doc).

    Parameters
    ----------
    functions : callable
        ``key -> callable``: the Function of a key (called in the worker; what was built
        before the fork is inherited, anything else is built there).
    """

    def __init__(self, functions: Callable[[Any], Any]) -> None:
        self._functions = functions
        self._pid: int | None = None
        self._fds: tuple[int, int, int] = (-1, -1, -1)  # request (write), answer, progress (read)
        self._finalizer: weakref.finalize | None = None
        #: the largest iteration number the last finished call printed (its progress as seen)
        self.iterations_seen = 0

    @property
    def alive(self) -> bool:
        """Whether a worker process is running."""
        return self._pid is not None

    def restart(self) -> None:
        """Stop the worker; the next call forks a new one (which inherits what was built since)."""
        if self._finalizer is not None:
            self._finalizer()
        self._pid, self._fds, self._finalizer = None, (-1, -1, -1), None

    def _fork(self) -> None:
        _flush_c_stdout()  # what C buffered belongs to the real stdout, not to a copy in the worker
        request_r, request_w = os.pipe()
        answer_r, answer_w = os.pipe()
        progress_r, progress_w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the worker: never returns
            code = 0
            try:
                for fd in (request_w, answer_r, progress_r):
                    os.close(fd)
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle
                _die_with_parent()  # a hung plugin must not outlive a caller killed by SIGKILL
                os.dup2(progress_w, 1)
                _line_buffered_c_stdout()  # a pipe is fully buffered: progress must come per line
                # CasADi prints a plugin's output through Python's sys.stdout (which a test
                # runner may have replaced): make that the pipe too, line by line
                sys.stdout = io.TextIOWrapper(
                    io.FileIO(1, "w", closefd=False), line_buffering=True, write_through=True
                )
                self._serve(request_r, answer_w)
            except BaseException:  # noqa: BLE001 - a worker reports by dying; the caller sees EOF
                code = 1
            finally:
                os._exit(code)
        for fd in (request_r, answer_w, progress_w):
            os.close(fd)
        self._pid, self._fds = pid, (request_w, answer_r, progress_r)
        self._finalizer = weakref.finalize(self, _shut, pid, (request_w, answer_r, progress_r))

    def _serve(self, requests: int, answers: int) -> None:
        while True:
            try:
                (size,) = _HEADER.unpack(_read_exactly(requests, _HEADER.size))
                key, args = pickle.loads(_read_exactly(requests, size))
            except EOFError:  # the caller is gone
                return
            function = self._functions(key)
            outputs = function(*args)
            stats = {k: v for k, v in function.stats().items() if isinstance(v, bool | int | float | str)}
            sys.stdout.flush()
            _flush_c_stdout()
            os.write(1, b"\n")  # end of this call's progress lines
            payload = pickle.dumps((outputs, stats), protocol=pickle.HIGHEST_PROTOCOL)
            _write_all(answers, _HEADER.pack(len(payload)) + payload)

    def call(
        self,
        key: Any,
        args: tuple[np.ndarray, ...],
        *,
        at: float = math.inf,
        max_iter: int | None = None,
        stall: float | None = None,
    ) -> tuple[list[np.ndarray], dict[str, Any]]:
        """Return the outputs and scalar stats of ``functions[key](*args)`` run in the worker.

        Raises
        ------
        Stopped
            The deadline ``at`` passed, more than ``max_iter`` iterations were printed, or none
            for ``stall`` seconds: the worker was killed.
        CrashedWorker
            The worker died on its own.
        """
        payload = pickle.dumps((key, args), protocol=pickle.HIGHEST_PROTOCOL)
        request = _HEADER.pack(len(payload)) + payload
        if self._pid is not None:
            try:
                _write_all(self._fds[0], request)
            except OSError:  # the idle worker is gone (e.g. its forking thread ended): a new one
                self.restart()
        if self._pid is None:
            self._fork()
            _write_all(self._fds[0], request)
        request_w, answer_r, progress_r = self._fds
        pending = b""
        iterations = 0
        try:
            last = now()
            while True:
                current = now()
                limits = [at - current]
                if stall is not None:
                    limits.append(last + stall - current)
                wait = min(limits)
                if wait <= 0.0:
                    reason = "deadline" if at - current <= 0.0 else "stall"
                    raise self._stop(reason, iterations, stall)
                ready, _, _ = select.select([answer_r, progress_r], [], [], min(wait, 3600.0))
                if progress_r in ready:
                    chunk = os.read(progress_r, 65536)
                    if chunk:
                        *lines, pending = (pending + chunk).split(b"\n")
                        for line in lines:  # the clock is read at every iteration line
                            match = _ITERATION_LINE.match(line)
                            if match:
                                iterations = max(iterations, int(match.group(1)))
                                last = now()
                                if last >= at:
                                    raise self._stop("deadline", iterations, stall)
                                if max_iter is not None and iterations > max_iter:
                                    raise self._stop("max_iter", iterations, stall)
                if answer_r in ready:
                    try:
                        (size,) = _HEADER.unpack(_read_exactly(answer_r, _HEADER.size))
                        outputs, stats = pickle.loads(_read_exactly(answer_r, size))
                    except EOFError as error:
                        self.restart()
                        raise CrashedWorker("the worker process died inside the plugin") from error
                    self._drain(progress_r)
                    self.iterations_seen = iterations
                    return outputs, stats
        except BaseException:
            if self._pid is not None:  # KeyboardInterrupt, Stopped, a broken pipe: never reuse it
                self.restart()
            raise

    def _stop(self, reason: str, iterations: int, stall: float | None) -> Stopped:
        self.restart()
        text = {
            "deadline": "the deadline passed",
            "max_iter": f"more than max_iter iterations ({iterations}, restoration included)",
            "stall": f"no iteration finished for {stall:g} s" if stall is not None else "stalled",
        }[reason]
        return Stopped(reason, iterations, f"killed by the watchdog: {text}")

    @staticmethod
    def _drain(progress_r: int) -> None:
        """Consume what is left of this call's progress lines (up to the worker's end marker)."""
        while select.select([progress_r], [], [], 0.0)[0]:
            if not os.read(progress_r, 65536):
                return


def _libc() -> Any:
    import ctypes

    return ctypes.CDLL(None)


def _flush_c_stdout() -> None:
    with contextlib.suppress(OSError, AttributeError):
        _libc().fflush(None)


def _line_buffered_c_stdout() -> None:
    import ctypes

    with contextlib.suppress(OSError, AttributeError, ValueError):
        libc = _libc()
        stream = ctypes.c_void_p.in_dll(libc, "stdout")
        libc.setvbuf(stream, None, 1, 0)  # _IOLBF


def _die_with_parent() -> None:
    """Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, so the worker dies with the caller (elsewhere: no-op)."""
    with contextlib.suppress(OSError, AttributeError):
        _libc().prctl(1, int(signal.SIGKILL), 0, 0, 0)


def _shut(pid: int, fds: tuple[int, ...]) -> None:
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)
    _kill(pid)
