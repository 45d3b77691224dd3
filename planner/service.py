"""The planner as the HTTP service (app/) sees it: the one module through which it
reaches `planner.ocp`.

The service needs the request (a `Scene`), what admits it as a plan job (`admit`: the
checks before a solve, each `Issue` a reason its task is infeasible), the function that
plans it (`plan`, given the issues admission found, so that a job's plan does not check
again, and the earlier plan it starts from as a `WarmStart`, so that the plan's report names
it), the result (`Plan`, its Ipopt iterate `NlpSolution` for a warm start, the `Progress` a
solve reports), the reason a finished plan is not verified (`verdict_reason`, or
`unverified_reason` of its verification), the plan sampled at any times (`Plan.sample`,
`PlanSample`), and what a transcription costs: its time nodes (the server's node limit) and
its knots (the memory estimate), the stored plan a scene should start from (`nearest`,
memory of motion), and replanning a finished plan from measured states (`Replanner`, fed a
client's `StateUpdate`, its updates reported as `ReplanReport`).
Everything else of the optimal-control package stays internal to the library
and may change without the service noticing. `tests/test_service_interface.py` holds
app/ to this module.
"""

from __future__ import annotations

from typing import get_args

from planner import feasibility
from planner.feasibility import Issue
from planner.memory import NEAREST, nearest
from planner.ocp import methods
from planner.ocp.planner import WarmStart, plan
from planner.ocp.replan import Replanner
from planner.ocp.replan_report import ReplanReport, StateUpdate
from planner.ocp.result import MAX_SAMPLE_TIMES, NlpSolution, Plan, PlanSample, Progress
from planner.ocp.transcription import AnyTranscription
from planner.ocp.verdict import unverified_reason
from planner.scene import DurationRange, Method, Scene, Transcription

METHODS: tuple[str, ...] = get_args(Method)
"""The transcription methods a scene may name (`transcription.method`)."""


def admit(scene: Scene) -> list[Issue]:
    """The checks before a solve (`planner.feasibility`): every reason the scene's task is
    known infeasible before one (empty: none). Give them to `plan(..., issues=)`, which then
    does not run them again."""
    return feasibility.check(scene)


def transcription(settings: Transcription, intervals: int | None = None) -> AnyTranscription:
    """The transcription a scene's settings ask for, on `intervals` intervals (default: its
    own; a mesh of its own breaks is replaced by a uniform one)."""
    if intervals is not None:
        settings = settings.model_copy(update={"intervals": intervals, "breaks": None})
    return methods.of(settings)


def node_count(settings: Transcription, intervals: int | None = None) -> int:
    """Time points the NLP of these settings holds variables at (`intervals`: as in
    `transcription`)."""
    return transcription(settings, intervals).node_count()


def knot_count(settings: Transcription, intervals: int | None = None) -> int:
    """Points where the NLP of these settings makes the dynamics hold."""
    return transcription(settings, intervals).knot_count()


def verdict_reason(result: Plan) -> str | None:
    """Why a finished plan is not verified (None when it is)."""
    return unverified_reason(result.verification)


__all__ = ["MAX_SAMPLE_TIMES", "METHODS", "NEAREST", "DurationRange", "Issue", "NlpSolution",
           "Plan", "PlanSample", "Progress", "ReplanReport", "Replanner", "Scene", "StateUpdate",
           "Transcription", "WarmStart", "admit", "knot_count", "nearest", "node_count", "plan",
           "transcription", "unverified_reason", "verdict_reason"]
