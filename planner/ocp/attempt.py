"""An attempt: where it starts (`Start`) and its solves in order (`Attempt`): preliminary
solves that prepare a guess (a coarse mesh, the relaxed NLPs of the continuation), the
first solve on its own mesh, and the refinements of that mesh while the plan is not
accurate (`planner.ocp.refine`)."""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, replace

import numpy as np

from planner.model import Robot
from planner.ocp import continuation, shortest
from planner.ocp.carried import Point, carried
from planner.ocp.guess import Guess, interpolant_guess
from planner.ocp.instance import Instance, initial_point, instance
from planner.ocp.margin_reserve import next_reserve, reserved_margin, with_margin
from planner.ocp.mesh import Mesh
from planner.ocp.monitor import Handler
from planner.ocp.outcome import Outcome, relaxed_solve, solve_on
from planner.ocp.refine import refined
from planner.ocp.result import NlpSolution
from planner.ocp.solve import Budget
from planner.ocp.solvers import SOLVERS
from planner.scene import Scene


@dataclass(frozen=True)
class Start:
    """Where an attempt starts: its name (the plan's `solver.strategy`), the mesh of its
    first solve, the initial guess with what it was, and the duration [s] and robot (the
    co-designed waves) it starts from."""

    name: str
    mesh: Mesh
    guess: Guess
    guess_used: str
    T: float
    robot: Robot
    point: NlpSolution | None = None
    """An earlier solution of the same problem on the same mesh: the start, primal and dual."""
    coarse: Mesh | None = None
    """A coarser mesh solved first, whose plan (if it converged) starts the solve on `mesh`."""
    relaxed: bool = False
    """Start from the continuation of relaxed NLPs (`planner.ocp.continuation`) on `mesh`."""
    may_stall: bool = False
    """Stop its first solves when they stall (`planner.ocp.monitor`): the scene's own start,
    which the other starts are there to rescue."""
    time_share: float = 1.0
    """The most of the plan's wall time its first solves may take (the scene's own start
    of a task whose duration the probe may show too short: `shortest.FIRST_SHARE`)."""
    max_iter: int | None = None
    """The most iterations each of its first solves may take (None: the plan's own limit);
    its refinements, from its converged plan, are not capped."""
    max_refinements: int | None = None
    """The most mesh refinements of its plan (None: the scene's `refinement.max_passes`):
    a start that is there to be quick (an earlier plan's, an example's) gives way to the
    next when its plan is not accurate soon."""
    continues: bool = False
    """It goes on from where an earlier attempt stopped (its last iterate), so its verdict
    is no independent witness of that attempt's."""
    limits_later: bool = False
    """Solve the task without its torque limit and velocity bounds first, from the guess,
    and start the task's own solve from that plan (`unlimited_solve`)."""


@dataclass
class Attempt:
    """The solves of one start, in order (`passes`): those that prepare a guess (on a
    coarse mesh, or of the relaxed NLPs) and those on its mesh and the refinements of that
    (`outcomes`, the plans it offers)."""

    start: Start
    passes: list[Outcome]
    outcomes: list[Outcome]

    def add(self, outcome: Outcome) -> None:
        """Record a solve of a plan the attempt may return."""
        self.passes.append(outcome)
        self.outcomes.append(outcome)


def attempt(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
            first_pass: int) -> Attempt:
    """The solves of one start: its first solves (`first_solves`), then its refinements
    (`refine`); `first_pass`: the plan's solves before it."""
    preliminary, first = first_solves(scene, start, budget, progress, first_pass)
    made = Attempt(start, [*preliminary, first], [first])
    refine(scene, made, budget, progress, first_pass)
    return made


def first_solves(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
                 first_pass: int) -> tuple[list[Outcome], Outcome]:
    """An attempt's preliminary solves (on its coarse mesh, or of the relaxed NLPs), and
    its first solve on its own mesh: from the preliminary plan where that converged, else
    from the start's guess; together within the start's share of the wall time."""
    capped = contextlib.nullcontext() if start.max_iter is None else budget.capped(start.max_iter)
    with budget.capped_time(start.time_share), capped:
        return _first_solves_within(scene, start, budget, progress, first_pass)


