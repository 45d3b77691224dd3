"""Piecewise polynomials in normalised interval time, the form every transcription's
interpolant takes: on interval k, with s = (t - t_k) / h_k in [0, 1],
value(t) = sum_j coeffs[k, j] s^j."""

from __future__ import annotations

from dataclasses import dataclass

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
