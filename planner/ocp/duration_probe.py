"""The plan's duration probe (`planner.ocp.shortest`), run from its starts: at most once,
after one of the scene's own attempts has given no converged plan, where the task's limits
can make its duration too short."""

from __future__ import annotations

import numpy as np

from planner.model import Robot
from planner.ocp import continuation, shortest
from planner.ocp.attempt import Attempt, Start
from planner.ocp.guess import Guess, plan_guess, stretched
from planner.ocp.mesh import Mesh
from planner.ocp.monitor import Handler
from planner.ocp.result import Plan
from planner.ocp.retries import passes, planned
from planner.ocp.solve import Budget
from planner.ocp.starts import continuation_start, duration_guess, first_mesh, scene_guess
from planner.scene import Scene


class DurationProbe:
    """The probe of one plan; `found`: what it found once it ran, `after`: the plan's
    solves before it."""

    def __init__(self, scene: Scene, robot: Robot, budget: Budget, progress: Handler | None):
        self.scene, self.robot, self.budget, self.progress = scene, robot, budget, progress
        self.found: shortest.Probe | None = None
        self.after = 0

    def run(self, attempts: list[Attempt]) -> None:
        """Probe, unless it ran already, does not apply, an attempt converged or the
        budget is spent."""
        converged = any(o.solution.success for a in attempts for o in a.outcomes)
        if self.found is None and shortest.applies(self.scene) and not converged \
                and not self.budget.spent:
            self.after = passes(attempts)
            self.found = shortest.probe(self.scene, self.budget, self.solve, self.motion)

    @property
    def too_short(self) -> bool:
        """It ran and showed the task's duration too short."""
        return self.found is not None and self.found.too_short

    def start(self) -> Start | None:
        """The task's start from the probe's time-optimal plan, stretched to the nearest
        duration the task allows, on that plan's mesh (None without such a plan)."""
        found = self.found
        if found is None or found.too_short or found.plan is None:
            return None
        fastest = found.plan
        shortest_allowed, longest = self.scene.task.duration_span
        T = min(max(fastest.duration, shortest_allowed), longest)
        breaks = np.asarray(fastest.t) / fastest.duration
        breaks[0], breaks[-1] = 0.0, 1.0
        guess = stretched(plan_guess(fastest), T / fastest.duration, self.robot)
        return Start("shortest-duration plan", Mesh(breaks), guess,
                     "the time-optimal plan under the task's limits", T, self.robot)

    def solve(self, scene: Scene, guess: Guess, used: str, T: float, budget: Budget) -> Plan:
        """The plan of one start of `scene` from `guess` (what it is: `used`) at T [s]."""
        start = Start("direct", first_mesh(scene), guess, used, T, self.robot, may_stall=True)
        return planned(scene, start, budget, self.progress)

    def motion(self, scene: Scene, budget: Budget) -> Plan:
        """The plan of a fixed-duration scene from the continuation start where it applies
        (an underactuated arm, whose fast motions the direct start often fails to find),
        else from the scene's own start."""
        T = duration_guess(scene)
        if continuation.applies(scene):
            return planned(scene, continuation_start(scene, self.robot, T), budget,
                           self.progress)
        guess, used = scene_guess(scene, self.robot, T)
        return self.solve(scene, guess, used, T, budget)
