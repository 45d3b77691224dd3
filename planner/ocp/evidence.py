"""The evidence of a plan that holds its task infeasible (`Infeasibility`)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from planner.ocp.output import Out


class ViolatedRows(Out):
    """The NLP's constraint rows of one kind that the reported iterate violates."""

    kind: str = Field(description="dynamics (collocation and M ddq + h - B tau), continuity "
                                  "(between intervals), torque limit, position bound, "
                                  "velocity bound, coupling margin or tip target")
    rows: int = Field(description="rows of this kind violated beyond 1e-6")
    largest: float = Field(description="the largest violation, in the rows' own units "
                                       "(N m for dynamics and limits, rad, rad/s, kg m^2, m)")
    time: float = Field(description="[s] where the largest violation is: the start of its "
                                    "interval, or the final time for a row of the final node")


class InfeasibleField(Out):
    """A field of the task that makes it infeasible, found before any solve."""

    field: str = Field(description='the field, a dotted path in the scene ("task.final.q.1")')
    kind: str = Field(description="the check: bounds, velocity reach, coupling margin, reach, "
                                  "zero torque")
    message: str


class Infeasibility(Out):
    """Why the planner holds the task infeasible, with its evidence (docs/planner.md,
    "Limits and failures")."""

    source: Literal["checks", "solver", "duration"] = Field(
        description="checks: a check before any solve failed (`fields`; no solve ran); "
                    "solver: two different starts ended locally infeasible, with a status "
                    "saying that their constraints cannot all hold near where they went (a "
                    "sign, not a proof: the plan's status is then solver-failure, not "
                    "infeasible); duration: the task's attempts gave no "
                    "converged plan and a time-optimal solve under its limits found a "
                    "verified plan only at a longer duration (`shortest_duration`)")
    summary: str = Field(description="one sentence: what cannot hold, and the evidence")
    fields: list[InfeasibleField] = Field(default_factory=list)
    attempts: list[str] = Field(
        default_factory=list, description="the starts that reported infeasibility, with "
                                          "their status")
    attempt: str | None = Field(
        default=None, description="the most informative of them (the least largest "
                                  "violation), whose iterate the plan is")
    violations: list[ViolatedRows] = Field(
        default_factory=list, description="the violated rows of that iterate by kind, the "
                                          "largest violation first")
    durations: list[float] = Field(
        default_factory=list, description="[s] the durations it covers: [T] for a fixed "
                                          "duration, [min, max] for a duration range")
    shortest_duration: float | None = Field(
        default=None, description="[s] the duration of the verified plan a time-optimal "
                                  "solve under the task's torque limit and velocity bounds "
                                  "ended at (docs/planner.md, \"Infeasible tasks\"): the task "
                                  "can be done in this duration, and the solve found none "
                                  "shorter near it; a local optimum, not proven the least "
                                  "duration. Null when none was found or tried")
