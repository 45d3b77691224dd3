"""Reference profiles for a prescribed passive motion over [0, T].

Each profile gives position [rad], velocity [rad/s] and acceleration [rad/s^2] of the
passive joints at times t (seconds), one row per time and one column per passive joint.
"""

from __future__ import annotations

from functools import cached_property
from itertools import pairwise
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field, model_validator
from scipy.interpolate import CubicSpline
from scipy.special import beta as beta_fn
from scipy.special import betainc

from planner.schema import REQUEST as _STRICT
from planner.schema import Angle

Motion = tuple[np.ndarray, np.ndarray, np.ndarray]


def _scale(t: np.ndarray, duration: float) -> np.ndarray:
    return np.clip(np.asarray(t, dtype=float) / duration, 0.0, 1.0)


def _blend(start: list[float], end: list[float], s, ds, dds, duration: float) -> Motion:
    """q = start + (end - start) s(x), x = t / T, with the chain rule for the rates."""
    start_, delta = np.asarray(start), np.asarray(end) - np.asarray(start)
    return (start_ + np.outer(s, delta), np.outer(ds, delta) / duration,
            np.outer(dds, delta) / duration**2)


class _Endpoints(BaseModel):
    model_config = _STRICT

    start: list[Angle] = Field(min_length=1, description="passive angles at t = 0 [rad]")
    end: list[Angle] = Field(min_length=1, description="passive angles at t = T [rad]")

    @model_validator(mode="after")
    def _same_size(self):
        if len(self.start) != len(self.end):
            raise ValueError(f"end: needs {len(self.start)} entries, as many as start")
        return self


class BetaProfile(_Endpoints):
    """s(x) = I_x(alpha, beta), the regularised incomplete Beta function.

    alpha, beta >= 2 keeps the acceleration finite; > 2 makes it rest-to-rest in
    acceleration too; alpha = beta = 3 is the quintic smoothstep."""

    profile: Literal["beta"] = "beta"
    alpha: float = Field(default=3.0, ge=2.0, le=50.0)
    beta: float = Field(default=3.0, ge=2.0, le=50.0)

    def evaluate(self, t, duration: float) -> Motion:
        x = _scale(t, duration)
        a, b = self.alpha, self.beta
        norm = beta_fn(a, b)
        s = betainc(a, b, x)
        ds = x ** (a - 1) * (1 - x) ** (b - 1) / norm
        dds = ((a - 1) * x ** (a - 2) * (1 - x) ** (b - 1)
               - (b - 1) * x ** (a - 1) * (1 - x) ** (b - 2)) / norm
        return _blend(self.start, self.end, s, ds, dds, duration)

    @property
    def n(self) -> int:
        return len(self.start)


class QuinticProfile(_Endpoints):
    """s(x) = 10 x^3 - 15 x^4 + 6 x^5: rest-to-rest with zero end accelerations."""

    profile: Literal["quintic"] = "quintic"

    def evaluate(self, t, duration: float) -> Motion:
        x = _scale(t, duration)
        s = x**3 * (10 - 15 * x + 6 * x**2)
        ds = 30 * x**2 * (1 - x) ** 2
        dds = 60 * x * (1 - x) * (1 - 2 * x)
        return _blend(self.start, self.end, s, ds, dds, duration)

    @property
    def n(self) -> int:
        return len(self.start)


class SampledProfile(BaseModel):
    """User samples q[k] at times t[k], joined by a cubic spline (continuous acceleration,
    zero velocity at both ends)."""

    model_config = _STRICT

    profile: Literal["samples"] = "samples"
    t: list[float] = Field(min_length=2, description="strictly increasing times [s], t[0] = 0")
    q: list[list[Angle]] = Field(min_length=2, description="passive angles at each time [rad]")

    @model_validator(mode="after")
    def _consistent(self) -> SampledProfile:
        if len(self.q) != len(self.t):
            raise ValueError(f"q: needs {len(self.t)} rows, one per time in t")
        if len({len(row) for row in self.q}) != 1 or not self.q[0]:
            raise ValueError("q: every row needs the same, non-zero number of passive angles")
        if self.t[0] != 0.0:
            raise ValueError("t: must start at 0")
        if any(b <= a for a, b in pairwise(self.t)):
            raise ValueError("t: must be strictly increasing")
        return self

    @cached_property
    def _spline(self) -> CubicSpline:
        """Built once per profile: the inverse dynamics evaluates it thousands of times."""
        return CubicSpline(self.t, np.asarray(self.q), bc_type="clamped")

    def evaluate(self, t, duration: float) -> Motion:
        tt = np.clip(np.asarray(t, dtype=float), 0.0, self.t[-1])
        return self._spline(tt), self._spline(tt, 1), self._spline(tt, 2)

    @property
    def n(self) -> int:
        return len(self.q[0])


PassiveMotion = Annotated[BetaProfile | QuinticProfile | SampledProfile,
                          Field(discriminator="profile")]