def _first_solves_within(scene: Scene, start: Start, budget: Budget,
                         progress: Handler | None,
                         first_pass: int) -> tuple[list[Outcome], Outcome]:
    guess, robot, T = start.guess, start.robot, start.T
    preliminary: list[Outcome] = []
    if start.limits_later:
        free = unlimited_solve(scene, start, budget, progress, first_pass)
        preliminary.append(free)
        if free.solution.success:
            guess = interpolant_guess(free.interp, free.T)
    if start.coarse is not None:
        coarse = solve_on(scene, instance(scene, robot, start.coarse, T), robot, T, guess,
                          budget, progress, first_pass + len(preliminary), start.name,
                          stall=start.may_stall)
        if budget.spent:  # no time left for its own mesh: the coarse plan is the attempt's
            return preliminary, coarse
        preliminary.append(coarse)
        if coarse.solution.success:
            guess, robot, T = interpolant_guess(coarse.interp, coarse.T), coarse.robot, coarse.T
    if start.relaxed:
        preliminary = continuation_solves(scene, start, budget, progress, first_pass)
        last = preliminary[-1]
        if last.finite:
            guess = continuation.active_guess(last.interp, last.T, len(robot.active))
            robot, T = last.robot, last.T
    first = solve_on(scene, instance(scene, robot, start.mesh, T), robot, T, guess, budget,
                     progress, first_pass + len(preliminary), start.name, start.point,
                     start.may_stall)
    return preliminary, first


UNLIMITED_COARSENING = 2
"""The unlimited solve, a guess for the task's own, is made on this many times fewer
uniform intervals than the start's first mesh (at least UNLIMITED_INTERVALS, or the first
mesh's own number where that is fewer): on the default suite's median plans, torque-limited
four-link tasks, it took a fifth less time to the same verified plans (docs/planner.md,
"Limits later")."""
UNLIMITED_INTERVALS = 10


def unlimited_solve(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
                    first_pass: int) -> Outcome:
    """The task without its torque limit and velocity bounds (`shortest.unlimited`) at the
    start's duration, on a uniform mesh UNLIMITED_COARSENING times coarser than its first
    one, from its guess: a solve from an interpolated guess under limits can wander along
    the bounds for hundreds of iterations (the two-link example under a limit above its
    own peak torque ended Infeasible_Problem_Detected), while the unlimited optimum
    converges in tens and often keeps the limits."""
    free = shortest.unlimited(scene, start.T)
    first = start.coarse if start.coarse is not None else start.mesh
    mesh = Mesh.uniform(max(first.intervals // UNLIMITED_COARSENING,
                            min(first.intervals, UNLIMITED_INTERVALS)))
    return solve_on(free, instance(free, start.robot, mesh, start.T), start.robot, start.T,
                    start.guess, budget, progress, first_pass,
                    f"{start.name}: the task without its limits", stall=start.may_stall)


def continuation_solves(scene: Scene, start: Start, budget: Budget,
                        progress: Handler | None, first_pass: int) -> list[Outcome]:
    """The relaxed NLPs' solves, each weight of `continuation.VIRTUAL_WEIGHTS` in turn from
    the solution before, until the virtual torques are negligible, a solve fails or the
    budget is spent (at least one solve)."""
    na = len(start.robot.active)
    outcomes: list[Outcome] = []
    for weight in continuation.VIRTUAL_WEIGHTS:
        before = outcomes[-1].solution if outcomes else None
        point = None if before is None else (before.x, before.lam_x, before.lam_g)
        inst = instance(scene, start.robot, start.mesh, start.T, weight)
        outcome = relaxed_solve(scene, inst, start.robot, start.T, start.name, start.guess,
                                point, budget, progress, first_pass + len(outcomes), weight)
        outcomes.append(outcome)
        if not (outcome.finite and outcome.solution.success) or budget.spent:
            break
        if continuation.virtual_peak(outcome.interp, na) < continuation.NEGLIGIBLE:
            break
    return outcomes


def refine(scene: Scene, made: Attempt, budget: Budget, progress: Handler | None,
           first_pass: int) -> None:
    """Refine the mesh of the attempt's last outcome while it converged but is not
    accurate, and stop at an artefact of the mesh (`artefact`): the next start follows.
    An accurate plan whose coupling margin dips between its knots is solved again on its
    mesh with a reserve above the margin where the task leaves room for one
    (`planner.ocp.margin_reserve`), else its mesh is cut there.
    `first_pass`: the plan's solves before the attempt's."""
    refinement, tolerance = scene.transcription.refinement, scene.solver.resimulation_tolerance
    passes = refinement.max_passes if made.start.max_refinements is None \
        else min(refinement.max_passes, made.start.max_refinements)
    outcomes, reserve, held = made.outcomes, 0.0, None
    while refinement.enabled and len(outcomes) <= passes and not budget.spent:
        last = outcomes[-1]
        if len(outcomes) > 1 and artefact(outcomes[-2], last) \
                or not last.solution.success or last.accurate(tolerance):
            return
        unproven = _unproven(last, tolerance)
        more = None if unproven is None or last.margin is None \
            else next_reserve(last.margin, reserve)
        margin = None if more is None else reserved_margin(scene.task, last.robot, more)
        mesh: Mesh | None
        if more is not None and margin is not None \
                and (held is None or margin > held):  # not what failed before
            reserve, held, mesh = more, margin, last.inst.mesh
        else:
            mesh = refined(last.inst.mesh, last.errors, last.inst.problem.transcription.order,
                           tolerance, refinement.max_intervals, unproven)
        if mesh is None:
            return
        *failed, solved = _refined_solve(scene, last, mesh, held, budget, progress,
                                         first_pass + len(made.passes))
        made.passes.extend(failed)
        made.add(solved)


