"""Piecewise polynomials in normalised interval time, the form every transcription's
interpolant takes: on interval k, with s = (t - t_k) / h_k in [0, 1],
value(t) = sum_j coeffs[k, j] s^j."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
        for _ in range(derivative):
            factor = factor * np.maximum(powers - _, 0)
        exps = np.maximum(powers - derivative, 0)
        basis = factor[None, :] * s[:, None] ** exps[None, :]
        h = (self.breaks[k + 1] - self.breaks[k])[:, None]
        return np.einsum("tm,tmd->td", basis, c) / h**derivative

    def derivative_poly(self) -> PiecewisePolynomial:
        """The d/dt derivative as a piecewise polynomial of one degree less."""
        m = self.coeffs.shape[1]
        h = np.diff(self.breaks)[:, None, None]
        if m == 1:
            return PiecewisePolynomial(self.breaks, np.zeros_like(self.coeffs))
        c = self.coeffs[:, 1:] * np.arange(1, m)[None, :, None] / h
        return PiecewisePolynomial(self.breaks, c)
