"""CasADi functions called on NumPy arrays through CasADi's buffer interface
(`Function.buffer`): the inputs are read and the outputs written in place, without the
conversions to and from DM of a plain call, which for a function mapped over thousands of
columns cost more than its evaluation.

    call(f, *args) -> list of arrays, one per output of f, each of its shape
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def call(f: ca.Function, *args: np.ndarray | float) -> list[np.ndarray]:
    """f's outputs as dense arrays of their shapes (structural zeros as 0.0) at dense
    inputs, each with as many entries as f's input (read column-major, as CasADi does).
    Raises ValueError for a wrong number or size of inputs, RuntimeError where the
    evaluation fails."""
    if len(args) != f.n_in():
        raise ValueError(f"{f.name()} takes {f.n_in()} inputs, not {len(args)}")
    buffer, trigger = f.buffer()
    inputs = [_flat(f, k, a) for k, a in enumerate(args)]  # referenced through the call
    for k, flat in enumerate(inputs):
        buffer.set_arg(k, flat.data)  # type: ignore[call-arg]  # its size goes with it
    outputs = [np.empty(f.nnz_out(k)) for k in range(f.n_out())]
    for k, out in enumerate(outputs):
        buffer.set_res(k, out.data)  # type: ignore[call-arg]
    trigger()
    if buffer.ret() != 0:
        raise RuntimeError(f"the evaluation of {f.name()} failed")
    return [_dense(f.sparsity_out(k), out) for k, out in enumerate(outputs)]


def _flat(f: ca.Function, k: int, value: np.ndarray | float) -> np.ndarray:
    """Input k as the column-major vector of its entries (f's inputs are dense); a value
    with a whole fraction of the input's columns is repeated across them, as a call
    repeats it (one column of parameters for a mapped function)."""
    rows, cols = f.size_in(k)
    array = np.asarray(value, dtype=float)
    matrix = array.reshape(-1, 1) if array.ndim < 2 else array
    if matrix.shape[0] == rows and matrix.shape[1] and cols % matrix.shape[1] == 0:
        matrix = np.tile(matrix, (1, cols // matrix.shape[1]))
    flat = np.ravel(matrix, order="F")  # contiguous: a view where it can be, else a copy
    if not f.sparsity_in(k).is_dense() or flat.size != f.nnz_in(k):
        raise ValueError(f"input {k} of {f.name()} takes {f.nnz_in(k)} dense entries, "
                         f"not {array.size}")
    return flat


def _dense(sparsity: ca.Sparsity, nonzeros: np.ndarray) -> np.ndarray:
    """The dense matrix of `nonzeros` in `sparsity`."""
    if sparsity.is_dense():
        return nonzeros.reshape(sparsity.shape, order="F")
    rows, cols = sparsity.get_triplet()
    dense = np.zeros(sparsity.shape)
    dense[rows, cols] = nonzeros
    return dense
