"""Trying starts in turn (`try_starts`): each start's attempt is solved and refined until
one gives a settled converged plan, the budget is spent, the plan is stopped, or the
attempts agree that the task is infeasible."""

from __future__ import annotations

from collections.abc import Iterable

from planner.ocp import infeasibility
from planner.ocp.attempt import Attempt, Start, attempt
from planner.ocp.monitor import Handler
from planner.ocp.report import plan_of
from planner.ocp.result import Plan
from planner.ocp.solve import Budget
from planner.scene import Scene


def try_starts(scene: Scene, starts: Iterable[Start], attempts: list[Attempt], budget: Budget,
               progress: Handler | None) -> None:
    """Solve and refine from each start in turn, appending its attempt to `attempts`,
    until `ended`."""
    for start in starts:
        attempts.append(attempt(scene, start, budget, progress, passes(attempts)))
        if ended(scene, attempts, budget):
            break


def ended(scene: Scene, attempts: list[Attempt], budget: Budget) -> bool:
    """Whether no further start should be tried: the last attempt gave a settled converged
    plan (accurate, or refinement off), the budget is spent, the plan was stopped, or two
    attempts agree that the task is infeasible."""
    last = attempts[-1].outcomes[-1]
    return settled(scene, attempts) or budget.spent \
        or last.solution.status == "User_Requested_Stop" or infeasibility.agreed(attempts)


def settled(scene: Scene, attempts: list[Attempt]) -> bool:
    """Whether the last attempt gave a settled converged plan: accurate, or refinement
    off (no further start is tried, and the plan is checked next)."""
    last = attempts[-1].outcomes[-1]
    accurate = last.accurate(scene.solver.resimulation_tolerance) \
        or not scene.transcription.refinement.enabled
    return bool(last.solution.success and accurate)


def planned(scene: Scene, start: Start, budget: Budget, progress: Handler | None) -> Plan:
    """The plan of one start alone (what a companion process or the duration probe runs)."""
    attempts: list[Attempt] = []
    try_starts(scene, [start], attempts, budget, progress)
    return plan_of(scene, attempts, budget)


def passes(attempts: list[Attempt]) -> int:
    """The solves of the attempts so far."""
    return sum(len(a.passes) for a in attempts)
