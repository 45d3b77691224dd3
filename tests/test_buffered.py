"""planner.buffered: CasADi functions called in place on NumPy arrays give what a plain call
gives."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner.buffered import call


def _function() -> ca.Function:
    """Two inputs (2 x 3 and a scalar), three outputs: dense, structurally sparse, scalar."""
    x, s = ca.SX.sym("x", 2, 3), ca.SX.sym("s")
    sparse = ca.SX(3, 2)
    sparse[0, 1], sparse[2, 0] = s * x[1, 2], ca.cos(x[0, 0])
    return ca.Function("f", [x, s], [ca.sin(x) * s, sparse, ca.sum1(ca.sum2(x))])


def test_outputs_agree_with_a_plain_call():
    f = _function()
    x = np.random.default_rng(0).normal(size=(2, 3))  # C order: read column-major all the same
    outputs = call(f, x, 0.7)
    expected = [np.array(out) for out in f(x, 0.7)]
    assert [o.shape for o in outputs] == [(2, 3), (3, 2), (1, 1)]
    for ours, theirs in zip(outputs, expected, strict=True):
        assert np.array_equal(ours, theirs)


def test_a_mapped_function_fills_every_column():
    x = ca.SX.sym("x", 2)
    f = ca.Function("g", [x], [ca.vertcat(x[0] * x[1], x[0] - x[1], 1.0)]).map(50)
    columns = np.random.default_rng(1).normal(size=(2, 50))
    (out,) = call(f, columns)
    assert np.allclose(out, np.vstack([columns[0] * columns[1], columns[0] - columns[1],
                                       np.ones(50)]), rtol=0, atol=1e-15)


def test_wrong_inputs_are_refused_with_what_was_expected():
    f = _function()
    with pytest.raises(ValueError, match=r"^f takes 2 inputs, not 1$"):
        call(f, np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"^input 0 of f takes 6 dense entries, not 4$"):
        call(f, np.zeros((2, 2)), 1.0)


def test_a_column_is_repeated_across_a_mapped_function_s_columns():
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 2)
    f = ca.Function("h", [x, p], [x * p]).map(4)
    columns, shared = np.arange(8.0).reshape(2, 4), np.array([2.0, -1.0])
    (out,) = call(f, columns, shared)
    assert np.array_equal(out, np.array(f(columns, shared)))
    with pytest.raises(ValueError, match=r"^input 1 of map4_h takes 8 dense entries, not 3$"):
        call(f, columns, np.ones(3))
