"""Where campaign trials run: processes on this machine, or a Dask cluster.

Both executors run the same picklable task function and hand back ``(key, result)`` pairs as
tasks finish; the caller (the campaign driver) is the only one that writes records, so a
worker that dies, is killed or is interrupted never leaves a record behind.

* ``"local"``: ``workers`` processes on this machine (a spawn-context
  :class:`concurrent.futures.ProcessPoolExecutor`); ``workers=1`` runs in this process, in
  order.  Workers ignore SIGINT (Ctrl-C stops the driver, which stops them) and die with their
  parent: on Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, elsewhere a thread that polls the
  parent's pid.  ``"process"`` is an alias kept from earlier versions (the pool even for
  ``workers=1``).  A worker that dies (killed, out of memory, a crash in native code) breaks
  the pool; the runner starts a new one and reruns the tasks that were running, each alone
  first so that the one that kills its worker is known; a task whose worker dies
  :data:`MAX_TRIES` times is handed back as a :class:`WorkerCrashed` instead of a result.
* ``"dask"``: :mod:`dask.distributed` (the ``dask`` extra): a :class:`~distributed.LocalCluster`
  of ``workers`` single-threaded worker processes, or the cluster whose scheduler is at
  ``scheduler`` (``tcp://host:port``), which must answer within :data:`DASK_CONNECT_TIMEOUT`
  (else :class:`SchedulerUnreachable`).  A task lost with a dead worker is rerun elsewhere by
  the scheduler.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from types import TracebackType
from typing import Any

EXECUTORS = ("local", "process", "dask")
DASK_HINT = "pip install 'uuv_ocp[dask]' (or: pip install 'dask[distributed]')"
_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
#: Tries of a task whose local worker process dies under it before it is given up.
MAX_TRIES = 3
#: Seconds to reach a Dask scheduler given by address (dask's own default is 30 s).  A scheduler
#: that is up answers in milliseconds, even across a network; 10 s leaves room for a slow link.
DASK_CONNECT_TIMEOUT = 10.0


class SchedulerUnreachable(ConnectionError):
    """The Dask scheduler given by address did not answer (the message names it)."""

    def __str__(self) -> str:
        """Return the one-line message."""
        return str(self.args[0]) if self.args else ""


class WorkerCrashed(RuntimeError):
    """A task's worker process died every time the task ran (:data:`MAX_TRIES` times)."""


class WorkerRestartWarning(UserWarning):
    """A local worker process died; the pool was restarted and its tasks are rerun."""


def require_dask() -> Any:
    """Return the :mod:`dask.distributed` module, or a one-line ``ValueError`` saying how to install it."""
    try:
        import dask.distributed
    except ImportError:
        raise ValueError(
            f"executor 'dask' needs dask.distributed, which is not installed: {DASK_HINT}"
        ) from None
    return dask.distributed


