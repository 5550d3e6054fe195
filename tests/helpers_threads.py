"""A forced interleaving for the lock-order tests: a builder holding BUILD_LOCK and a reader."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from uuv_ocp._concurrency import BUILD_LOCK


def read_while_building(built: Callable[[], object], read: Callable[[], object], timeout: float) -> None:
    """Run ``built()`` inside BUILD_LOCK (after 0.2 s) while another thread calls ``read()``.

    The builder is an Ocp's ``_declare`` (it holds the lock, then reads a lazily built
    attribute); the reader asks for another instance's attribute meanwhile.  The threads are
    daemons joined with ``timeout`` (s): a deadlock fails the assertion instead of hanging the suite.
    """
    holding = threading.Event()

    def builder() -> None:
        with BUILD_LOCK:
            holding.set()
            time.sleep(0.2)  # the reader asks for its value meanwhile
            built()

    threads = [
        threading.Thread(target=builder, daemon=True),
        threading.Thread(target=lambda: (holding.wait(), read()), daemon=True),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=timeout)
    assert not any(thread.is_alive() for thread in threads), "deadlock: both threads still waiting"
