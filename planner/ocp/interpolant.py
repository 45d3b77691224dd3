"""Piecewise polynomials in normalised interval time, the form every transcription's
interpolant takes: on interval k, with s = (t - t_k) / h_k in [0, 1],
value(t) = sum_j coeffs[k, j] s^j."""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

HERMITE = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-3, -2, 3, -1], [2, 1, -2, 1]], dtype=float)
"""Monomial coefficients (rows: powers of s) of the cubic Hermite basis on [0, 1] for the
data (v0, h v0', v1, h v1') (columns)."""


def monomial(points: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Coefficients (ascending powers of s) of the polynomial through values at points.

    points: (m,), values: (..., m, dim) -> (..., m, dim).
    """
    vander = np.vander(np.asarray(points, float), increasing=True)
    return np.linalg.solve(vander, values)


def bernstein(points) -> np.ndarray:
    """E (m x m): E @ values are the Bernstein coefficients (degree m - 1 on [0, 1]) of the
    polynomial through the values at `points` (m distinct fractions of the interval).

    The polynomial lies in the convex hull of its Bernstein coefficients on [0, 1], the first
    and the last of which are its values at 0 and 1; the hull narrows to the polynomial's
    range as the interval is cut (the coefficients are within O(h^2) of its values)."""
    points = np.asarray(points, float)
    m = points.size
    to_bernstein = np.array([[comb(i, j) / comb(m - 1, j) if j <= i else 0.0
                              for j in range(m)] for i in range(m)])
    return to_bernstein @ np.linalg.inv(np.vander(points, increasing=True))


def hull(points, end_known: bool = False) -> np.ndarray:
    """The rows of `bernstein(points)` that a bound on the values does not already bound:
    without the first where 0 is a point (the coefficient is that value), without the last
    where 1 is a point or the end value is known otherwise (end_known: a constraint makes it
    the next node's value). (r x m), r = 0 for a constant or a line between known values."""
    points = np.asarray(points, float)
    if points.size < 2:
        return np.zeros((0, points.size))
    E = bernstein(points)
    keep = np.ones(points.size, bool)
    keep[0] = points[0] != 0.0
    keep[-1] = not (end_known or points[-1] == 1.0)
    return E[keep]


def integrate(coeffs: np.ndarray, start: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Coefficients of start + h * int_0^s p(r) dr for p given by coeffs (K, m, dim)."""
    K, m, dim = coeffs.shape
    out = np.empty((K, m + 1, dim))
    out[:, 0] = start
    out[:, 1:] = coeffs * (h[:, None, None] / np.arange(1, m + 1)[None, :, None])
    return out


def hermite(v: np.ndarray, dv: np.ndarray, h: np.ndarray,
            dv_end: np.ndarray | None = None) -> np.ndarray:
    """Cubic Hermite coefficients (K, 4, dim) through values v (K + 1, dim) and their time
    derivatives dv (K + 1, dim) at breakpoints spaced h (K,) [s]; dv_end (K, dim), when
    given, are the derivatives at the end of each interval instead of dv[1:]."""
    h = np.asarray(h, float)[:, None]
    end = dv[1:] if dv_end is None else dv_end
    data = np.stack([v[:-1], dv[:-1] * h, v[1:], end * h], axis=1)
    return np.einsum("mj,kjd->kmd", HERMITE, data)


@dataclass(frozen=True)
class PiecewisePolynomial:
    """breaks: (K + 1,) times [s]; coeffs: (K, m, dim) in ascending powers of s."""

    breaks: np.ndarray
    coeffs: np.ndarray

    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, float)
        k = np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, len(self.breaks) - 2)
        h = self.breaks[k + 1] - self.breaks[k]
        return k, (t - self.breaks[k]) / h

    def __call__(self, t, derivative: int = 0) -> np.ndarray:
        """Value (or d/dt derivative of the given order) at times t, shape (len(t), dim)."""
        k, s = self._locate(t)
        c = self.coeffs[k]  # (T, m, dim)
        m = c.shape[1]
        powers = np.arange(m)
        factor = np.ones(m)
        for order in range(derivative):
            factor = factor * np.maximum(powers - order, 0)
        exps = np.maximum(powers - derivative, 0)
        basis = factor[None, :] * s[:, None] ** exps[None, :]
        h = (self.breaks[k + 1] - self.breaks[k])[:, None]
        return np.einsum("tm,tmd->td", basis, c) / h**derivative

    def extrema(self) -> Extrema:
        """The exact smallest and largest value on every interval, and where: the polynomial
        at the interval's ends and at the real parts of the roots of its derivative that lie
        inside it (eigenvalues of the derivative's companion matrix). Every candidate is a
        point of the interval, so each value is attained; the critical points are among them,
        so nothing beyond is missed."""
        c = self.coeffs
        K, m, dim = c.shape
        s = [np.zeros((K, 1, dim)), np.ones((K, 1, dim))]
        if m >= 3:
            s.append(_critical(c).reshape(K, dim, -1).transpose(0, 2, 1))
        at = np.concatenate(s, axis=1)  # (K, candidates, dim)
        values = np.zeros_like(at)
        for j in range(m - 1, -1, -1):  # Horner, per interval and component
            values = values * at + c[:, j][:, None, :]
        lo, hi = values.argmin(axis=1)[:, None, :], values.argmax(axis=1)[:, None, :]
        start, h = self.breaks[:-1, None], np.diff(self.breaks)[:, None]

        def pick(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
            return np.take_along_axis(a, idx, axis=1)[:, 0, :]

        return Extrema(pick(values, lo), pick(values, hi), start + h * pick(at, lo),
                       start + h * pick(at, hi))


@dataclass(frozen=True)
class Extrema:
    """The smallest and largest value of a piecewise polynomial on each interval (K, dim),
    and the times [s] where it takes them."""

    low: np.ndarray
    high: np.ndarray
    t_low: np.ndarray
    t_high: np.ndarray


def _critical(c: np.ndarray) -> np.ndarray:
    """Real parts, clipped to [0, 1], of the roots of the derivatives of the polynomials c
    (K, m, dim), m >= 3: (K * dim, m - 2), polynomial k, component d in row k * dim + d."""
    K, m, dim = c.shape
    d = (c[:, 1:] * np.arange(1, m)[None, :, None]).transpose(0, 2, 1).reshape(K * dim, m - 1)
    lead = d[:, -1]
    regular = np.abs(lead) > 1e-12 * np.abs(d).max(axis=1, initial=0.0)
    out = np.zeros((K * dim, m - 2))
    if np.any(regular):
        monic = d[regular, :-1] / lead[regular, None]
        companion = np.zeros((monic.shape[0], m - 2, m - 2))
        if m > 3:
            companion[:, 1:, :-1] = np.eye(m - 3)
        companion[:, :, -1] = -monic
        out[regular] = np.linalg.eigvals(companion).real
    for row in np.flatnonzero(~regular):  # a lower degree: numpy trims the zero lead
        roots = np.polynomial.polynomial.polyroots(d[row]) if np.any(d[row]) else np.zeros(0)
        out[row, :roots.size] = roots.real
    return np.clip(out, 0.0, 1.0)
