"""The build lock and the bounded build cache (uuv_ocp._concurrency), against a reference LRU.

The eviction order is checked against an independent least-recently-used model written here
(a plain list), over a seeded random sequence of requests; the threads test counts builds.
"""

import threading
import time

import numpy as np
import pytest

from uuv_ocp._concurrency import BUILD_LOCK, BuildCache, serialised


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
