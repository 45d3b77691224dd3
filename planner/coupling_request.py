"""A request of the coupling analysis: the robot, its configurations (an explicit path or
a grid box) and the threshold below which a local minimum of sigma_min is singular."""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, Field, model_validator

from planner.errors import InputError
from planner.model import Robot
from planner.schema import REQUEST as _STRICT
from planner.schema import Angle

MAX_POINTS = 200_000
"""Largest number of configurations one request may evaluate."""


class Grid(BaseModel):
    """A box of configurations [rad]: `points` per axis (one number for all axes, or one
    per joint); an axis with lower == upper is a single point."""

    model_config = _STRICT

    lower: list[Angle] = Field(min_length=1, description="lower corner, one angle per joint [rad]")
    upper: list[Angle] = Field(min_length=1, description="upper corner, one angle per joint [rad]")
    points: int | list[int] = Field(
        default=51, description="grid points per axis (>= 2 where lower < upper)")

    @model_validator(mode="after")
    def _consistent(self) -> Grid:
        if len(self.upper) != len(self.lower):
            raise ValueError(f"upper: needs {len(self.lower)} entries, as many as lower")
        if any(u < lo for lo, u in zip(self.lower, self.upper, strict=True)):
            raise ValueError("upper: every entry must be >= the matching entry of lower")
        counts = self._requested()
        if len(counts) != len(self.lower):
            raise ValueError(f"points: needs 1 or {len(self.lower)} entries")
        if any(c < 1 or (c < 2 and u > lo)
               for c, lo, u in zip(counts, self.lower, self.upper, strict=True)):
            raise ValueError("points: an axis with lower < upper needs at least 2 points")
        return self

    def _requested(self) -> list[int]:
        """`points` as one count per axis."""
        return self.points if isinstance(self.points, list) else [self.points] * len(self.lower)

    def counts(self) -> list[int]:
        """Points of every axis (1 on a degenerate axis), computed without building the axes."""
        return [1 if u == lo else c
                for lo, u, c in zip(self.lower, self.upper, self._requested(), strict=True)]

    def axes(self) -> list[np.ndarray]:
        """Grid coordinates of every axis; a degenerate axis holds its single value."""
        return [np.array([lo]) if c == 1 else np.linspace(lo, u, c)
                for lo, u, c in zip(self.lower, self.upper, self.counts(), strict=True)]

    @property
    def size(self) -> int:
        """Number of grid points (arithmetic: nothing is allocated, whatever the request)."""
        return math.prod(self.counts())


class CouplingRequest(BaseModel):
    """Configurations to analyse: an explicit list (read as a path) or a grid box."""

    model_config = _STRICT

    robot: Robot
    configurations: list[list[Angle]] | None = Field(
        default=None, description="joint angles [rad], one row per configuration; "
                                  "consecutive rows are joined by straight segments")
    grid: Grid | None = None
    threshold: float = Field(
        default=1e-3, ge=0.0,
        description="local minima of sigma_min below this [kg m^2] are reported as singular")

    @model_validator(mode="after")
    def _consistent(self) -> CouplingRequest:
        check_split(self.robot)
        n = self.robot.n
        if (self.configurations is None) == (self.grid is None):
            raise ValueError("configurations: give exactly one of configurations and grid")
        if self.configurations is not None:
            if not self.configurations:
                raise ValueError("configurations: needs at least one configuration")
            if len(self.configurations) > MAX_POINTS:
                raise ValueError(f"configurations: {len(self.configurations):,} exceed the "
                                 f"limit of {MAX_POINTS:,}")
            if any(len(row) != n for row in self.configurations):
                raise ValueError(f"configurations: every row needs {n} entries, one per joint")
        elif self.grid is not None:  # (the other of the two)
            if len(self.grid.lower) != n:
                raise ValueError(f"grid.lower: needs {n} entries, one per joint")
            if self.grid.size > MAX_POINTS:
                raise ValueError(f"grid.points: {self.grid.size:,} points exceed the limit of "
                                 f"{MAX_POINTS:,}; use fewer points per axis")
        return self


def check_split(robot: Robot) -> None:
    """Raise InputError when the robot has no coupling block (no passive joint)."""
    if not robot.passive:
        raise InputError("robot: has no passive joint, so there is no coupling block "
                         "(the arm is fully actuated)")
