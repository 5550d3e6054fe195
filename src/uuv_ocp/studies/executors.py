"""Where campaign trials run: processes on this machine, or a Dask cluster.

Both executors run the same picklable task function and hand back ``(key, result)`` pairs as
tasks finish; the caller (the campaign driver) is the only one that writes records, so a
worker that dies, is killed or is interrupted never leaves a record behind.

* ``"local"``: ``workers`` processes on this machine (a spawn-context
  :class:`concurrent.futures.ProcessPoolExecutor`); ``workers=1`` runs in this process, in
  order.  Workers ignore SIGINT (Ctrl-C stops the driver, which stops them) and die with their
  parent: on Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, elsewhere a thread that polls the
  parent's pid.  ``"process"`` is an alias kept from earlier versions (the pool even for
  ``workers=1``).
* ``"dask"``: :mod:`dask.distributed` (the ``dask`` extra): a :class:`~distributed.LocalCluster`
  of ``workers`` single-threaded worker processes, or the cluster whose scheduler is at
  ``scheduler`` (``tcp://host:port``).  A task lost with a dead worker is rerun elsewhere by
  the scheduler.
"""

from __future__ import annotations

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
from types import TracebackType
from typing import Any

EXECUTORS = ("local", "process", "dask")
DASK_HINT = "pip install 'uuv_ocp[dask]' (or: pip install 'dask[distributed]')"
_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


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
    """

    def __init__(self, executor: str, workers: int, scheduler: str | None = None) -> None:
        self.executor, self.workers, self.scheduler = executor, workers, scheduler
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
                self._client = self._stack.enter_context(distributed.Client(self.scheduler))
        elif self.executor == "process" or self.workers > 1:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),  # no inherited threads or locks
                initializer=die_with_parent,
                initargs=(os.getpid(),),
            )
        return self

    def run(
        self, function: Callable[..., Any], tasks: Sequence[tuple[Any, tuple]]
    ) -> Iterator[tuple[Any, Any]]:
        """Run ``function(*args)`` for every ``(key, args)``; yield ``(key, result)`` as they finish."""
        if self._client is not None:
            from dask.distributed import as_completed

            futures = {self._client.submit(function, *args, pure=False): key for key, args in tasks}
            for future in as_completed(futures):
                yield futures[future], future.result()
        elif self._pool is not None:
            pending = {self._pool.submit(function, *args): key for key, args in tasks}
            for future in concurrent.futures.as_completed(pending):
                yield pending[future], future.result()
        else:
            for key, args in tasks:
                yield key, function(*args)

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
