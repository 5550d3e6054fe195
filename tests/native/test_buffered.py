"""Zero-copy Function calls: equal to ordinary CasADi calls, column-major, checked sizes."""

import copy

import casadi as ca
import numpy as np
import pytest

from uuv_ocp.native.buffered import BufferedFunction


def _function() -> ca.Function:
    matrix = ca.SX.sym("A", 2, 3)
    vector = ca.SX.sym("v", 3)
    sparse = ca.SX(3, 1)
    sparse[1] = ca.sin(vector[0])  # a structurally sparse output is returned dense
    return ca.Function("f", [matrix, vector], [ca.mtimes(matrix, vector), sparse])


def test_buffered_call_equals_an_ordinary_call_matrix_inputs_column_by_column():
    function = _function()
    call = BufferedFunction(function)
    rng = np.random.default_rng(2)
    matrix, vector = rng.normal(size=(2, 3)), rng.normal(size=3)
    product, sparse = call(matrix, vector)
    np.testing.assert_array_equal(product, np.array(function(matrix, vector)[0]).ravel())
    np.testing.assert_array_equal(sparse, [0.0, np.sin(vector[0]), 0.0])
    flat, _ = call(matrix.ravel(order="F"), vector)  # nonzeros in CasADi's order: the same
    np.testing.assert_array_equal(flat, product)


def test_wrong_input_size_is_named():
    call = BufferedFunction(_function())
    with pytest.raises(ValueError, match="input 1 of 'f_dense' needs 3 values, got shape \\(2,\\)"):
        call(np.zeros((2, 3)), np.zeros(2))


def test_a_copy_gets_buffers_of_its_own():
    call = BufferedFunction(_function())
    twin = copy.deepcopy(call)
    first = call(np.ones((2, 3)), np.ones(3))[0]
    second = twin(2 * np.ones((2, 3)), np.ones(3))[0]
    np.testing.assert_array_equal(call(np.ones((2, 3)), np.ones(3))[0], first)
    np.testing.assert_array_equal(second, 2 * first)
