"""Torques of the active joints as a piecewise polynomial in time: what a plan delivers and
what a simulation can be fed exactly.

On interval k, t in [breaks[k], breaks[k + 1]], with s = (t - breaks[k]) /
(breaks[k + 1] - breaks[k]) in [0, 1]:

    tau_j(t) = sum_m coefficients[k][m][j] * s**m   [N m]

(ascending powers of s, one column j per active joint in joint order). The torque may jump
at a breakpoint; at t = breaks[k] the interval starting there applies.
"""

from __future__ import annotations

import itertools

import numpy as np
from pydantic import BaseModel, Field, field_validator, model_validator

from planner.schema import REQUEST

MAX_DEGREE = 9  # highest power of s


class TorquePolynomial(BaseModel):
    """Piecewise-polynomial torques (see the module's formula)."""

    model_config = REQUEST

    breaks: list[float] = Field(min_length=2, description="interval boundaries [s], K + 1 "
                                                          "strictly increasing values")
    coefficients: list[list[list[float]]] = Field(
        description="K x (degree + 1) x n_active: coefficients of ascending powers of s "
                    f"[N m], degree at most {MAX_DEGREE}")

    @field_validator("breaks")
    @classmethod
    def _increasing(cls, breaks: list[float]) -> list[float]:
        if any(b <= a for a, b in itertools.pairwise(breaks)):
            raise ValueError("must be strictly increasing")
        return breaks

    @model_validator(mode="after")
    def _shape(self) -> TorquePolynomial:
        K = len(self.breaks) - 1
        if len(self.coefficients) != K:
            raise ValueError(f"coefficients: needs {K} entries, one per interval between "
                             f"breaks (got {len(self.coefficients)})")
        powers = {len(interval) for interval in self.coefficients}
        if len(powers) != 1 or not 1 <= powers.pop() <= MAX_DEGREE + 1:
            raise ValueError(f"coefficients: every interval needs the same number of powers, "
                             f"1 to {MAX_DEGREE + 1}")
        widths = {len(row) for interval in self.coefficients for row in interval}
        if len(widths) != 1:
            raise ValueError("coefficients: every power needs one entry per active joint")
        return self

    @property
    def joints(self) -> int:
        """The number of active joints the torques are for."""
        return len(self.coefficients[0][0])

    def array(self) -> np.ndarray:
        """The coefficients as an array (K, degree + 1, n_active)."""
        return np.asarray(self.coefficients, dtype=float)

    def evaluate(self, t) -> np.ndarray:
        """tau (len(t), n_active) [N m] at times t [s]."""
        breaks, coeffs = np.asarray(self.breaks), self.array()
        t = np.asarray(t, float)
        k = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(breaks) - 2)
        s = (t - breaks[k]) / (breaks[k + 1] - breaks[k])
        powers = s[:, None] ** np.arange(coeffs.shape[1])[None, :]
        return np.einsum("tm,tmj->tj", powers, coeffs[k])
