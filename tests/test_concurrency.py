"""The build lock and the bounded build cache (uuv_ocp._concurrency), against a reference LRU.

The eviction order is checked against an independent least-recently-used model written here
(a plain list), over a seeded random sequence of requests; the threads test counts builds.
"""

import threading
import time

import numpy as np
import pytest

from tests.helpers_threads import read_while_building
from uuv_ocp._concurrency import BUILD_LOCK, BuildCache, built_once, serialised


def test_values_are_built_once_and_returned_by_identity():
    cache: BuildCache[object] = BuildCache(4)
    calls = []

    def build():
        calls.append(1)
        return object()

    first = cache.get("a", build)
    assert cache.get("a", build) is first
    assert len(calls) == 1
    assert "a" in cache and len(cache) == 1


def test_eviction_is_least_recently_used():
    rng = np.random.default_rng(3)
    size = 3
    cache: BuildCache[int] = BuildCache(size)
    model: list[int] = []  # most recent last
    for _ in range(500):
        key = int(rng.integers(0, 6))
        built = []
        cache.get(key, lambda key=key, built=built: built.append(key) or key)
        expected_miss = key not in model
        assert bool(built) == expected_miss
        if key in model:
            model.remove(key)
        model.append(key)
        del model[:-size]
        assert sorted(k for k in range(6) if k in cache) == sorted(model)


def test_concurrent_requests_for_one_key_build_once():
    cache: BuildCache[object] = BuildCache(2)
    calls = []
    start = threading.Barrier(8)
    results = []

    def build():
        calls.append(1)
        time.sleep(0.05)  # long enough that every thread asks while the first still builds
        return object()

    def worker():
        start.wait()
        results.append(cache.get("key", build))

    threads = [threading.Thread(target=worker) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(calls) == 1
    assert all(value is results[0] for value in results)


def test_builds_run_under_the_build_lock_and_a_hit_does_not_wait_for_it():
    cache: BuildCache[int] = BuildCache(2)
    cache.get("kept", lambda: 1)
    held = []
    cache.get("new", lambda: held.append(BUILD_LOCK._is_owned()) or 2)  # type: ignore[attr-defined]
    assert held == [True]
    hit = []
    with BUILD_LOCK:  # another thread building: a hit from this second thread still returns
        thread = threading.Thread(target=lambda: hit.append(cache.get("kept", lambda: -1)))
        thread.start()
        thread.join(timeout=5.0)
    assert hit == [1]


def test_serialised_functions_never_overlap():
    inside = []
    overlaps = []

    @serialised
    def critical():
        inside.append(1)
        if len(inside) > 1:
            overlaps.append(1)
        time.sleep(0.002)
        inside.pop()

    threads = [threading.Thread(target=lambda: [critical() for _ in range(20)]) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert overlaps == []


def test_size_must_be_positive():
    with pytest.raises(ValueError, match="size must be an integer >= 1, got 0"):
        BuildCache(0)


class _Lazy:
    """Two instances' built_once values: counts the computations and whether BUILD_LOCK was held."""

    def __init__(self, tag: int) -> None:
        self.tag, self.calls = tag, 0
        self.held: list[bool] = []

    @built_once
    def value(self) -> int:
        self.calls += 1
        self.held.append(BUILD_LOCK._is_owned())  # type: ignore[attr-defined]
        time.sleep(0.05)  # widen the window in which other threads ask for it
        return 10 * self.tag


def test_built_once_computes_once_under_the_build_lock_and_then_reads_without_it():
    lazy = _Lazy(3)
    answers: list[int] = []
    threads = [threading.Thread(target=lambda: answers.append(lazy.value), daemon=True) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10.0)
    assert answers == [30] * 4 and lazy.calls == 1 and lazy.held == [True]
    read = []
    with BUILD_LOCK:  # another thread building: the filled value is read without the lock
        thread = threading.Thread(target=lambda: read.append(lazy.value), daemon=True)
        thread.start()
        thread.join(timeout=5.0)
    assert read == [30]
    assert isinstance(_Lazy.value, built_once)


class _Building:
    """A property that builds (takes BUILD_LOCK inside), like PathFollowingProblem.window did."""

    def __init__(self) -> None:
        self.calls = 0

    @built_once
    def value(self) -> int:
        with BUILD_LOCK:
            self.calls += 1
            return self.calls


def test_built_once_has_no_lock_of_its_own_to_invert_with_the_build_lock():
    """Forced interleaving of a builder holding BUILD_LOCK and a reader of another instance.

    With functools.cached_property (Python 3.11) the reader holds the class attribute's lock and
    waits for BUILD_LOCK while the builder holds BUILD_LOCK and waits for that lock.
    """
    first, second = _Building(), _Building()
    read_while_building(lambda: first.value, lambda: second.value, timeout=10.0)
    assert (first.value, second.value, first.calls, second.calls) == (1, 1, 1, 1)
