"""What the package serialises between threads, and its one shared, bounded build cache.

CasADi evaluates a Function from several threads at once when each caller has memory of its
own (``Function.buffer``: :class:`~uuv_ocp.native.buffered.BufferedFunction`), but building
expressions and Functions, solver plugins, generated code, JIT and loading libraries touch
process-wide state (sparsity caches, plugin tables, the working directory).  Every place the
package builds runs under :data:`BUILD_LOCK`, one re-entrant lock for the whole process, and
only there: solves and steps never take it, so a controller stepping in one thread does not wait
for a problem being built in another.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, Generic, ParamSpec, TypeVar, overload

#: Held while the package builds CasADi objects, generates or compiles code, or loads a library.
#: Re-entrant: a build may call other builders.
BUILD_LOCK = threading.RLock()

P = ParamSpec("P")
R = TypeVar("R")
V = TypeVar("V")


def serialised(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` under :data:`BUILD_LOCK` (for builders, never for hot paths)."""

    @functools.wraps(function)
    def locked(*args: P.args, **kwargs: P.kwargs) -> R:
        with BUILD_LOCK:
            return function(*args, **kwargs)

    return locked


class BuildCache(Generic[V]):
    """Thread-safe, bounded map ``key -> value`` whose values are built once, under :data:`BUILD_LOCK`.

    Parameters
    ----------
    size : int
        Most entries kept; beyond that the least recently used one is dropped (whoever still
        holds its value keeps it; the next request for its key builds it again).
    """

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"size must be an integer >= 1, got {size!r}")
        self.size = size
        self._entries: OrderedDict[Hashable, V] = OrderedDict()
        self._lock = threading.Lock()  # the dict only: a hit never waits for a build

    def get(self, key: Hashable, build: Callable[[], V]) -> V:
        """Return the value of ``key``, building it with ``build()`` if it is not kept."""
        with self._lock:
            if key in self._entries:
                self._entries.move_to_end(key)
                return self._entries[key]
        with BUILD_LOCK:
            with self._lock:  # another thread may have built it while this one waited
                if key in self._entries:
                    self._entries.move_to_end(key)
                    return self._entries[key]
            value = build()
            with self._lock:
                self._entries[key] = value
                while len(self._entries) > self.size:
                    self._entries.popitem(last=False)
            return value

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._entries

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def clear(self) -> None:
        """Forget every entry."""
        with self._lock:
            self._entries.clear()


class built_once(Generic[R]):  # noqa: N801 (a decorator, named like functools.cached_property)
    """``functools.cached_property`` whose first computation runs under :data:`BUILD_LOCK`.

    Python 3.11's ``cached_property`` holds one lock per class attribute (shared by every
    instance) while it computes: a property that builds (takes :data:`BUILD_LOCK` inside) then
    deadlocks against a builder that holds :data:`BUILD_LOCK` and reads it on another instance.
    Here :data:`BUILD_LOCK` is the only lock, taken first; once filled, the instance's
    ``__dict__`` answers (a non-data descriptor), so reads take no lock.
    """

    def __init__(self, function: Callable[[Any], R]) -> None:
        self.function = function
        self.name = function.__name__
        self.__doc__ = function.__doc__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, instance: None, owner: type | None = None) -> built_once[R]: ...

    @overload
    def __get__(self, instance: object, owner: type | None = None) -> R: ...

    def __get__(self, instance: object, owner: type | None = None) -> R | built_once[R]:
        if instance is None:
            return self
        cache = instance.__dict__
        with BUILD_LOCK:
            if self.name not in cache:  # another thread may have filled it while this one waited
                cache[self.name] = self.function(instance)
            return cache[self.name]
