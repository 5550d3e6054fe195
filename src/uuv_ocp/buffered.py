"""Zero-copy calls of CasADi Functions from numpy (``casadi.Function.buffer``).

An ordinary call converts every numpy argument to a ``DM`` and every result back (≈ 50–150 µs
for the functions of a tracking problem); the buffer interface reads and writes numpy memory
directly.  Same Function, same arithmetic: the results are bit-identical to an ordinary call.
A caller owns its buffers, so one caller must not be used from two threads at once.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


class BufferedFunction:
    """Call ``function`` on flat numpy arrays of its nonzeros (column-major), without copies in.

    Parameters
    ----------
    function : casadi.Function
        Any Function whose inputs and outputs are dense.

    Raises
    ------
    ValueError
        If an input or output is not dense.
    """

    def __init__(self, function: ca.Function) -> None:
        for kind, count, sparsity in (
            ("input", function.n_in(), function.sparsity_in),
            ("output", function.n_out(), function.sparsity_out),
        ):
            for index in range(count):
                if not sparsity(index).is_dense():
                    raise ValueError(
                        f"{kind} {index} of {function.name()!r} must be dense for a buffered call, "
                        f"got sparsity {sparsity(index).dim()}"
                    )
        self.function = function
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._buffer, self._trigger = function.buffer()
        for index, array in enumerate(self._inputs):
            self._buffer.set_arg(index, memoryview(array))
        for index, array in enumerate(self._outputs):
            self._buffer.set_res(index, memoryview(array))

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        """Evaluate; ``inputs`` are flat (column-major) nonzeros; returns copies of the outputs."""
        for target, value in zip(self._inputs, inputs, strict=True):
            target[:] = np.ravel(value)
        self._trigger()
        return [output.copy() for output in self._outputs]
