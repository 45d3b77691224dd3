"""CasADi SX functions evaluated in ball arithmetic (python-flint's arb).

An SX function is a straight-line algorithm of scalar operations; running the same
algorithm on balls (midpoint and radius, every operation rounded outwards by arb) gives
balls that contain the function's value at every point of the input balls. This is how
the coupling block M_pa(q) is enclosed over a box of configurations: from the very
expression graph the planner differentiates, not from a second derivation.

An operation outside `_UNARY` and `_BINARY` raises `Unsupported`; an operation that is
not defined on part of a ball (a division by a ball holding zero) gives arb's NaN ball,
which every caller treats as "no bound".
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import casadi as ca
from flint import arb


class Unsupported(ValueError):
    """The function uses an operation this evaluator has no enclosure for."""


def _square(x: arb) -> arb:
    """x^2, kept non-negative for a ball that holds zero (arb's x * x is not)."""
    a = abs(x)
    return a * a


_UNARY: dict[int, Callable[[arb], arb]] = {
    ca.OP_ASSIGN: lambda x: x,
    ca.OP_NEG: lambda x: -x,
    ca.OP_SIN: lambda x: x.sin(),
    ca.OP_COS: lambda x: x.cos(),
    ca.OP_TAN: lambda x: x.tan(),
    ca.OP_EXP: lambda x: x.exp(),
    ca.OP_LOG: lambda x: x.log(),
    ca.OP_SQRT: lambda x: x.sqrt(),
    ca.OP_SQ: _square,
    ca.OP_TWICE: lambda x: 2 * x,
    ca.OP_INV: lambda x: 1 / x,
    ca.OP_FABS: abs,
    ca.OP_ATAN: lambda x: x.atan(),
}
def _indicator(certain: bool, impossible: bool) -> arb:
    """1 or 0 where a comparison is decided on the balls, [0, 1] where it is not: what the
    derivative of fmax, fmin and fabs multiplies by (the hull of both one-sided ones)."""
    return arb(1) if certain else arb(0) if impossible else arb(0.5, 0.5)


_BINARY: dict[int, Callable[[arb, arb], arb]] = {
    ca.OP_LE: lambda x, y: _indicator(bool(x <= y), bool(x > y)),
    ca.OP_LT: lambda x, y: _indicator(bool(x < y), bool(x >= y)),
    ca.OP_ADD: lambda x, y: x + y,
    ca.OP_SUB: lambda x, y: x - y,
    ca.OP_MUL: lambda x, y: x * y,
    ca.OP_DIV: lambda x, y: x / y,
    ca.OP_FMIN: lambda x, y: x.min(y),
    ca.OP_FMAX: lambda x, y: x.max(y),
    ca.OP_ATAN2: lambda y, x: arb.atan2(y, x),
}


class BallFunction:
    """A CasADi SX function (scalar algorithm) that evaluates on lists of balls.

    Called with one list of arb per input (its nonzeros, column-major), it returns one
    dense list of lists (rows x columns) of arb per output.
    """

    def __init__(self, f: ca.Function):
        if not f.is_a("SXFunction"):
            raise Unsupported(f"{f.name()} is not an SX function")
        self.f = f
        self.program = [self._instruction(k) for k in range(f.n_instructions())]
        self.width = f.sz_w()
        self.shapes = [(f.size1_out(i), f.size2_out(i)) for i in range(f.n_out())]
        self.positions = [_positions(f.sparsity_out(i)) for i in range(f.n_out())]

    def _instruction(self, k: int) -> tuple[int, list[int], list[int], float]:
        op = self.f.instruction_id(k)
        known = op in (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST) or op in _UNARY or op in _BINARY
        if not known:
            raise Unsupported(f"operation {op} of {self.f.name()} has no ball enclosure")
        constant = self.f.instruction_constant(k) if op == ca.OP_CONST else 0.0
        return op, list(self.f.instruction_input(k)), list(self.f.instruction_output(k)), constant

    def __call__(self, inputs: Sequence[Sequence[arb]]) -> list[list[list[arb]]]:
        work: list[arb] = [arb(0)] * self.width
        outputs = [[[arb(0)] * cols for _ in range(rows)] for rows, cols in self.shapes]
        for op, args, res, constant in self.program:
            if op == ca.OP_INPUT:
                work[res[0]] = inputs[args[0]][args[1]]
            elif op == ca.OP_OUTPUT:
                row, col = self.positions[res[0]][res[1]]
                outputs[res[0]][row][col] = work[args[0]]
            elif op == ca.OP_CONST:
                work[res[0]] = arb(constant)
            elif op in _UNARY:
                work[res[0]] = _UNARY[op](work[args[0]])
            else:
                work[res[0]] = _BINARY[op](work[args[0]], work[args[1]])
        return outputs


def _positions(sp: ca.Sparsity) -> list[tuple[int, int]]:
    """(row, column) of every nonzero of a sparsity pattern, in CasADi's order."""
    rows, cols = sp.get_triplet()
    return list(zip(rows, cols, strict=True))
