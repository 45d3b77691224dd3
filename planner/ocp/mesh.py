"""The time mesh of a transcription: interval breakpoints as fractions of the duration.

A mesh of N intervals is its N + 1 breakpoints 0 = b_0 < b_1 < ... < b_N = 1; interval k
spans [b_k, b_{k+1}] T. The NLP of a structure takes the widths b_{k+1} - b_k as
parameters, so one built NLP serves every mesh with the same number of intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.errors import InputError


@dataclass(frozen=True, eq=False)
class Mesh:
    """breaks: (N + 1,) strictly increasing fractions of T from 0 to 1."""

    breaks: np.ndarray

    def __post_init__(self) -> None:
        b = np.asarray(self.breaks, dtype=float)
        if b.ndim != 1 or b.size < 2 or b[0] != 0.0 or b[-1] != 1.0 or np.any(np.diff(b) <= 0):
            raise InputError("breaks: a mesh needs strictly increasing breakpoints from 0 to 1")
        object.__setattr__(self, "breaks", b)

    @classmethod
    def uniform(cls, intervals: int) -> Mesh:
        """N equal intervals."""
        return cls(np.linspace(0.0, 1.0, intervals + 1))

    @property
    def intervals(self) -> int:
        """N, the number of intervals."""
        return self.breaks.size - 1

    @property
    def widths(self) -> np.ndarray:
        """(N,) interval widths as fractions of T; they sum to 1."""
        return np.diff(self.breaks)

    def points(self, fractions: np.ndarray) -> np.ndarray:
        """Times (as fractions of T) at the given fractions of every interval, interval-major:
        fractions (m,) -> (N * m,)."""
        f = np.asarray(fractions, dtype=float)
        return (self.breaks[:-1, None] + self.widths[:, None] * f[None, :]).ravel()

    def split(self, pieces: np.ndarray) -> Mesh:
        """Each interval k cut into pieces[k] >= 1 equal parts."""
        parts = [np.linspace(a, b, int(m) + 1)[:-1]
                 for a, b, m in zip(self.breaks[:-1], self.breaks[1:], pieces, strict=True)]
        return Mesh(np.concatenate([*parts, [1.0]]))
