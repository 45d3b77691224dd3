"""plan(): plan a scene's feed-forward torques.

The story of a plan, one module a step:
1. the checks before any solve (`planner.feasibility`; or what they found when the caller
   ran them, `issues`): a task they hold infeasible is refused at once
   (`planner.ocp.infeasibility.refused`);
2. the cores it may use (`planner.ocp.cores`): with a spare one, a forked companion solves
   the continuation start beside the plan's own starts (`planner.ocp.portfolio`);
3. its starts (`planner.ocp.starts`): an earlier plan's, with few iterations, then the
   scene's own in order, the duration probe among them (`planner.ocp.duration_probe`);
4. each start's attempt (`planner.ocp.attempt`): its solves and mesh refinements, tried in
   turn until one settles (`planner.ocp.retries`);
5. the result (`planner.ocp.report`): the best outcome, checked (`planner.ocp.verify`),
   with the infeasibility its attempts establish (`planner.ocp.infeasibility`).
"""

from __future__ import annotations

import itertools
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, replace

from planner import feasibility
from planner.feasibility import Issue
from planner.model import Robot
from planner.ocp import continuation, cores, infeasibility, portfolio, shortest
from planner.ocp.attempt import Attempt, Start
from planner.ocp.codesign import design_robot
from planner.ocp.duration_probe import DurationProbe
from planner.ocp.monitor import Handler
from planner.ocp.report import joined, plan_of
from planner.ocp.result import MeshPass, Plan
from planner.ocp.retries import ended, planned, settled, try_starts
from planner.ocp.solve import Budget
from planner.ocp.starts import continuation_start, duration_guess, own_starts, warm_starts
from planner.scene import Scene

COMPANION_GRACE = 3.0
"""[s] past the budget the plan waits for its companion's plan (its checks): less than
the plan's MARGIN (`planner.ocp.solve`), which also covers what follows the wait."""


@dataclass(frozen=True)
class WarmStart:
    """An earlier plan to start from, with where it came from: the service's id of its job
    and, when it was the nearest stored one, its distance [rad] (`planner.memory.distance`)."""

    plan: Plan
    job_id: str
    distance: float | None = None


def plan(scene: Scene, progress: Handler | None = None,
         warm_start: Plan | WarmStart | None = None, *, starts: Collection[str] | None = None,
         issues: Sequence[Issue] | None = None) -> Plan:
    """Plan feed-forward torques for a scene.

    progress is called once per Ipopt iteration; returning False stops the plan.
    warm_start: an earlier plan whose trajectory (or NLP solution) is tried first; as a
    `WarmStart`, the plan's report names where it came from (`solver.warm_start`,
    `solver.warm_start_distance`).
    starts: the names of the scene's own starts the plan may try (`Plan.solver.strategy`
    names them: "direct", "coarse to fine", "continuation", ...), in the planner's order;
    None: all, and a companion process where one helps.
    issues: what the checks before a solve (`planner.feasibility.check`) already found for
    this scene, e.g. when the service admitted it: any refuses the plan, none lets it solve
    without checking again; None: the checks run here.
    A failed solve is returned (success False, the last iterate), never raised. A task
    known infeasible before a solve returns at once, and one the solver holds infeasible
    says so (`Plan.infeasibility`).
    """
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    found = feasibility.check(scene) if issues is None else list(issues)
    if found:
        refused = infeasibility.refused(scene, found, budget.started, duration_guess(scene))
        return _started_from(refused, warm_start)
    earlier = warm_start.plan if isinstance(warm_start, WarmStart) else warm_start
    wanted = starts is None and continuation.applies(scene) and scene.solver.retries > 0 \
        and portfolio.solver_processes() >= 2
    own = cores.take()
    spare = cores.take() if wanted and own is not None else None
    try:
        result = _planned(scene, progress, earlier, budget, starts, alone=spare is None)
    finally:
        cores.release(own, spare)
    return _started_from(result, warm_start)


