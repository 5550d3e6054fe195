"""Zero-copy calls of CasADi Functions from numpy (``casadi.Function.buffer``).

An ordinary call converts every numpy argument to a ``DM`` and every result back (≈ 50–150 µs
for the functions of a tracking problem); the buffer interface reads and writes numpy memory
directly.  Same Function, same arithmetic: the results are bit-identical to an ordinary call.
A caller owns its buffers, so one caller must not be used from two threads at once (the
callers cached on a problem or a reference are therefore not thread-safe; processes are fine,
and a copy gets buffers of its own).
"""

from __future__ import annotations

from typing import Any, cast

import casadi as ca
import numpy as np


class BufferedFunction:
    """Call ``function`` on flat numpy arrays of its nonzeros (column-major), without copies in.

    Parameters
    ----------
    function : casadi.Function
        Any Function; sparse inputs and outputs are taken and returned dense (a thin MX
        wrapper densifies them).
    """

    def __init__(self, function: ca.Function) -> None:
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
