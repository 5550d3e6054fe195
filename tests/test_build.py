"""The one cached build step (uuv_ocp.build): shared by content, bounded, buffered per thread."""

import threading

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp import build
from uuv_ocp._concurrency import BuildCache


def tiny(**changes):
    """RexROV on s2 with a three-step horizon (builds in well under a second)."""
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3, **changes)


def test_equal_problems_share_one_build_and_a_changed_one_does_not():
    first, second = tiny(), tiny()
    assert first is not second
    assert first.build() is second.build()
    assert tiny(dt=0.05).build() is not first.build()


def test_the_cache_keeps_the_last_builds_and_rebuilds_a_dropped_one(monkeypatch):
    monkeypatch.setattr(build, "_BUILDS", BuildCache(2))
    a, b, c = tiny(), tiny(dt=0.05), tiny(dt=0.2)
    kept = a.build()
    b.build()
    assert a.build() is kept  # a used last: b is the oldest
    c.build()  # drops b
    assert a.build() is kept
    rebuilt_b = b.build()  # drops c, the oldest (a and b kept)
    assert rebuilt_b.spec.key == b.spec().key
    assert a.build() is kept
    c.build()  # drops b: a was used after it
    assert a.build() is kept
    b.build()  # drops c ...
    b.build()
    c.build()  # ... and now a, used longest ago
    assert a.build() is not kept
    assert a.build().spec.key == kept.spec.key


def test_buffered_callers_are_per_thread_and_give_the_functions_values():
    problem = tiny()
    rollout = problem.build().rollout
    rng = np.random.default_rng(5)
    inputs = [rng.normal(size=rollout.size_in(i)) for i in range(rollout.n_in())]
    expected = [np.asarray(value) for value in rollout.call(inputs)]
    caller = problem.buffered("rollout")
    assert problem.buffered("rollout") is caller
    other = []
    thread = threading.Thread(target=lambda: other.append(problem.buffered("rollout")))
    thread.start()
    thread.join()
    assert other[0] is not caller
    outputs = caller(*inputs)
    outputs = outputs if isinstance(outputs, tuple | list) else [outputs]
    for got, want in zip(outputs, expected, strict=True):
        np.testing.assert_allclose(np.asarray(got).reshape(want.shape, order="F"), want, rtol=0, atol=0)


def test_cache_size_is_bounded():
    assert build.BUILD_CACHE_SIZE >= 1
    with pytest.raises(ValueError, match="size"):
        BuildCache(0)
