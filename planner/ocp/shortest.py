"""The shortest duration a task's limits allow: evidence that its duration is too short,
or a feasible start for it.

A torque limit and velocity bounds are what can make a duration too short (without them a
motion can be run as fast as asked). When a task with either gives no converged plan from
its first start (which may take FIRST_SHARE of the wall time), the planner probes its
shortest duration (`probe`) before further starts:

1. the task without its torque limit and velocity bounds, at MOTION_SPAN times its
   (longest) duration T: the motion it asks for, slowed so that it converges easily;
2. that motion stretched in time by the least factor s that brings its torque and rates
   within the limits (stretched by s, a motion needs its rates divided by s and the
   torque beside gravity's by s^2, exactly: `stretch_factor`), a start that keeps them;
3. from it, a time-optimal solve: the duration free between the task's shortest and
   SPAN times the stretched motion's, the duration minimised with a little effort beside
   it (EFFORT_SHARE).

A verified time-optimal plan whose duration T* exceeds the task's longest duration by more
than DURATION_RTOL is the evidence that the task is infeasible: the solve's duration is at
a local minimum above the task's, its lower bound inactive (`Probe.too_short`). One within
the task's durations keeps every limit at a duration the task allows, and starts the task's
own solve (`Probe.start`). A probe that finds no verified plan decides nothing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planner.dynamics import Dynamics
from planner.ocp.guess import Guess, plan_guess, stretched
from planner.ocp.result import MeshPass, Plan
from planner.ocp.solve import Budget
from planner.scene import DurationRange, Objective, Scene

DURATION_RTOL = 1e-3
"""A time-optimal duration above the task's longest by more than this share shows the task
too short (Ipopt keeps the duration's bound to about 1e-8 when it is active)."""
PROBE_SHARE = 0.15
"""The most of the plan's wall time the probe's two solves may take together."""
FIRST_SHARE = 0.1
"""The most of the plan's wall time the scene's own first start may take before the probe
runs (on an infeasible task Ipopt's iterations can slow to half a second each)."""
MOTION_SPAN = 2.0
"""The unlimited motion is planned at this many times the task's longest duration: a
slower motion converges where a fast one of an underactuated arm stalls."""
SPAN = 4.0
"""The time-optimal solve's longest duration, in multiples of the stretched motion's."""
STRETCH_MARGIN = 1.05
"""The stretched motion's peak torque and rates stay this factor inside the limits."""
PASS_PREFIX = "shortest-duration probe"
"""How the plan's `mesh_passes` name the probe's solves."""
EFFORT_SHARE = 1e-2
"""The effort's weight in the time-optimal objective: this share of the duration at the
stretched motion's effort."""

Solver = Callable[[Scene, Guess, str, float, Budget], Plan]
"""solver(scene, guess, what the guess is, T [s] to start from, budget): the plan of one
start of `scene` (the planner's own, with its refinement and checks)."""
Planner = Callable[[Scene, Budget], Plan]
"""planner(scene, budget): the plan of a scene from the planner's own first starts."""


@dataclass(frozen=True)
class Probe:
    """What the probe found: the verified time-optimal plan (None: none found), whether it
    shows the task's duration too short, and a sentence saying what was done."""

    plan: Plan | None
    too_short: bool
    note: str
    passes: list[MeshPass]
    """The probe's solves, named after it (`PASS_PREFIX`)."""

    @property
    def shortest(self) -> float | None:
        """[s] The time-optimal plan's duration (None without one)."""
        return None if self.plan is None else self.plan.duration


def applies(scene: Scene) -> bool:
    """Whether the task's duration can be too short for it: a torque limit or velocity
    bounds, no prescribed motion (which needs its fixed duration), no wave co-design."""
    task = scene.task
    limited = task.torque_limit is not None or task.velocity_bounds is not None
    return limited and task.tracking is None and task.co_design is None


def unlimited(scene: Scene, T: float) -> Scene:
    """The task at duration T [s] without its torque limit and velocity bounds, its
    effort minimised (at least a little of it, so that the problem has an objective)."""
    objective = Objective(effort=max(scene.task.objective.effort, 1.0), time=0.0,
                          smoothness=scene.task.objective.smoothness)
    task = scene.task.model_copy(update={"duration": T, "torque_limit": None,
                                         "velocity_bounds": None, "objective": objective})
    return scene.model_copy(update={"task": task})


def time_optimal(scene: Scene, shortest: float, longest: float, effort: float) -> Scene:
    """The task with its duration free in [shortest, longest] [s] and the objective
    duration + `effort` x effort, solved by Ipopt (fatrop states no free duration)."""
    objective = Objective(effort=effort, time=1.0, smoothness=0.0)
    task = scene.task.model_copy(update={
        "duration": DurationRange(min=shortest, max=longest), "objective": objective})
    solver = scene.solver.model_copy(update={"name": "ipopt"})
    return scene.model_copy(update={"task": task, "solver": solver})


def stretch_factor(scene: Scene, motion: Plan) -> float:
    """The factor s >= 1 by which stretching `motion` in time brings its torque and its
    rates within the task's limits, STRETCH_MARGIN inside them (`_torque_stretch`; rates
    scale as 1/s); inf where a zero limit meets a torque."""
    task = scene.task
    factor = 1.0 if task.torque_limit is None else _torque_stretch(scene, motion)
    if task.velocity_bounds is not None:
        dq = np.asarray(motion.dq, float)
        for j, (lo, hi) in enumerate(zip(task.velocity_bounds.lower,
                                         task.velocity_bounds.upper, strict=True)):
            fast = [float(dq[:, j].max()) / hi if hi is not None and hi > 0 else 0.0,
                    float(dq[:, j].min()) / lo if lo is not None and lo < 0 else 0.0]
            factor = max(factor, STRETCH_MARGIN * max(fast))
    return factor


def _torque_stretch(scene: Scene, motion: Plan) -> float:
    """The least s >= 1 with |I(t) / s^2 + G(t)| <= limit / STRETCH_MARGIN along the motion's
    dense samples, G the gravity torque of the active joints and I = tau - G the rest of the
    torque (stretched by s, the motion needs its rates over s and its accelerations over
    s^2, so I scales as 1/s^2 and G stays). Where G alone is beyond the limit no stretch
    keeps it: then the s that would bring the whole torque within it (inf for a zero
    limit), for a start that is not feasible but near. The set
    of u = 1/s^2 that keep the limit is an interval (|u I + G| is convex in u) holding 0
    when G keeps it: its upper end is found by bisection."""
    tau = np.asarray(motion.dense.tau, float)
    limit = np.broadcast_to(np.asarray(scene.task.torque_limit, float),
                            tau.shape[1:]) / STRETCH_MARGIN
    dynamics = Dynamics(scene.robot)
    active = scene.robot.active
    G = np.array([dynamics.gravity(q)[active] for q in np.asarray(motion.dense.q, float)])
    inertial = tau - G

    def keeps(u: float) -> bool:
        return bool(np.all(np.abs(u * inertial + G) <= limit))

    if keeps(1.0):
        return 1.0
    if not keeps(0.0):  # the stretch that scales the whole torque: a start, if no witness
        peak = np.abs(tau).max(axis=0)
        return math.sqrt(float(np.max(peak / limit))) if np.all(limit > 0.0) else math.inf
    low, high = 0.0, 1.0  # keeps(low), not keeps(high)
    for _ in range(60):
        middle = (low + high) / 2
        low, high = (middle, high) if keeps(middle) else (low, middle)
    return math.inf if low == 0.0 else 1.0 / math.sqrt(low)


def _effort(motion: Plan) -> float:
    """[N^2 m^2 s] The integral of |tau|^2 over the motion's dense samples (trapezoids)."""
    t, tau = np.asarray(motion.dense.t, float), np.asarray(motion.dense.tau, float)
    return float(np.trapezoid(np.sum(tau ** 2, axis=1), t))


def _share(budget: Budget, share: float) -> Budget:
    """A budget of the plan's iterations per solve, ending `share` of the plan's wall time
    from now or at the plan's solves' end, whichever comes first; its iterations count on
    from the plan's."""
    now = time.perf_counter()
    end = min(now + share * (budget.deadline - budget.started), budget.solves_until)
    return Budget(started=now, deadline=max(end, now), max_iter=budget.max_iter,
                  used=budget.used)


def probe(scene: Scene, budget: Budget, solve: Solver, plan_motion: Planner,
          lowest: float | None = None, share: float = PROBE_SHARE) -> Probe:
    """The shortest duration of the task's motion under its limits (see the module), within
    `share` of the plan's wall time; `plan_motion` plans the unlimited motion, `solve` the
    time-optimal task from its stretch; `lowest` [s]: the time-optimal solve's shortest
    duration (default: the task's)."""
    shortest, longest = scene.task.duration_span
    shortest = shortest if lowest is None else lowest
    sub = _share(budget, share)
    slow = MOTION_SPAN * longest
    free = unlimited(scene, slow)
    motion = plan_motion(free, sub)
    passes = _named(motion, "the task without its limits")
    if not (motion.solver.success and motion.verification.verified):
        return _done(budget, sub, passes, None, False, f"the task without its limits gave no "
                                                       f"verified motion in {slow:g} s "
                                                       f"({motion.solver.status})")
    s = stretch_factor(scene, motion)
    if not math.isfinite(s):
        return _done(budget, sub, passes, None, False, "a zero torque limit stops a joint the "
                                                       "motion needs")
    effort = _effort(motion) / s ** 3  # the stretched motion's, exact without gravity
    weight = EFFORT_SHARE * s * slow / effort if effort > 0.0 else EFFORT_SHARE
    fastest = time_optimal(scene, shortest, max(SPAN * s * slow, longest), weight)
    guess = stretched(plan_guess(motion), s, scene.robot)
    found = solve(fastest, guess, "the task's motion without its limits, stretched",
                  s * slow, sub)
    passes += _named(found, "time-optimal")
    if not (found.solver.success and found.verification.verified):
        return _done(budget, sub, passes, None, False, f"the time-optimal solve gave no verified "
                                               f"plan ({found.solver.status})")
    too_short = found.duration > longest * (1.0 + DURATION_RTOL)
    note = (f"a time-optimal solve under the task's limits, from its motion without them "
            f"stretched to keep them, ended at a verified plan of {found.duration:.4g} s"
            + (f", {found.duration / longest - 1:.1%} above {longest:g} s (a local optimum of "
               f"that solve: the task can be done in {found.duration:.4g} s, and no shorter "
               f"duration was found near it)" if too_short else ""))
    return _done(budget, sub, passes, found, too_short, note)


def _named(plan: Plan, what: str) -> list[MeshPass]:
    """The plan's solves, their strategy prefixed with the probe's name and `what`."""
    return [m.model_copy(update={"strategy": f"{PASS_PREFIX}, {what}: {m.strategy}"})
            for m in plan.mesh_passes]


def _done(budget: Budget, sub: Budget, passes: list[MeshPass], plan: Plan | None,
          too_short: bool, note: str) -> Probe:
    """The probe's result; the plan's iteration count, and when its latest solve ended,
    take the probe's on."""
    budget.used, budget.solved = sub.used, sub.solved or budget.solved
    return Probe(plan, too_short, note, passes)
