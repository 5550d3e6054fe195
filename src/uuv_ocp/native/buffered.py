"""Zero-copy calls of CasADi Functions from numpy (``casadi.Function.buffer``).

An ordinary call converts every numpy argument to a ``DM`` and every result back (≈ 50–150 µs
for the functions of a tracking problem); the buffer interface reads and writes numpy memory
directly.  Same Function, same arithmetic: the results are bit-identical to an ordinary call.
A caller owns its buffers and CasADi memory, so the package gives every owner its own (a backend,
a thread: ``Transcribed.buffered``, ``Reference.evaluate``); a copy (``copy``, ``deepcopy``,
pickle) gets buffers of its own.  A caller that is shared anyway is still safe: its calls take a
lock of their own, so two threads calling it at once take turns instead of mixing their inputs.
"""

from __future__ import annotations

import threading
from typing import Any, cast

import casadi as ca
import numpy as np

from uuv_ocp._concurrency import BUILD_LOCK


class BufferedFunction:
    """Call ``function`` on flat numpy arrays of its nonzeros (column-major), without copies in.

    Parameters
    ----------
    function : casadi.Function
        Any Function; sparse inputs and outputs are taken and returned dense (a thin MX
        wrapper densifies them).
    """

    def __init__(self, function: ca.Function) -> None:
        with BUILD_LOCK:  # a densifying wrapper and Function.buffer build CasADi objects
            self._build(function)
        self._lock = threading.Lock()

    def _build(self, function: ca.Function) -> None:
        dense = all(function.sparsity_in(i).is_dense() for i in range(function.n_in())) and all(
            function.sparsity_out(i).is_dense() for i in range(function.n_out())
        )
        if not dense:
            symbols = [ca.MX.sym(function.name_in(i), *function.size_in(i)) for i in range(function.n_in())]
            outputs = function.call(symbols)
            function = ca.Function(f"{function.name()}_dense", symbols, [ca.densify(o) for o in outputs])
        self.function = function
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        buffer, self._trigger = function.buffer()
        # Any: casadi's stub gives set_arg/set_res a third `size` argument that SWIG takes from
        # the memoryview itself (passing it fails at run time).
        self._buffer = cast(Any, buffer)
        for index, array in enumerate(self._inputs):
            self._buffer.set_arg(index, array.data)  # ndarray.data: a memoryview of the array
        for index, array in enumerate(self._outputs):
            self._buffer.set_res(index, array.data)

    def stats(self) -> dict:
        """``Function.stats()`` of the last buffered call (its own memory, not ``stats(0)``)."""
        return self._buffer.stats()

    def __reduce__(self) -> tuple[type[BufferedFunction], tuple[ca.Function]]:
        """Pickle the Function only: a copy (deepcopy, pickle) gets buffers of its own."""
        return (BufferedFunction, (self.function,))

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        """Evaluate; returns copies of the outputs (flat, column-major).

        ``inputs`` are the inputs' values: flat vectors of their nonzeros, or dense matrices of
        the inputs' shape (taken column by column, as CasADi stores them).
        """
        with self._lock:  # the buffers are this caller's: one call at a time writes them
            for index, (target, value) in enumerate(zip(self._inputs, inputs, strict=True)):
                value = np.asarray(value, dtype=float)
                if value.size != target.size:
                    raise ValueError(
                        f"input {index} of {self.function.name()!r} needs {target.size} values, "
                        f"got shape {value.shape}"
                    )
                target[:] = value.ravel(order="F")
            self._trigger()
            return [output.copy() for output in self._outputs]
