"""The robot model: links, joints and waves (pydantic), and its structure key.

A robot is a planar chain of 1 to 8 links. Link i is the vector r_i(q_i) e(q_i) with
r_i = l_i + a_i sin(n_i q_i + eps_i), q_i the absolute angle measured from gravity.
A point mass sits at the tip of every link. SI units throughout.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

MAX_LINKS = 8

_FINITE = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Wave(BaseModel):
    """Wave r = l + amplitude * sin(frequency * q + phase) on an active joint."""

    model_config = _FINITE

    amplitude: float = Field(ge=0.0, description="a [m], 0 <= a < link length")
    frequency: float = Field(ge=0.0, description="n [1/rad], waves per radian of joint angle")
    phase: float = Field(default=0.0, description="eps [rad]")


class Link(BaseModel):
    """One link with its point mass at the tip and the joint that drives it."""

    model_config = _FINITE

    length: float = Field(gt=0.0, description="l [m]")
    mass: float = Field(gt=0.0, description="point mass at the tip [kg]")
    inertia: float = Field(default=0.0, ge=0.0, description="rotational inertia [kg m^2]")
    joint: Literal["passive", "active"]
    wave: Wave | None = None

    @model_validator(mode="after")
    def _wave_fits(self) -> Link:
        if self.wave is None:
            return self
        if self.joint == "passive":
            raise ValueError("wave: a passive joint cannot carry a wave")
        if self.wave.amplitude >= self.length:
            raise ValueError(
                f"wave.amplitude: must be smaller than the link length "
                f"({self.wave.amplitude:g} >= {self.length:g})"
            )
        return self

    @property
    def wavy(self) -> bool:
        """True when the link carries a wave of non-zero amplitude."""
        return self.wave is not None and self.wave.amplitude > 0.0


class Robot(BaseModel):
    """A planar chain of links under gravity g along +x."""

    model_config = _FINITE

    links: list[Link] = Field(min_length=1, max_length=MAX_LINKS)
    gravity: float = Field(default=0.0, ge=0.0, description="g [m/s^2] along +x")
    rotational_inertia: Literal["cumulative", "absolute"] = "cumulative"

    @model_validator(mode="after")
    def _has_active_joint(self) -> Robot:
        if not any(link.joint == "active" for link in self.links):
            raise ValueError("links: at least one joint must be active")
        return self

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

    def with_waves(self, waves: dict[int, Wave | None]) -> Robot:
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
    values += [link.inertia for link, on in zip(links, structure.inertial) if on]
    for link, on in zip(links, structure.wavy):
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