def _started_from(result: Plan, warm_start: Plan | WarmStart | None) -> Plan:
    """The plan with the job it was given to start from, and its distance, in its report
    (unchanged without a `WarmStart`)."""
    if not isinstance(warm_start, WarmStart):
        return result
    report = result.solver.model_copy(update={"warm_start": warm_start.job_id,
                                              "warm_start_distance": warm_start.distance})
    return result.model_copy(update={"solver": report})


def shortest_duration(scene: Scene, lowest: float | None = None) -> shortest.Probe:
    """The duration probe (`planner.ocp.shortest`) of a scene's task on its own, within the
    scene's whole budget: the unlimited motion, stretched, then a time-optimal solve whose
    duration may go down to `lowest` [s] (default: the task's shortest)."""
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    probe = DurationProbe(scene, design_robot(scene), budget, None)
    return shortest.probe(scene, budget, probe.solve, probe.motion, lowest, share=1.0)


def _planned(scene: Scene, progress: Handler | None, warm_start: Plan | None, budget: Budget,
             names: Collection[str] | None, alone: bool) -> Plan:
    """The plan in this process alone, or beside a companion that solves the continuation
    (forked once an earlier plan, if one was given, has failed to start it)."""
    robot, T = design_robot(scene), duration_guess(scene)
    attempts: list[Attempt] = []
    try_starts(scene, warm_starts(scene, robot, T, warm_start, stall=alone,
                                  recalled=names is None), attempts, budget, progress)
    if attempts and ended(scene, attempts, budget):
        return plan_of(scene, attempts, budget)
    if not alone:
        return _beside_companion(scene, robot, T, attempts, budget, progress)
    probe = DurationProbe(scene, robot, budget, progress)
    try_starts(scene, _own(scene, attempts, probe, names, alone), attempts, budget, progress)
    return plan_of(scene, attempts, budget, probe.found, probe.after)


def _own(scene: Scene, attempts: list[Attempt], probe: DurationProbe,
         names: Collection[str] | None, alone: bool) -> Iterator[Start]:
    """The scene's own starts the plan tries: those named (all without names), at most
    1 + solver.retries of them."""
    robot, T = probe.robot, duration_guess(scene)
    chosen = (s for s in own_starts(scene, robot, T, attempts, probe, stall=alone)
              if names is None or s.name in names)
    return itertools.islice(chosen, 1 + scene.solver.retries)


def _beside_companion(scene: Scene, robot: Robot, T: float, attempts: list[Attempt],
                      budget: Budget, progress: Handler | None) -> Plan:
    """The plan of the scene's own starts (the continuation left out, `robot` and T [s]
    the plan's starting ones) beside a forked companion that solves the continuation: the
    first verified plan wins."""
    relaxed = continuation_start(scene, robot, T)
    companion = portfolio.Companion(lambda guard: planned(scene, relaxed, replace(budget), guard))
    try:
        handler = portfolio.Watch(companion, progress)
        probe = DurationProbe(scene, robot, budget, handler)
        starts = (s for s in _own(scene, attempts, probe, None, False) if not s.relaxed)
        try_starts(scene, starts, attempts, budget, handler)
        if not handler.cancelled and companion.verified() and companion.plan is not None:
            return joined(companion.plan, _records(attempts), budget)
        if attempts and settled(scene, attempts):
            companion.defer()  # its plan is then rarely taken: the checks come first
        own = plan_of(scene, attempts, budget, probe.found, probe.after)
        if handler.cancelled or own.infeasibility is not None \
                or own.solver.success and own.verification.verified:
            return joined(own, [], budget)
        other = companion.wait(budget.deadline + COMPANION_GRACE)
        chosen = own if other is None or portfolio.better(own, other) else other
        return joined(chosen, [], budget)
    finally:
        companion.stop()


def _records(attempts: list[Attempt]) -> list[MeshPass]:
    return [o.record for a in attempts for o in a.passes]
