"""Replanning from a measured state: the rest of a plan's motion, solved again from where
the arm is.

A `Replanner` keeps one NLP (the scene's transcription on N uniform intervals, built once:
the intervals' widths and the duration are parameters) and its last solution. Each
`update(t, q, dq)` plans the motion from the measured state at time t [s] along the plan to
the scene's goal at the plan's end time T (a shrinking horizon): N uniform intervals on
[t, T], started from the last motion evaluated at the new knots.

"real-time" runs a fixed few Ipopt iterations from that point and the last solution's
multipliers (a stage moves by a fraction of its width between updates, so the same stage's
multipliers fit), with Ipopt's warm-start settings (a small barrier parameter); where they
end beyond ACCEPTED_VIOLATION (after a push, say: from a small barrier parameter, Ipopt
may need hundreds of iterations or fail), the update escalates to the converged solve.
"converged" starts from the primal point alone, with Ipopt's own barrier parameter, and
runs to the solver's tolerance: after a push on a passive joint it converges in a few
iterations where the warm settings can wander or fail.

Each update says what it checked. Always, at the returned point: the NLP's rows (the
collocation defects and the dynamics at the knots, the continuity between intervals, the
torque limit and the bounds on the delivered polynomials, the coupling margin at the
knots) and bounds, their largest violation against `solver.tol` (cheap: the solver
returns them). With `verify`, the plan's interval check too: every interval re-integrated
from the plan's state with the torque it delivers, within `solver.resimulation_tolerance`.
An update whose solve ends beyond ACCEPTED_VIOLATION (a rest too short for the goal, say)
replaces nothing: the last plan's remainder stands, and the update says so; its point and
multipliers still start the next update, so that iterations cut short by the time limit
are not lost (real-time iterations go on converging while the arm moves).

Each accepted update carries the LQR feedback along its motion (`planner.ocp.feedback`:
the same weights as a plan's), and `Replan.command(t, x)` is its torque with the
correction for the state x: a servo loop applies it between updates, and after a fallback
it holds the arm to the last plan. In the final stretch of the motion (its last
`final_stretch` seconds) no update solves: the rest is too short to re-route an arm in
a few iterations, and the last plan with its feedback finishes the motion.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import ValidationError

from planner.errors import InputError
from planner.ocp.accuracy import interval_errors
from planner.ocp.feedback import gains, linearise, torque_scale
from planner.ocp.guess import Guess, interpolant_guess, plan_interpolant
from planner.ocp.instance import Instance, initial_point, instance
from planner.ocp.mesh import Mesh
from planner.ocp.outcome import interpolant
from planner.ocp.replays import planned_state
from planner.ocp.result import Plan
from planner.ocp.solve import Budget, Solution, solve
from planner.ocp.transcription import Interpolant
from planner.scene import DurationRange, Scene, State
from planner.schema import JointState

Mode = Literal["real-time", "converged"]
REALTIME_ITERATIONS = 3
"""Ipopt iterations of a real-time update (from the last solution, primal and dual)."""
ACCEPTED_VIOLATION = 1e-4
"""The largest violation of the NLP's rows and bounds (in their units: rad, rad/s, N m)
at which an update's plan replaces the last one."""
ROWS_CHECKED = ("the NLP's rows and bounds at the returned point: the dynamics at the knots, "
                "continuity, the torque limit and bounds on the delivered polynomials, the "
                "coupling margin at the knots")
SHORTEST_REST = 1e-3
"""[s] the shortest rest of the motion an update may be asked for."""
FINAL_STRETCH = 0.05
"""The final stretch, as a fraction of the plan's duration, by default."""
HELD = "Final_Stretch"
"""The status of an update in the final stretch (no solve: the last plan stands)."""

Motion = Callable[[np.ndarray], dict[str, np.ndarray]]
"""Absolute times [s] (K,) -> q, dq, ddq (K, n) and tau (K, na) of a motion."""


