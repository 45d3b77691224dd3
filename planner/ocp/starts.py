"""The starts a plan tries, in order: an earlier plan's (`warm_starts`), then the scene's
own (`own_starts`; docs/planner.md, "Retries")."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from typing import Protocol

import numpy as np

from planner.errors import InputError
from planner.model import Robot
from planner.ocp import continuation, shortest
from planner.ocp.attempt import Attempt, Start
from planner.ocp.guess import (
    Guess,
    hermite_guess,
    interpolant_guess,
    inverse_dynamics_guess,
    plan_guess,
)
from planner.ocp.mesh import Mesh
from planner.ocp.problem import ProblemKey
from planner.ocp.recall import recall
from planner.ocp.result import Plan
from planner.scene import DurationRange, Scene

WARM_ITERATIONS = 100
"""Iterations each first solve started from an earlier plan (or a plan example's motion)
may take before the next start takes over: a warm start near its optimum converges in a
few (docs/benchmarks.md, "Memory of motion": at most 34 where it beat the cold plan but
one), while those that failed ran for half a minute before the cold starts began ("Warm
replanning"). The refinements of one that converged are not capped in iterations, but
there are at most WARM_REFINEMENTS of them: such a start is there to be quick."""
WARM_REFINEMENTS = 1
"""Mesh refinements of a plan started from an earlier plan or an example's motion: a
recalled motion of the seed arm with its goal moved (N = 40) was refined pass after pass
without becoming accurate before the scene's own start gave the verified plan, 6.4 s in
all (docs/benchmarks.md, "Built-in plan examples with their goals moved", at the commit
that set this cap); with one refinement no moved example goal took over 1.15 s."""
COARSE_INTERVALS = 50  # a uniform mesh finer than this is first solved on this many intervals
SECOND_OPINION_SHARE = 0.15
"""The most of the plan's wall time the inverse-dynamics start after a duration probe that
showed the task too short may take: the probe's evidence stands only once that start
fails too."""


class DurationProbe(Protocol):
    """What the scene's own starts ask of the plan's duration probe
    (`planner.ocp.duration_probe`)."""

    @property
    def too_short(self) -> bool: ...

    def run(self, attempts: list[Attempt]) -> None: ...

    def start(self) -> Start | None: ...


def warm_starts(scene: Scene, robot: Robot, T: float, warm_start: Plan | None,
                stall: bool = True, recalled: bool = True) -> Iterator[Start]:
    """The attempts an earlier plan gives, tried before the scene's own, which follow them
    unchanged when they fail: its NLP solution, primal and dual, where it solved the same
    problem on a mesh at least as fine as the scene's (its refined mesh is kept); then its
    trajectory as the initial guess on the scene's own mesh, from Ipopt's own barrier
    parameter. Each is stopped when it stalls (stall: as the scene's own start). A goal
    moved across the earlier plan's optimum can send the primal-dual start, from its small
    barrier parameter, wandering for thousands of iterations where the trajectory alone
    converges in tens (docs/planner.md, "Memory of motion"). Without an earlier plan: the
    nearest plan example's motion as the initial guess, where one is near (`recalled`:
    `planner.ocp.recall`)."""
    if warm_start is None:
        found = recall(scene) if recalled else None
        if found is not None:
            yield Start(f"example {found[0].example} as the guess", first_mesh(scene),
                        plan_guess(found[0]), "recalled example", T, robot, may_stall=stall,
                        max_iter=WARM_ITERATIONS, max_refinements=WARM_REFINEMENTS)
        return
    guess = earlier_guess(robot, warm_start)
    earlier, mesh = warm_start.solution, first_mesh(scene)
    if earlier is not None:
        solved_on = Mesh(np.asarray(earlier.breaks))
        same = ProblemKey.of(scene, solved_on.intervals).fingerprint() == earlier.fingerprint
        if same and solved_on.intervals >= mesh.intervals:
            yield Start("warm start", solved_on, guess, "warm start", warm_start.duration,
                        robot, earlier, may_stall=stall, max_iter=WARM_ITERATIONS,
                        max_refinements=WARM_REFINEMENTS)
    yield Start("earlier plan as the guess", mesh, guess, "warm start", T, robot,
                may_stall=stall, max_iter=WARM_ITERATIONS, max_refinements=WARM_REFINEMENTS)


def own_starts(scene: Scene, robot: Robot, T: float, attempts: list[Attempt],
               probe: DurationProbe | None = None, stall: bool = True) -> Iterator[Start]:
    """The scene's own attempts, in order, each tried while the ones before it have not given a
    converged plan (with mesh refinement on: an accurate one): the scene's own start (with
    refinement on, a uniform mesh of over COARSE_INTERVALS intervals solved on that many
    first; with a torque limit or velocity bounds, the task without them solved first:
    `attempt.unlimited_solve`); after it the duration probe, where given (when it shows the
    duration too short no start follows, and a time-optimal plan it found within the task's
    durations is the next start; where the probe applies, the scene's own start may take
    `shortest.FIRST_SHARE` of the wall time before it runs; one that showed it too short is
    followed by the inverse-dynamics start alone, within SECOND_OPINION_SHARE); the
    continuation from relaxed
    dynamics, where it applies; then the rescues (`_rescues`). stall: the scene's own start
    is stopped when it stalls (where no companion process solves the continuation)."""
    mesh = first_mesh(scene)
    guess, used = scene_guess(scene, robot, T)
    share = shortest.FIRST_SHARE if probe is not None and shortest.applies(scene) else 1.0
    tr = scene.transcription
    later = shortest.applies(scene)
    if tr.refinement.enabled and tr.breaks is None and tr.intervals > COARSE_INTERVALS:
        yield Start("coarse to fine", mesh, guess, used, T, robot,
                    coarse=Mesh.uniform(COARSE_INTERVALS), may_stall=stall, time_share=share,
                    limits_later=later)
    else:
        yield Start("direct", mesh, guess, used, T, robot, may_stall=stall, time_share=share,
                    limits_later=later)
    if probe is not None:
        probe.run(attempts)
        if probe.too_short:  # a local minimum of the duration: one converged plan at
            # the task's own duration, from an independent start, refutes it
            yield from _inverse_dynamics_start(scene, robot, T, used, SECOND_OPINION_SHARE)
            return
        fastest = probe.start()
        if fastest is not None:
            yield fastest
    if continuation.applies(scene):
        yield continuation_start(scene, robot, T)
    yield from _rescues(scene, robot, T, attempts, used)


def _inverse_dynamics_start(scene: Scene, robot: Robot, T: float, used: str,
                            time_share: float = 1.0) -> Iterator[Start]:
    """The classical inverse dynamics as the initial guess, where it applies and was not
    the scene's own guess already, within `time_share` of the plan's wall time."""
    if used != "inverse-dynamics" and _inverse_dynamics_applies(robot):
        with contextlib.suppress(ValueError):
            yield Start("inverse-dynamics start", first_mesh(scene),
                        inverse_dynamics_guess(scene, robot, T), "inverse-dynamics", T, robot,
                        time_share=time_share)


def _rescues(scene: Scene, robot: Robot, T: float, attempts: list[Attempt],
             used: str) -> Iterator[Start]:
    """The last starts: a restart from the last iterate of the scene's start where that
    neither converged nor stalled; the classical inverse dynamics as the initial guess; a
    first mesh of twice, then of half the intervals."""
    last = [a for a in attempts if not a.start.relaxed][-1].outcomes[-1]
    if last.finite and not last.solution.success and last.solution.status != "Stalled":
        yield Start("restart from the last iterate", last.inst.mesh,
                    interpolant_guess(last.interp, last.T), "the last iterate", last.T,
                    last.robot, continues=True)
    yield from _inverse_dynamics_start(scene, robot, T, used)
    first = hermite_guess(scene, robot, T)
    intervals = scene.transcription.intervals
    for count in (2 * intervals, max(intervals // 2, 1)):
        yield Start(f"first mesh of {count} intervals", Mesh.uniform(count), first,
                    "interpolation", T, robot)


def first_mesh(scene: Scene) -> Mesh:
    """The scene's own first mesh: its breaks, else equal intervals."""
    tr = scene.transcription
    return Mesh(np.asarray(tr.breaks)) if tr.breaks else Mesh.uniform(tr.intervals)


def continuation_start(scene: Scene, robot: Robot, T: float) -> Start:
    """The continuation start (`planner.ocp.continuation`) on the scene's first mesh."""
    return Start("continuation", first_mesh(scene), continuation.relaxed_guess(scene, robot, T),
                 "relaxed dynamics", T, robot, relaxed=True)


def _inverse_dynamics_applies(robot: Robot) -> bool:
    """The classical inverse dynamics needs passive joints and as many active ones."""
    return 0 < len(robot.passive) <= len(robot.active)


def earlier_guess(robot: Robot, earlier: Plan) -> Guess:
    """An earlier plan's trajectory as the initial guess; InputError when it is of
    another arm."""
    shape = (len(earlier.q[0]), len(earlier.tau[0]))
    if shape != (robot.n, len(robot.active)):
        raise InputError(f"warm_start: the earlier plan is of an arm with {shape[0]} joints, "
                         f"{shape[1]} of them active; this one has {robot.n}, "
                         f"{len(robot.active)}")
    return plan_guess(earlier)


def scene_guess(scene: Scene, robot: Robot, T: float) -> tuple[Guess, str]:
    """The scene's initial guess (`solver.initial_guess`) and what it was: an inverse
    dynamics that cannot be computed leaves the interpolation."""
    if scene.solver.initial_guess == "inverse-dynamics":
        try:
            return inverse_dynamics_guess(scene, robot, T), "inverse-dynamics"
        except ValueError as exc:
            return hermite_guess(scene, robot, T), f"interpolation; inverse-dynamics refused: {exc}"
    return hermite_guess(scene, robot, T), "interpolation"


def duration_guess(scene: Scene) -> float:
    """The duration [s] a plan starts from: the task's, or the geometric mean of its range."""
    d = scene.task.duration
    return math.sqrt(d.min * d.max) if isinstance(d, DurationRange) else d
