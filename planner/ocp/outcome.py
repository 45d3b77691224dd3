"""One solve on one mesh and what it gives (`Outcome`): the solved robot, the duration, the
interpolant and its interval errors, each solve's record among the plan's mesh passes."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from planner.dynamics import Dynamics
from planner.model import Robot
from planner.ocp.accuracy import interval_errors
from planner.ocp.carried import Point
from planner.ocp.codesign import solved_robot
from planner.ocp.guess import Guess
from planner.ocp.instance import Instance, initial_point
from planner.ocp.margin_proof import MarginProof, prove
from planner.ocp.monitor import Handler
from planner.ocp.result import MeshPass, NlpSolution
from planner.ocp.solve import Budget, Solution, solve
from planner.ocp.transcription import Interpolant
from planner.scene import DurationRange, Scene

NOT_FINITE = "not run: non-finite solution"


@dataclass(frozen=True)
class Outcome:
    """A solve on one mesh and what it gives: the solved robot (co-designed waves), the
    duration T [s], the interpolant, and its interval errors [rad] (inf where unknown)."""

    inst: Instance
    solution: Solution
    robot: Robot
    T: float
    interp: Interpolant
    finite: bool
    errors: np.ndarray
    errors_status: str
    record: MeshPass
    margin: MarginProof | None = None
    """The coupling margin proven interval by interval (None without one, or not made)."""

    def accurate(self, tolerance: float) -> bool:
        """Every interval error at most `tolerance` [rad], and the coupling margin proven on
        every interval where the task has one."""
        proven = self.margin is None or not self.margin.unproven().any()
        return self.finite and bool(np.all(self.errors <= tolerance)) and proven

    def worst_error(self) -> float:
        """The largest interval error [rad] (inf where unknown)."""
        worst = float(self.errors.max()) if self.errors.size else math.inf
        return worst if math.isfinite(worst) else math.inf


def solve_on(scene: Scene, inst: Instance, robot: Robot, T: float, guess: Guess,
             budget: Budget, progress: Handler | None, mesh_pass: int,
             strategy: str, point: NlpSolution | Solution | Point | None = None,
             stall: bool = False) -> Outcome:
    """Solve on the instance's mesh from a guess (or from an earlier solution, primal and
    dual; stall: a cold solve is stopped when it stalls), and estimate the plan's interval
    errors (its open-loop replay is one of the final checks, `planner.ocp.verify`)."""
    started = time.perf_counter()
    if point is None:
        solution = solve(inst, initial_point(inst, guess, T, robot), budget, progress,
                         mesh_pass, stall=stall)
    else:
        solution = solve(inst, np.asarray(point.x), budget, progress, mesh_pass,
                         (np.asarray(point.lam_x), np.asarray(point.lam_g)))
    outcome = outcome_of(scene, inst, robot, T, solution, strategy, started)
    if not outcome.finite:
        return outcome
    checked = time.perf_counter()
    errors, status = interval_errors(outcome.robot, outcome.interp, scene.solver.jit,
                                     budget.deadline)
    margin = prove(outcome.robot, outcome.interp, scene.task.coupling_margin, budget.deadline)
    budget.measured = time.perf_counter() - checked  # what the final checks will scale with
    record = outcome.record.model_copy(update={
        "max_local_error": finite_or_none(float(errors.max())),
        "time": time.perf_counter() - started})
    return replace(outcome, errors=errors, errors_status=status, record=record, margin=margin)


def relaxed_solve(scene: Scene, inst: Instance, robot: Robot, T: float, name: str,
                  guess: Guess,
                  point: tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None,
                  budget: Budget, progress: Handler | None, mesh_pass: int,
                  weight: float) -> Outcome:
    """One solve of the relaxed NLP: from the guess, or from the previous relaxed solve's
    solution (primal and, where it has them, dual). Its plan needs virtual torques, so it
    is no motion of the robot: its interval errors are not computed (inf)."""
    started = time.perf_counter()
    x, lam_x, lam_g = point if point is not None else (None, None, None)
    if x is None:
        x = initial_point(inst, guess, T, robot)
    multipliers = (lam_x, lam_g) if lam_x is not None and lam_g is not None else None
    solution = solve(inst, x, budget, progress, mesh_pass, multipliers)
    return outcome_of(scene, inst, robot, T, solution,
                      f"{name}: relaxed, virtual weight {weight:g}", started)


def outcome_of(scene: Scene, inst: Instance, robot: Robot, T: float, solution: Solution,
               strategy: str, started: float) -> Outcome:
    """What a solve gives (solved robot, duration, interpolant), its errors not yet
    estimated (inf)."""
    finite = bool(np.all(np.isfinite(solution.x)))
    solved = solved_robot(inst, robot, solution.x) if finite else robot
    duration = _duration(scene, inst, solution.x) if finite else T
    interp = interpolant(inst, solved, duration, solution.x)
    errors = np.full(inst.mesh.intervals, np.inf)
    status = NOT_FINITE if not finite else "not estimated: a preliminary solve"
    record = MeshPass(strategy=strategy, intervals=inst.mesh.intervals,
                      iterations=solution.iterations,
                      status=solution.status, objective=finite_or_none(solution.objective),
                      max_local_error=None, resimulation_error=None,
                      time=time.perf_counter() - started)
    return Outcome(inst, solution, solved, duration, interp, finite, errors, status, record)


def _duration(scene: Scene, inst: Instance, x: np.ndarray) -> float:
    """The duration [s]: the solution's own where it is free (a duration range)."""
    duration = scene.task.duration
    if isinstance(duration, DurationRange):  # the key's free_time
        return float(inst.problem.layout.view(x, "T")[0, 0])
    return float(duration)


def interpolant(inst: Instance, robot: Robot, T: float, x: np.ndarray) -> Interpolant:
    """The solution's states and torques between its knots, on the mesh in seconds."""
    lay = inst.problem.layout
    blocks = {name: lay.view(x, name) for name, (kind, _) in lay.blocks.items()
              if kind != "global"}
    dynamics = Dynamics(robot)
    return inst.problem.transcription.interpolant(blocks, inst.mesh.breaks * T,
                                                  dynamics.forward_many)


def finite_or_none(value: float) -> float | None:
    """The value, None where it is not finite."""
    return value if math.isfinite(value) else None