@dataclass(frozen=True)
class Replan:
    """One update: the plan of the motion from `start` to `end` [s] (times along the
    original plan).

    interp: its states and delivered torque, in time since `start` [s]; status, success,
    iterations: the solve's (a real-time update ends "Maximum_Iterations_Exceeded" by
    design; `violation` says how far from the constraints it stopped; HELD in the final
    stretch, with no solve); violation: the largest violation of the NLP's rows and bounds
    at the returned point [their units] (None when held);
    checked: what was checked, in words; interval_error: the largest interval error [rad]
    when verified (None otherwise); within: every check passed; escalated: the real-time
    iterations ended beyond ACCEPTED_VIOLATION and a converged solve followed; fallback: no
    solve ended within ACCEPTED_VIOLATION and the last plan's remainder stands (interp is
    None then: keep the last update's); gains: the LQR gains K_k (N, na, 2n) [N m/rad,
    N m s/rad] on the intervals of interp (None without feedback); wall, cpu: the update's
    time [s]."""

    start: float
    end: float
    interp: Interpolant | None
    status: str
    success: bool
    iterations: int
    violation: float | None
    checked: tuple[str, ...]
    interval_error: float | None
    within: bool
    escalated: bool
    fallback: bool
    gains: np.ndarray | None
    wall: float
    cpu: float

    @classmethod
    def of_plan(cls, plan: Plan) -> Replan:
        """The plan itself as the update at time 0 (its LQR gains when it has them): what
        a controller follows before its first update."""
        K = None if plan.feedback is None else np.asarray(plan.feedback.gains)
        return cls(0.0, float(plan.duration), plan_interpolant(plan), plan.solver.status,
                   plan.solver.success, 0, None, (), None, plan.status == "verified", False,
                   False, K, 0.0, 0.0)

    def torque(self, t: np.ndarray) -> np.ndarray:
        """The delivered torque [N m] at times t [s] along the original plan, (K, na)."""
        return self._interp().tau(self._rest(t))

    def command(self, t: float, x: np.ndarray) -> np.ndarray:
        """The torque [N m] (na,) for the measured state x = (q, dq) (2n,) at time t [s]
        along the original plan: the delivered torque less K_k (x - x_plan(t)) on the
        interval k of the torque holding t (the torque alone without gains)."""
        interp, rest = self._interp(), self._rest(np.array([t]))
        tau = interp.tau(rest)[0]
        if self.gains is None:
            return tau
        breaks = interp.tau.breaks
        k = int(np.clip(np.searchsorted(breaks, rest[0], side="right") - 1, 0,
                        len(breaks) - 2))
        return tau - self.gains[k] @ (np.asarray(x, float) - planned_state(interp, rest[0]))

    def _interp(self) -> Interpolant:
        if self.interp is None:
            raise ValueError("a fallback update carries no plan: use the last update's")
        return self.interp

    def _rest(self, t: np.ndarray) -> np.ndarray:
        """Times t [s] along the original plan as times since `start`, within the plan."""
        return np.clip(np.asarray(t, float) - self.start, 0.0, self.end - self.start)


