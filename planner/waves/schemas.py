"""What a wave design is asked and what it answers: the request (bounds of the waves, and
the region or the motion to keep regular) and the designed waves."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, model_validator

from planner.certify import CouplingCertificate
from planner.inverse import ACTIVE_INITIAL, check_motion, check_prescribable
from planner.model import Robot
from planner.profiles import PassiveMotion
from planner.schema import REQUEST as _STRICT
from planner.schema import Angle, Duration, JointState
from planner.waves.screening import SCREEN_STEPS, coarse_points, phases_per_joint

MAX_SCREENING = 5_000_000
"""Largest number of configurations the screening of one design may evaluate
(candidates x samples of each, `WaveDesignRequest.screening`)."""


class Region(BaseModel):
    """A box of configurations [rad], one bound per joint; lower == upper fixes a joint."""

    model_config = _STRICT

    lower: list[Angle] = Field(min_length=1)
    upper: list[Angle] = Field(min_length=1)


class Motion(BaseModel):
    """A prescribed passive motion and the active joints' initial state (as for
    `planner.inverse.InverseDynamicsRequest`)."""

    model_config = _STRICT

    passive_motion: PassiveMotion
    duration: Duration = Field(description="T [s], within [0.01, 10000] s")
    active_initial: JointState = Field(description=ACTIVE_INITIAL)


class WaveDesignRequest(BaseModel):
    """Bounds of the waves and what they must keep regular: a region or a motion."""

    model_config = _STRICT

    robot: Robot
    amplitude_max: float = Field(gt=0.0, description="largest amplitude a [m]")
    frequency_max: int = Field(ge=1, le=12, description="largest integer frequency n")
    margin: float = Field(gt=0.0, description="required sigma_min(M_pa) [kg m^2]")
    region: Region | None = None
    motion: Motion | None = None
    starts: int = Field(default=4, ge=1, le=32, description="NLP starting points")
    certification_points: int | None = Field(
        default=None, ge=100, le=200_000,
        description="dense check: grid points of the region (default 40,000) or "
                    "inverse-dynamics samples of the motion (default 2,001), whose cubic "
                    "Hermite interpolant the proof runs along")

    @model_validator(mode="after")
    def _consistent(self) -> WaveDesignRequest:
        check_prescribable(self.robot)
        n = self.robot.n
        if (self.region is None) == (self.motion is None):
            raise ValueError("region: give exactly one of region and motion")
        if self.region is not None:
            if len(self.region.lower) != n or len(self.region.upper) != n:
                raise ValueError(f"region: lower and upper need {n} entries each, one per joint")
            if any(u < lo for lo, u in zip(self.region.lower, self.region.upper, strict=True)):
                raise ValueError("region.upper: every entry must be >= the matching entry "
                                 "of lower")
        elif self.motion is not None:  # (the other of the two)
            m = self.motion
            check_motion(self.robot, m.passive_motion, m.duration, m.active_initial, "motion.")
        if self.screening > MAX_SCREENING:
            raise ValueError(f"frequency_max: the screening would evaluate {self.screening:,} "
                             f"configurations, more than the limit of {MAX_SCREENING:,}; lower "
                             "frequency_max or fix joints of the region (lower == upper)")
        return self

    @property
    def screening(self) -> int:
        """Configurations the screening evaluates, counted without building anything:
        every frequency and phase combination of the active joints times its samples (the
        region's coarse grid, or the motion's RK4 steps)."""
        na = len(self.robot.active)
        candidates = (self.frequency_max * phases_per_joint(na)) ** na
        if self.region is None:
            return candidates * (SCREEN_STEPS + 1)
        free = sum(hi > lo for lo, hi in zip(self.region.lower, self.region.upper, strict=True))
        return candidates * coarse_points(free) ** free


class WaveSpec(BaseModel):
    """The wave of one active joint (0-based index)."""

    joint: int
    amplitude: float
    frequency: int
    phase: float


Status = Literal["certified", "infeasible", "undecided"]
"""What a design's certificate says of the margin."""


class WaveDesignResult(BaseModel):
    """The designed waves, the proven smallest sigma_min [kg m^2] and how it was proven.
    `robot` is the request's robot carrying these waves."""

    status: Status = Field(
        description="certified: sigma_min(M_pa) >= margin is proven over the whole region "
                    "or along the whole motion; infeasible: sigma_min falls below the margin "
                    "at a sample (the best design found; this proves nothing about other "
                    "waves); undecided: neither within the proof's boxes or the deadline")
    waves: list[WaveSpec]
    certified_sigma_min: float = Field(
        description="[kg m^2] proven lower bound of sigma_min(M_pa) over the region or along "
                    "the motion (certificate.bound)")
    certificate: CouplingCertificate = Field(description="the proof against the margin")
    method: str = Field(description="how the waves were found, checked and proven, and "
                                    "what the proof covers")
    robot: Robot
