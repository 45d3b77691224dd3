"""The coupling margin as smooth rows: every row at or above 0 exactly where
sigma_least(M_pa) >= margin and a square block's determinant keeps its sign. The NLP holds
them at its points (`planner.ocp.terms.CouplingMargin`), and the proofs on whole intervals
enclose them over boxes (`planner.certify.margin`)."""

from __future__ import annotations

from functools import lru_cache

import casadi as ca

from planner.dynamics import derive
from planner.model import Structure


@lru_cache(maxsize=64)
def margin_function(s: Structure) -> ca.Function:
    """Rows that are all >= 0 exactly where sigma_min(M_pa) >= margin (the least singular
    value) and a square block's determinant keeps the sign it has at the start.

    In general: the leading principal minors of G / margin^2 - I, G the smaller Gram matrix
    of M_pa (all > 0 <=> G - margin^2 I positive definite <=> sigma_min(M_pa) > margin). A
    square block adds sign * det(M_pa) / margin^p - 1 >= 0, necessary for the margin
    (|det| >= margin^p) and what stops a path from jumping through det = 0 between two
    knots. A 1 x 1 block needs that row alone (sign * M_pa / margin >= 1 is the margin):
    its minor M_pa^2 / margin^2 - 1 would be active at the same points with a parallel
    gradient, which breaks the linear independence of the active constraints' gradients
    that Ipopt's steps rely on. A 2 x 2 block, the seed arm's, replaces the minors by one
    row of the order of sigma_min / margin, sign * det / (margin sqrt(|M_pa|_F^2 -
    margin^2)) - 1 >= 0: with sigma_1 >= sigma_2, det = sigma_1 sigma_2 and |M_pa|_F^2 =
    sigma_1^2 + sigma_2^2, it holds where both singular values are at least the margin or
    both at most it, and the sign row (det >= margin^2) leaves the first. The minors grow
    as sigma^4 / margin^4 (1e5 for entries of 0.1 kg m^2 and a margin of 0.005), which
    left Ipopt in its restoration phase for hundreds of iterations on the hard suite's
    co-design tasks (docs/benchmarks.md, "Hard suite").
    """
    sym = derive(s)
    margin, sign = ca.SX.sym("margin"), ca.SX.sym("sign")
    mpa = sym.mass[s.passive_idx, s.active_idx]
    square = mpa.size1() == mpa.size2()
    if square and mpa.size1() == 1:
        rows = []
    elif square and mpa.size1() == 2:
        rest = ca.fmax(ca.sumsqr(mpa) - margin**2, 1e-6 * margin**2)
        rows = [sign * ca.det(mpa) / (margin * ca.sqrt(rest)) - 1]
    else:
        gram = ca.mtimes(mpa, mpa.T) if mpa.size1() <= mpa.size2() else ca.mtimes(mpa.T, mpa)
        shifted = gram / margin**2 - ca.SX.eye(gram.size1())
        rows = [ca.det(shifted[:k, :k]) for k in range(1, gram.size1() + 1)]
    if square:
        rows.append(sign * ca.det(mpa) / margin ** mpa.size1() - 1)
    return ca.Function("margin", [sym.q, sym.p, margin, sign], [ca.vertcat(*rows)])