class Replanner:
    """Shrinking-horizon replanning of a scene's plan from measured states (the module's
    docstring). scene: the plan's scene (no tracked passive motion, no co-designed waves;
    a range of durations ends at the plan's own); earlier: its plan; intervals: N of every
    replan (default: the scene's); final_stretch: the last seconds of the motion, in which
    updates hold the last plan (default: FINAL_STRETCH of the plan's duration)."""

    def __init__(self, scene: Scene, earlier: Plan, intervals: int | None = None,
                 final_stretch: float | None = None):
        task = scene.task
        if task.tracking is not None or task.co_design is not None:
            raise InputError("task: replanning keeps neither a tracked passive motion nor "
                             "co-designed waves; plan those again")
        self.end = float(earlier.duration)
        if isinstance(task.duration, DurationRange):  # the time the plan chose is its end
            scene = scene.model_copy(update={"task": task.model_copy(
                update={"duration": self.end})})
        self.scene = scene
        self.final_stretch = (FINAL_STRETCH * self.end if final_stretch is None
                              else float(final_stretch))
        if not (math.isfinite(self.final_stretch) and 0.0 <= self.final_stretch < self.end):
            raise InputError(f"final_stretch: must lie in [0, {self.end:g}) s, within the "
                             f"plan's duration")
        self.intervals = intervals or scene.transcription.intervals
        self.robot = scene.robot
        self.goal: State = task.final
        self.motion: Motion = _of_interp(plan_interpolant(earlier), 0.0)
        solution = earlier.solution
        self.multipliers: tuple[np.ndarray, np.ndarray] | None = None
        if solution is not None and len(solution.breaks) == self.intervals + 1:
            self.multipliers = (np.asarray(solution.lam_x), np.asarray(solution.lam_g))

    def update(self, t: float, q: list[float], dq: list[float], *,
               mode: Mode = "real-time", iterations: int = REALTIME_ITERATIONS,
               goal: State | None = None, verify: bool = False, feedback: bool = True,
               wall_time: float | None = None) -> Replan:
        """The plan from the measured state (q [rad], dq [rad/s], one entry per joint) at
        time t [s] along the plan to its goal at its end (`goal`: a moved one, from then
        on). Raises InputError for a state of the wrong size, not finite or beyond the
        task's bounds, a goal of the wrong size, or a time outside the plan. feedback: the
        LQR gains along an accepted update's motion (`Replan.gains`). wall_time [s]:
        the most each of its solves may take (default: the scene's `solver.max_wall_time`);
        a controller gives its period's share, so that an update that cannot be made
        falls back in time."""
        started, cpu = time.perf_counter(), time.process_time()
        state = self._state(t, q, dq)
        if goal is not None:
            self.goal = self._goal(goal)
        if self.end - t <= self.final_stretch:
            return self._held(t, (started, cpu))
        rest = self._rest_scene(t, state)
        inst = instance(rest, self.robot, Mesh.uniform(self.intervals), self.end - t)
        x0 = initial_point(inst, self._guess(t), self.end - t, self.robot)
        wall = rest.solver.max_wall_time if wall_time is None else wall_time
        solution, violation, escalated = self._solve(inst, x0, mode, iterations, wall,
                                                     rest.solver.max_iter)
        interp = (interpolant(inst, self.robot, self.end - t, solution.x)
                  if math.isfinite(violation) else None)
        if interp is not None:
            self._carry(t, interp, solution)
        if interp is None or violation > ACCEPTED_VIOLATION:
            return self._fallback(t, solution, violation, escalated, (started, cpu))
        checked = [ROWS_CHECKED]
        within = violation <= rest.solver.tol
        error = None
        if verify:
            errors, _ = interval_errors(self.robot, interp, rest.solver.jit)
            error = float(errors.max())
            checked.append("every interval re-integrated from the plan's state with its "
                           "delivered torque")
            within = within and error <= rest.solver.resimulation_tolerance
        K = self._gains(interp, rest) if feedback else None
        return Replan(t, self.end, interp, solution.status, solution.success,
                      solution.iterations, violation, tuple(checked), error, bool(within),
                      escalated, False, K, time.perf_counter() - started,
                      time.process_time() - cpu)

    def _solve(self, inst: Instance, x0: np.ndarray, mode: Mode, iterations: int,
               wall: float, max_iter: int) -> tuple[Solution, float, bool]:
        """An update's solve (the module's docstring): the solution, its violation, and
        whether real-time iterations escalated to a converged solve."""
        if mode == "real-time":
            solution = solve(inst, x0, Budget.of(iterations, wall), None, 0,
                             self._multipliers(inst))
            violation = _violation(inst, solution)
            if violation <= ACCEPTED_VIOLATION:
                return solution, violation, False
        solution = solve(inst, x0, Budget.of(max_iter, wall), None, 0)
        return solution, _violation(inst, solution), mode == "real-time"

    def _gains(self, interp: Interpolant, rest: Scene) -> np.ndarray | None:
        """The LQR gains (N, na, 2n) along an update's motion (None where its
        linearisation or Riccati recursion is not finite)."""
        lin = linearise(self.robot, interp, rest.solver.jit)
        fb = None if lin is None else gains(lin, np.diff(interp.q.breaks),
                                            torque_scale(interp, rest.task.torque_limit))
        return None if fb is None else np.asarray(fb.gains)

    def _carry(self, t: float, interp: Interpolant, solution: Solution) -> None:
        """A solve's motion and multipliers as the next update's start, accepted or not:
        an update that could not be made still leaves its iterations' progress to the
        next one, as real-time iterations do."""
        self.motion = _of_interp(interp, t)
        if solution.lam_x is not None and solution.lam_g is not None:
            self.multipliers = (solution.lam_x, solution.lam_g)

    def _state(self, t: float, q: list[float], dq: list[float]) -> JointState:
        """The measured state, refused where it is not one of this arm within the task."""
        n = len(self.robot.links)
        if not (math.isfinite(t) and 0.0 <= t <= self.end - SHORTEST_REST):
            raise InputError(f"t: must lie in [0, {self.end - SHORTEST_REST:g}] s, the plan's "
                             f"time before its end")
        for name, values in (("q", q), ("dq", dq)):
            if len(values) != n:
                raise InputError(f"{name}: needs {n} entries, one per joint")
            if not all(math.isfinite(v) for v in values):
                raise InputError(f"{name}: every entry must be finite")
        bounds = {"q": self.scene.task.position_bounds, "dq": self.scene.task.velocity_bounds}
        for name, values in (("q", q), ("dq", dq)):
            b = bounds[name]
            if b is None:
                continue
            for j, v in enumerate(values):
                lo, hi = b.lower[j], b.upper[j]
                if lo is not None and v < lo or hi is not None and v > hi:
                    raise InputError(f"{name}.{j}: {v:g} lies beyond the task's bounds")
        try:
            return JointState(q=list(q), dq=list(dq))
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(part) for part in first["loc"])
            raise InputError(f"{where}: {first['msg'].lower()}") from None

    def _goal(self, goal: State) -> State:
        """A moved goal, refused where it is not one of this arm."""
        n = len(self.robot.links)
        for name in ("q", "dq"):
            values = getattr(goal, name)
            if len(values) != n:
                raise InputError(f"goal.{name}: needs {n} entries, one per joint")
            if not all(v is None or math.isfinite(v) for v in values):
                raise InputError(f"goal.{name}: every entry must be finite")
        return goal

    def _rest_scene(self, t: float, state: JointState) -> Scene:
        """The scene of the rest of the motion: from the state, for the time left, on N
        uniform intervals, one solve."""
        s = self.scene
        task = s.task.model_copy(update={"initial": state, "final": self.goal,
                                         "duration": self.end - t})
        tr = s.transcription.model_copy(update={
            "intervals": self.intervals, "breaks": None,
            "refinement": s.transcription.refinement.model_copy(update={"enabled": False})})
        return s.model_copy(update={"task": task, "transcription": tr})

    def _guess(self, t: float) -> Guess:
        """The last motion from t to the end, as a guess over fractions of the rest."""
        rest, motion = self.end - t, self.motion
        return lambda x: motion(t + np.asarray(x, float) * rest)

    def _multipliers(self, inst: Instance) -> tuple[np.ndarray, np.ndarray] | None:
        """The last solution's multipliers where they fit this NLP (the same layout)."""
        m = self.multipliers
        if m is None or m[0].size != inst.lbx.size or m[1].size != inst.problem.lbg.size:
            return None
        return m

    def _fallback(self, t: float, solution: Solution, violation: float, escalated: bool,
                  timing: tuple[float, float]) -> Replan:
        """The update that could not be made: the last plan's remainder stands."""
        return Replan(t, self.end, None, solution.status, False, solution.iterations,
                      violation, (ROWS_CHECKED, f"not accepted ({solution.status}, violation "
                      f"{violation:.3g} above {ACCEPTED_VIOLATION:g}): the last plan's "
                      f"remainder stands"), None, False, escalated, True, None,
                      time.perf_counter() - timing[0], time.process_time() - timing[1])

    def _held(self, t: float, timing: tuple[float, float]) -> Replan:
        """An update in the final stretch: no solve, the last plan stands."""
        return Replan(t, self.end, None, HELD, False, 0, None,
                      (f"nothing: in the final {self.final_stretch:.3g} s the last plan and "
                       f"its feedback finish the motion",), None, False, False, True, None,
                      time.perf_counter() - timing[0], time.process_time() - timing[1])


def _of_interp(interp: Interpolant, start: float) -> Motion:
    """A motion given by its interpolant in time since `start` [s] (a plan's: 0), at
    absolute times."""
    guess = interpolant_guess(interp, 1.0)
    return lambda t: guess(np.asarray(t, float) - start)


def _violation(inst: Instance, solution: Solution) -> float:
    """The largest violation of the NLP's rows and of its variables' bounds at a solve's
    point (inf where the point or its rows are not finite)."""
    x, g = solution.x, solution.g
    if not np.all(np.isfinite(x)) or g is not None and not np.all(np.isfinite(g)):
        return math.inf
    lbg, ubg = inst.problem.lbg, inst.problem.ubg
    rows = 0.0 if g is None or g.size == 0 else float(
        np.max(np.maximum(lbg - g, 0.0) + np.maximum(g - ubg, 0.0)))
    bounds = float(np.max(np.maximum(inst.lbx - x, 0.0) + np.maximum(x - inst.ubx, 0.0)))
    return max(rows, bounds)
