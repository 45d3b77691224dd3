"""The report of the coupling analysis: the shape of M_pa, its measures at every
configuration, the singular points and the smallest sigma_min met."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel

from planner.model import Robot

SplitKind = Literal["square", "fewer-active", "more-active"]


class Split(BaseModel):
    """Passive and active joints (0-based) and the shape of M_pa."""

    passive: list[int]
    active: list[int]
    kind: SplitKind
    note: str


class PointResult(BaseModel):
    """Coupling measures at one configuration; det only for a square block, condition
    None where sigma_min is zero."""

    q: list[float]
    det: float | None
    sigma_min: float
    condition: float | None


class SingularPoint(BaseModel):
    """A configuration where M_pa loses rank (refined sign change of det) or sigma_min has
    a local minimum below the threshold."""

    q: list[float]
    det: float | None
    sigma_min: float
    source: Literal["det-sign-change", "sigma-minimum"]


class MinSigma(BaseModel):
    """Smallest sigma_min met [kg m^2] and where."""

    q: list[float]
    sigma_min: float


class CouplingReport(BaseModel):
    """Coupling measures at every configuration, the singular points and the minimum.

    For grids larger than MAX_RESULTS points `results` is empty and `results_omitted`
    counts the points left out (the singular points and the minimum are still complete).
    Grid results are listed in row-major order (the last joint varies fastest).
    """

    split: Split
    results: list[PointResult]
    results_omitted: int = 0
    singular_points: list[SingularPoint]
    singular_points_omitted: int = 0
    min_sigma: MinSigma


def split_of(robot: Robot) -> Split:
    """Classify M_pa: square, fewer active than passive joints, or more."""
    passive, active = robot.passive, robot.active
    if len(active) == len(passive):
        kind: SplitKind = "square"
        note = (f"M_pa is {len(passive)} x {len(active)}: the active accelerations follow "
                "uniquely from the passive motion where det M_pa != 0")
    elif len(active) < len(passive):
        kind = "fewer-active"
        note = (f"only {len(active)} active joints for {len(passive)} passive: M_pa cannot "
                "have full row rank, so the passive motion cannot be prescribed in full "
                "(sigma_min is 0 everywhere)")
    else:
        kind = "more-active"
        note = (f"{len(active)} active joints for {len(passive)} passive: the inverse "
                "dynamics uses the minimum-norm active accelerations; singular where "
                "M_pa loses row rank (sigma_min = 0)")
    return Split(passive=passive, active=active, kind=kind, note=note)