def _refined_solve(scene: Scene, last: Outcome, mesh: Mesh, held: float | None,
                   budget: Budget, progress: Handler | None, mesh_pass: int) -> list[Outcome]:
    """The solves that follow `last` on `mesh` with its knots held at the margin `held`
    [kg m^2] (None: the task's own), their records saying the reserve: on the same mesh
    from `last`'s solution (primal and dual where it has both); on another from its
    interpolant with its multipliers carried over (`planner.ocp.carried`) and, where that
    solve fails, again from its interpolant alone. The last of them is the one that
    counts."""
    inst = instance(with_margin(scene, held), last.robot, mesh, last.T)
    solution, guess = last.solution, interpolant_guess(last.interp, last.T)
    same = mesh is last.inst.mesh and solution.lam_x is not None and solution.lam_g is not None
    point = solution if same \
        else _carried_start(last, inst, guess, scene.solver.resimulation_tolerance)
    solved = [solve_on(scene, inst, last.robot, last.T, guess, budget, progress, mesh_pass,
                       last.record.strategy, point)]
    if not same and point is not None and not solved[0].solution.success \
            and not budget.spent:
        solved.append(solve_on(scene, inst, last.robot, last.T, guess, budget, progress,
                               mesh_pass + 1, last.record.strategy))
    task_margin = scene.task.coupling_margin
    if held is None or task_margin is None:
        return solved
    update = {"margin_reserve": held / task_margin - 1.0}
    return [replace(o, record=o.record.model_copy(update=update)) for o in solved]


CARRY_WITHIN = 10.0
"""A refined solve starts from the multipliers of the plan before only where that plan's
interval errors are at most this many times the tolerance: a plan further off may sit at
an optimum of its coarser mesh alone, which a warm start would not leave (the two-link
example on 30 intervals, tests/test_refinement.py), while a cold start from its
interpolant finds the refined mesh's own."""


def _carried_start(last: Outcome, inst: Instance, guess: Guess,
                   tolerance: float) -> Point | None:
    """The start of a solve on a refinement of `last`'s mesh: `last`'s plan interpolated,
    with its multipliers carried over; None where its interval errors exceed CARRY_WITHIN
    times the `tolerance` [rad], the multipliers cannot be carried, or the solver takes
    none."""
    if SOLVERS[inst.problem.key.solver].warm_options is None \
            or not last.worst_error() <= CARRY_WITHIN * tolerance:
        return None
    x0 = initial_point(inst, guess, last.T, last.robot)
    return carried(last.inst, last.solution, inst, x0)


def _unproven(last: Outcome, tolerance: float) -> np.ndarray | None:
    """The intervals to halve for the coupling margin (None: none): those it is not proven
    on, once every interval is accurate; until then the errors decide the cuts alone (a
    mesh that follows an inaccurate plan's margin dips leads elsewhere)."""
    if last.margin is None or np.any(last.errors > tolerance):
        return None
    return last.margin.unproven()


ARTEFACT_GROWTH = 2.0
"""A refined plan whose objective exceeds its predecessor's by this factor, no more
accurate than half its error, left an optimum that the coarser mesh made up."""


def artefact(before: Outcome, after: Outcome) -> bool:
    """Whether refining `before` into `after` moved away from a mesh artefact: a refined
    solve stays at a true optimum (a pass after the first changes the objective by the
    discretisation error), while at an artefact the objective grows pass after pass."""
    f0, f1 = before.solution.objective, after.solution.objective
    if not (before.solution.success and math.isfinite(f0) and math.isfinite(f1)) or f0 <= 0:
        return False
    error0, error1 = float(before.errors.max()), float(after.errors.max())
    return f1 > ARTEFACT_GROWTH * f0 and not error1 < error0 / 2