def die_with_parent(parent: int) -> None:
    """Make this process end when process ``parent`` ends (worker initializer; also ignores SIGINT)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    else:
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


class TaskRunner:
    """Context manager running tasks on one executor (see the module doc).

    Parameters
    ----------
    executor : {"local", "process", "dask"}
    workers : int
        Worker processes (local pool, or the Dask ``LocalCluster``), >= 1.
    scheduler : str, optional
        Address of a running Dask scheduler; only with ``executor="dask"``.
    on_restart : callable, optional
        ``on_restart(message, keys)``: called when the local pool was restarted after a worker
        died, with a one-line message and the keys of the tasks that are rerun.
    """

    def __init__(
        self,
        executor: str,
        workers: int,
        scheduler: str | None = None,
        on_restart: Callable[[str, list], None] | None = None,
    ) -> None:
        self.executor, self.workers, self.scheduler = executor, workers, scheduler
        self.on_restart = on_restart
        self._stack = contextlib.ExitStack()
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._client: Any = None

    def __enter__(self) -> TaskRunner:
        """Start the workers (a pool, a LocalCluster, or a client of ``scheduler``)."""
        if self.executor == "dask":
            distributed = require_dask()
            if self.scheduler is None:
                cluster = self._stack.enter_context(
                    distributed.LocalCluster(
                        n_workers=self.workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                        silence_logs=40,  # logging.ERROR: a rescheduled task is not the user's problem
                    )
                )
                self._client = self._stack.enter_context(distributed.Client(cluster))
            else:
                try:
                    client = distributed.Client(self.scheduler, timeout=DASK_CONNECT_TIMEOUT)
                except (OSError, TimeoutError) as error:  # dask says "Timed out trying to connect"
                    self._stack.close()
                    raise SchedulerUnreachable(
                        f"no Dask scheduler answered at {self.scheduler} within {DASK_CONNECT_TIMEOUT:g} s "
                        f"({type(error).__name__}: {' '.join(str(error).split())[:200]}); start one "
                        "(dask scheduler) or check the address and port"
                    ) from None
                self._client = self._stack.enter_context(client)
        elif self.executor == "process" or self.workers > 1:
            self._pool = self._new_pool()
        return self

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        return concurrent.futures.ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),  # no inherited threads or locks
            initializer=die_with_parent,
            initargs=(os.getpid(),),
        )

    def run(
        self, function: Callable[..., Any], tasks: Sequence[tuple[Any, tuple]]
    ) -> Iterator[tuple[Any, Any]]:
        """Run ``function(*args)`` for every ``(key, args)``; yield ``(key, result)`` as they finish.

        On the local pool, a task whose worker died :data:`MAX_TRIES` times yields a
        :class:`WorkerCrashed` as its result; ``on_restart``, if given, is called with one line
        each time the pool is restarted.
        """
        if self._client is not None:
            from dask.distributed import as_completed

            futures = {self._client.submit(function, *args, pure=False): key for key, args in tasks}
            for future in as_completed(futures):
                yield futures[future], future.result()
        elif self._pool is not None:
            yield from self._run_pool(function, tasks)
        else:
            for key, args in tasks:
                yield key, function(*args)

    def _run_pool(
        self, function: Callable[..., Any], tasks: Sequence[tuple[Any, tuple]]
    ) -> Iterator[tuple[Any, Any]]:
        """Run the tasks on the local pool, at most ``workers`` in flight (so every one is running).

        A dead worker breaks the whole pool and fails every task in flight with it; which of
        them killed it is unknown, so after a restart each of them runs alone once (the others
        wait), and a task whose worker dies while it runs alone is the one: only such a death
        can give a task up.  Keeping no more than ``workers`` tasks submitted means no queued,
        never-started task is charged with a death.
        """
        todo = collections.deque(tasks)
        alone: collections.deque[tuple[Any, tuple]] = collections.deque()  # suspects, one at a time
        tries: collections.Counter[Any] = collections.Counter()
        running: dict[concurrent.futures.Future, tuple[Any, tuple]] = {}

        def submit(queue: collections.deque[tuple[Any, tuple]]) -> bool:
            """Submit the next task of ``queue``; ``False`` (task kept) if the pool broke meanwhile."""
            assert self._pool is not None
            try:
                future = self._pool.submit(function, *queue[0][1])
            except BrokenProcessPool:  # a worker died since the last wait: its future says so next
                return False
            running[future] = queue.popleft()
            return True

        while todo or alone or running:
            assert self._pool is not None
            if alone:
                if not running:
                    submit(alone)
            else:
                while todo and len(running) < self.workers and submit(todo):
                    pass
            if not running:  # broken with nothing in flight to blame: a fresh pool, no one charged
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = self._new_pool()
                continue
            done, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
            lost = []
            for future in done:
                task = running.pop(future)
                if isinstance(future.exception(), BrokenProcessPool):
                    lost.append(task)
                    continue
                yield task[0], future.result()
            if not lost:
                continue
            # the pool is broken: every task still in flight is lost with it
            lost += [running[future] for future in running]
            running.clear()
            single = len(lost) == 1
            retry = []
            for task in lost:
                tries[task[0]] += 1
                if single and tries[task[0]] >= MAX_TRIES:
                    yield (
                        task[0],
                        WorkerCrashed(
                            f"task {task[0]!r}: its worker process died each of the {tries[task[0]]} times "
                            "it ran (killed, out of memory, or a crash in native code)"
                        ),
                    )
                else:
                    retry.append(task)
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = self._new_pool()
            alone.extend(retry)
            if self.on_restart is not None and retry:
                self.on_restart(
                    f"a worker process died; restarted the pool and rerunning {len(retry)} "
                    f"lost task{'s' if len(retry) != 1 else ''} (each alone first; "
                    f"a task whose worker dies {MAX_TRIES} times is given up)",
                    [task[0] for task in retry],
                )

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Stop the workers; on an error or interrupt, kill them at once without waiting."""
        if self._pool is not None:
            if error is None:
                self._pool.shutdown(wait=True)
            else:
                processes = list(getattr(self._pool, "_processes", {}).values())
                self._pool.shutdown(wait=False, cancel_futures=True)
                for process in processes:  # a running trial would finish first otherwise
                    process.kill()
        self._stack.close()
