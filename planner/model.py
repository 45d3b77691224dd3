"""The robot model: links, joints and waves (pydantic), and its structure key.

A robot is a planar chain of 1 to 8 links. Link i is the vector r_i(q_i) e(q_i) with
r_i = l_i + a_i sin(n_i q_i + eps_i), q_i the absolute angle measured from gravity.
A point mass sits at the tip of every link. SI units throughout.

Every number is bounded to a physically sane range (the `MIN_`/`MAX_` constants) so that
M, h, the energies and the tips of a valid robot are finite at any moderate state.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, ValidationInfo, field_validator

from planner.schema import REQUEST as _FINITE

MAX_LINKS = 8
MIN_LENGTH, MAX_LENGTH = 1e-4, 1e3  # m
MIN_MASS, MAX_MASS = 1e-6, 1e6  # kg
MAX_INERTIA = 1e6  # kg m^2
MAX_GRAVITY = 1e3  # m/s^2
MAX_FREQUENCY = 100.0  # periods per turn
MAX_PHASE = 1e3  # rad


class Wave(BaseModel):
    """Wave r = l + amplitude * sin(frequency * q + phase) on an active joint."""

    model_config = _FINITE

    amplitude: float = Field(ge=0.0, description="a [m], 0 <= a < link length")
    frequency: float = Field(
        ge=0.0, le=MAX_FREQUENCY,
        description="n [-], periods of the wave per full turn (2 pi rad) of the joint angle")
    phase: float = Field(default=0.0, ge=-MAX_PHASE, le=MAX_PHASE, description="eps [rad]")


class Link(BaseModel):
    """One link with its point mass at the tip and the joint that drives it."""

    model_config = _FINITE

    length: float = Field(ge=MIN_LENGTH, le=MAX_LENGTH, description="l [m]")
    mass: float = Field(ge=MIN_MASS, le=MAX_MASS, description="point mass at the tip [kg]")
    inertia: float = Field(default=0.0, ge=0.0, le=MAX_INERTIA,
                           description="rotational inertia [kg m^2]")
    joint: Literal["passive", "active"]
    wave: Wave | None = None

    @field_validator("wave")
    @classmethod
    def _wave_fits(cls, wave: Wave | None, info: ValidationInfo) -> Wave | None:
        """Only an active joint carries a wave, and r = l + a sin(...) stays positive.

        `joint` and `length` are validated first; one that failed is absent from
        `info.data` and its own error is reported instead.
        """
        if wave is None:
            return wave
        if info.data.get("joint") == "passive":
            raise ValueError("a passive joint cannot carry a wave")
        length = info.data.get("length")
        if length is not None and wave.amplitude >= length:
            raise ValueError(f"amplitude: must be smaller than the link length "
                             f"({wave.amplitude:g} >= {length:g})")
        return wave

    @property
    def wavy(self) -> bool:
        """True when the link carries a wave of non-zero amplitude."""
        return self.wave is not None and self.wave.amplitude > 0.0


class Robot(BaseModel):
    """A planar chain of links under gravity g along +x."""

    model_config = _FINITE

    links: list[Link] = Field(min_length=1, max_length=MAX_LINKS)
    gravity: float = Field(default=0.0, ge=0.0, le=MAX_GRAVITY, description="g [m/s^2] along +x")
    rotational_inertia: Literal["cumulative", "absolute"] = "cumulative"

    @field_validator("links")
    @classmethod
    def _has_active_joint(cls, links: list[Link]) -> list[Link]:
        if not any(link.joint == "active" for link in links):
            raise ValueError("at least one joint must be active")
        return links

    @property
    def n(self) -> int:
        """Number of links (and joints)."""
        return len(self.links)

    @property
    def active(self) -> list[int]:
        """0-based indices of the active joints."""
        return [i for i, link in enumerate(self.links) if link.joint == "active"]

    @property
    def passive(self) -> list[int]:
        """0-based indices of the passive joints."""
        return [i for i, link in enumerate(self.links) if link.joint == "passive"]

    def without_waves(self) -> Robot:
        """The same robot with every wave removed."""
        links = [link.model_copy(update={"wave": None}) for link in self.links]
        return self.model_copy(update={"links": links})

    def with_waves(self, waves: Mapping[int, Wave | None]) -> Robot:
        """The same robot with the waves of the given joints replaced."""
        links = list(self.links)
        for joint, wave in waves.items():
            links[joint] = Link.model_validate({**links[joint].model_dump(), "wave": wave})
        return Robot.model_validate({**self.model_dump(), "links": links})


@dataclass(frozen=True)
class Structure:
    """What decides which terms the dynamics contains; numbers are parameters.

    Two robots with the same structure share one set of compiled functions.
    """

    n: int
    active: tuple[bool, ...]
    wavy: tuple[bool, ...]
    inertial: tuple[bool, ...]
    gravity: bool
    rotational: Literal["cumulative", "absolute"]

    @classmethod
    def of(cls, robot: Robot, wavy: tuple[bool, ...] | None = None) -> Structure:
        """The structure of a robot; `wavy` forces which joints carry wave terms."""
        return cls(
            n=robot.n,
            active=tuple(link.joint == "active" for link in robot.links),
            wavy=tuple(link.wavy for link in robot.links) if wavy is None else wavy,
            inertial=tuple(link.inertia > 0.0 for link in robot.links),
            gravity=robot.gravity > 0.0,
            rotational=robot.rotational_inertia,
        )

    @property
    def n_params(self) -> int:
        """Length of the parameter vector (see `parameters`)."""
        return 2 * self.n + sum(self.inertial) + 3 * sum(self.wavy) + int(self.gravity)

    @property
    def passive_idx(self) -> list[int]:
        return [i for i, a in enumerate(self.active) if not a]

    @property
    def active_idx(self) -> list[int]:
        return [i for i, a in enumerate(self.active) if a]


def parameters(robot: Robot, structure: Structure) -> np.ndarray:
    """The parameter vector of a robot for a structure.

    Layout: lengths (n), masses (n), inertias of inertial links, then (a, n, eps) of
    each wavy joint, then g if gravity is on.
    """
    links = robot.links
    values: list[float] = [link.length for link in links] + [link.mass for link in links]
    values += [link.inertia for link, on in zip(links, structure.inertial, strict=True) if on]
    for link, on in zip(links, structure.wavy, strict=True):
        if on:
            wave = link.wave or Wave(amplitude=0.0, frequency=0.0)
            values += [wave.amplitude, wave.frequency, wave.phase]
    if structure.gravity:
        values.append(robot.gravity)
    return np.asarray(values, dtype=float)


def wave_slots(structure: Structure) -> dict[int, int]:
    """Index in the parameter vector of each wavy joint's amplitude (frequency, phase follow)."""
    start = 2 * structure.n + sum(structure.inertial)
    slots, k = {}, 0
    for i, on in enumerate(structure.wavy):
        if on:
            slots[i] = start + 3 * k
            k += 1
    return slots
