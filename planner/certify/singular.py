"""A rigorous lower bound of the least singular value of every matrix in a ball matrix.

For a ball matrix with midpoint A and radius R (entrywise), every matrix in it is A + E
with |E| <= R, and Weyl's inequality for singular values gives
    sigma_least(A + E) >= sigma_least(A) - |E|_2 >= sigma_least(A) - |R|_F.
sigma_least(A) (the min(r, c)-th singular value) is bounded below through the smaller
Gram matrix G of A: sigma_least(A)^2 = lambda_min(G), and lambda_min(G) >= mu exactly when
G - mu I is positive semi-definite, which every leading principal minor of G - mu I being
positive proves (Sylvester's criterion). The minors are arb determinants of the exact
midpoint, so the proof holds whatever floating-point rounding the guess of mu saw.
"""

from __future__ import annotations

import math

import numpy as np
from flint import arb, arb_mat

SHRINK = (1e-9, 1e-6, 1e-3, 0.1, 0.5)
"""Fractions by which the floating-point lambda_min(G) is lowered until the minors of
G - mu I prove mu: the first is all that a well-conditioned G needs."""


def least_lower(balls: list[list[arb]]) -> float:
    """A float at most the least singular value of every matrix in the balls (r x c,
    r, c >= 1), 0.0 where nothing better is proven (also for NaN or infinite balls)."""
    mid = np.array([[float(b.mid()) for b in row] for row in balls])
    rad = np.array([[float(b.rad()) for b in row] for row in balls])
    if not (np.isfinite(mid).all() and np.isfinite(rad).all()):
        return 0.0
    radius = _norm_upper(rad)
    if radius == math.inf:
        return 0.0
    sigma = _least_of_point(mid)
    return max(float((arb(sigma) - arb(radius)).lower()), 0.0)


def _norm_upper(rad: np.ndarray) -> float:
    """An upper bound of the Frobenius norm of the radius matrix (rounded up by arb)."""
    total = arb(0)
    for r in rad.ravel():
        total += arb(float(r)) * arb(float(r))
    return float(total.sqrt().upper())


def _least_of_point(a: np.ndarray) -> float:
    """A proven lower bound of sigma_least(a) for an exact float matrix a (r x c)."""
    gram = a @ a.T if a.shape[0] <= a.shape[1] else a.T @ a
    guess = float(np.linalg.eigvalsh(gram)[0])
    if not guess > 0.0:
        return 0.0
    exact = arb_mat([[arb(float(x)) for x in row] for row in a])
    g = exact * exact.transpose() if a.shape[0] <= a.shape[1] else exact.transpose() * exact
    for shrink in SHRINK:
        mu = guess * (1.0 - shrink)
        if _positive_definite(g, mu):
            return float(arb(mu).sqrt().lower())
    return 0.0


def _positive_definite(g: arb_mat, mu: float) -> bool:
    """Whether every leading principal minor of g - mu I is provably positive."""
    k = g.nrows()
    shifted = arb_mat([[g[i, j] - (arb(mu) if i == j else 0) for j in range(k)]
                       for i in range(k)])
    for size in range(1, k + 1):
        minor = arb_mat([[shifted[i, j] for j in range(size)] for i in range(size)])
        if not minor.det() > 0:
            return False
    return True
