"""plan(): solve a scene's NLP, refine its mesh until the plan is accurate, verify it.

The first solve runs on the scene's uniform mesh from the initial guess. While the plan
is not accurate (an interval re-integrated from the plan's own state departs from it by
more than `solver.resimulation_tolerance`, see `planner.ocp.accuracy`) and the budget
allows, the mesh is refined where the error is (`planner.ocp.refine`) and the NLP solved
again from the previous plan interpolated onto the new mesh, so that the refined solve
stays at the same local optimum.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from planner import feasibility
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import Robot, Wave
from planner.ocp import continuation, cores, infeasibility, portfolio, shortest
from planner.ocp.accuracy import interval_errors
from planner.ocp.feedback import REPLAY_SAMPLES
from planner.ocp.guess import (
    Guess,
    hermite_guess,
    interpolant_guess,
    inverse_dynamics_guess,
    plan_guess,
    stretched,
)
from planner.ocp.instance import Instance, initial_point, instance
from planner.ocp.mesh import Mesh
from planner.ocp.monitor import Handler
from planner.ocp.problem import ProblemKey
from planner.ocp.refine import refined
from planner.ocp.result import (
    DenseTrajectory,
    MeshPass,
    NlpSolution,
    Plan,
    Progress,
    SolverReport,
    StatePolynomials,
    Verification,
    WaveOut,
)
from planner.ocp.solve import Budget, Solution, solve
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import open_loop, verify
from planner.scene import DurationRange, Scene
from planner.torque import TorquePolynomial

COARSE_INTERVALS = 50  # a uniform mesh finer than this is first solved on this many intervals
DENSE_POINTS = 2000  # about this many dense samples per plan, at least REPLAY_SAMPLES per
# interval and a multiple of them, so that the replays' samples are among the dense ones
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
    replayed: tuple[float | None, str]
    record: MeshPass

    def accurate(self, tolerance: float) -> bool:
        return self.finite and bool(np.all(self.errors <= tolerance))


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


@dataclass
class Attempt:
    """The solves of one start, in order (`passes`): those that prepare a guess (on a
    coarse mesh, or of the relaxed NLPs) and those on its mesh and the refinements of that
    (`outcomes`, the plans it offers)."""

    start: Start
    passes: list[Outcome]
    outcomes: list[Outcome]

    def solves(self) -> list[Outcome]:
        return self.passes

    def add(self, outcome: Outcome) -> None:
        """Record a solve of a plan the attempt may return."""
        self.passes.append(outcome)
        self.outcomes.append(outcome)


def plan(scene: Scene, progress: Handler | None = None, warm_start: Plan | None = None) -> Plan:
    """Plan feed-forward torques for a scene.

    progress is called once per Ipopt iteration; returning False stops the plan.
    warm_start: an earlier plan whose trajectory seeds the initial guess.
    A failed solve is returned (success False, Ipopt's last iterate), never raised.
    With two solver processes (`planner.ocp.portfolio`), the continuation start runs in a
    forked companion beside the other starts, and the first verified plan wins.
    A task known infeasible before a solve returns at once, and one the solver holds
    infeasible says so (`Plan.infeasibility`, `planner.ocp.infeasibility`).
    """
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    issues = feasibility.check(scene)
    if issues:  # known infeasible before any solve
        return infeasibility.refused(scene, issues, budget.started, _duration_guess(scene))
    return _plan(scene, progress, warm_start, budget)


def shortest_duration(scene: Scene, lowest: float | None = None) -> shortest.Probe:
    """The duration probe (`planner.ocp.shortest`) of a scene's task on its own, within the
    scene's whole budget: the unlimited motion, stretched, then a time-optimal solve whose
    duration may go down to `lowest` [s] (default: the task's shortest)."""
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    probe = _DurationProbe(scene, _design_robot(scene), budget, None)
    return shortest.probe(scene, budget, probe.solve, probe.motion, lowest, share=1.0)


def _plan(scene: Scene, progress: Handler | None, warm_start: Plan | None,
          budget: Budget) -> Plan:
    """`plan` of a scene that passed the checks before a solve, within `budget`: with a
    companion where one helps and a core is free for it (`planner.ocp.cores`), else alone."""
    wanted = continuation.applies(scene) and scene.solver.retries > 0 \
        and portfolio.solver_processes() >= 2
    own = cores.take()
    spare = cores.take() if wanted and own is not None else None
    try:
        return _planned_on(scene, progress, warm_start, budget, alone=spare is None)
    finally:
        cores.release(own, spare)


def _planned_on(scene: Scene, progress: Handler | None, warm_start: Plan | None,
                budget: Budget, alone: bool) -> Plan:
    """`_plan` in this process alone, or beside a companion that solves the continuation
    (forked once an earlier plan, if one was given, has failed to start it)."""
    robot, T = _design_robot(scene), _duration_guess(scene)
    attempts: list[Attempt] = []
    with budget.capped(WARM_ITERATIONS):
        _attempt(scene, _warm_starts(scene, robot, T, warm_start, stall=alone), attempts,
                 budget, progress)
    if attempts and _ended(scene, attempts, budget):
        return _result(scene, attempts, budget)
    if alone:
        probe = _DurationProbe(scene, robot, budget, progress)
        starts = itertools.islice(_starts(scene, robot, T, attempts, probe, stall=alone),
                                  1 + scene.solver.retries)
        _attempt(scene, starts, attempts, budget, progress)
        return _result(scene, attempts, budget, probe)
    relaxed = _continuation_start(scene, robot, T)
    companion = portfolio.Companion(
        lambda guard: _planned(scene, relaxed, replace(budget), guard))
    try:
        handler = _Watch(companion, progress)
        probe = _DurationProbe(scene, robot, budget, handler)
        starts = itertools.islice(_starts(scene, robot, T, attempts, probe, stall=alone),
                                  1 + scene.solver.retries)
        _attempt(scene, (s for s in starts if not s.relaxed), attempts, budget, handler)
        if not handler.cancelled and companion.verified() and companion.plan is not None:
            return _joined(companion.plan, _passes_of(attempts), budget)
        own = _result(scene, attempts, budget, probe)
        if handler.cancelled or own.infeasibility is not None \
                or own.solver.success and own.verification.verified:
            return _joined(own, [], budget)
        other = companion.wait(budget.deadline + COMPANION_GRACE)
        return _joined(own if other is None or _better(own, other) else other,
                       [], budget)
    finally:
        companion.stop()


WARM_ITERATIONS = 100
"""Iterations a solve started from an earlier plan may take before the scene's own starts
take over: a warm start near its optimum converges in a few (docs/benchmarks.md, "Memory of
motion": at most 34 where it beat the cold plan but one), while those that failed ran for
half a minute before the cold starts began ("Warm replanning")."""

COMPANION_GRACE = 3.0
"""[s] past the budget the plan waits for its companion's plan (its checks): less than
the plan's MARGIN (`planner.ocp.solve`), which also covers what follows the wait."""


def _attempt(scene: Scene, starts: Iterator[Start], attempts: list[Attempt], budget: Budget,
             progress: Handler | None) -> None:
    """Solve and refine from each start in turn until one gives a settled converged plan
    (accurate, or refinement off), the budget is spent or the plan is stopped."""
    for start in starts:
        preliminary, first = _first_solves(scene, start, budget, progress, _passes(attempts))
        attempt = Attempt(start, [*preliminary, first], [first])
        attempts.append(attempt)
        _refine(scene, attempt, budget, progress, _passes(attempts))
        if _ended(scene, attempts, budget):
            break


def _ended(scene: Scene, attempts: list[Attempt], budget: Budget) -> bool:
    """Whether no further start should be tried: the last attempt gave a settled converged
    plan (accurate, or refinement off), the budget is spent, the plan was stopped, or two
    attempts agree that the task is infeasible."""
    last = attempts[-1].outcomes[-1]
    settled = last.accurate(scene.solver.resimulation_tolerance) \
        or not scene.transcription.refinement.enabled
    return bool(last.solution.success and settled) or budget.spent \
        or last.solution.status == "User_Requested_Stop" or infeasibility.agreed(attempts)


def _planned(scene: Scene, start: Start, budget: Budget, progress: Handler | None) -> Plan:
    """The plan of one start alone (what a companion process runs)."""
    attempts: list[Attempt] = []
    _attempt(scene, iter([start]), attempts, budget, progress)
    return _result(scene, attempts, budget)


class _DurationProbe:
    """The plan's probe of its shortest duration (`planner.ocp.shortest`): run at most
    once, after one of the scene's own attempts has given no converged plan, where the
    task's limits can make its duration too short."""

    def __init__(self, scene: Scene, robot: Robot, budget: Budget, progress: Handler | None):
        self.scene, self.robot, self.budget, self.progress = scene, robot, budget, progress
        self.found: shortest.Probe | None = None
        self.after = 0
        """The plan's solves before the probe's."""

    def run(self, attempts: list[Attempt]) -> None:
        """Probe, unless it ran already, does not apply, an attempt converged or the
        budget is spent."""
        converged = any(o.solution.success for a in attempts for o in a.outcomes)
        if self.found is None and shortest.applies(self.scene) and not converged \
                and not self.budget.spent:
            self.after = _passes(attempts)
            self.found = shortest.probe(self.scene, self.budget, self.solve, self.motion)

    @property
    def too_short(self) -> bool:
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
        start = Start("direct", _first_mesh(scene), guess, used, T, self.robot, may_stall=True)
        return _planned(scene, start, budget, self.progress)

    def motion(self, scene: Scene, budget: Budget) -> Plan:
        """The plan of a fixed-duration scene from the continuation start where it applies
        (an underactuated arm, whose fast motions the direct start often fails to find),
        else from the scene's own start."""
        T = _duration_guess(scene)
        if continuation.applies(scene):
            return _planned(scene, _continuation_start(scene, self.robot, T), budget,
                            self.progress)
        guess, used = _guess(scene, self.robot, T)
        return self.solve(scene, guess, used, T, budget)


class _Watch:
    """The plan's own progress handler beside a companion: it passes reports on, and also
    stops the solve once the companion has a verified plan; `cancelled`: the caller's
    handler stopped it."""

    def __init__(self, companion: portfolio.Companion, progress: Handler | None):
        self.companion, self.progress, self.cancelled = companion, progress, False

    def __call__(self, report: Progress) -> bool:
        if self.progress is not None and self.progress(report) is False:
            self.cancelled = True
            return False
        return not self.companion.verified()


def _better(own: Plan, other: Plan) -> bool:
    """Whether `own` is at least as good as `other`: verified, then converged, then the
    smaller largest interval error."""
    def rank(p: Plan) -> tuple[bool, bool, float]:
        error = p.verification.local_error
        return (not p.verification.verified, not p.solver.success,
                math.inf if error is None else error)

    return rank(own) <= rank(other)


def _passes_of(attempts: list[Attempt]) -> list[MeshPass]:
    return [o.record for a in attempts for o in a.solves()]


def _joined(chosen: Plan, also: list[MeshPass], budget: Budget) -> Plan:
    """The chosen plan, with the solves of the process that lost listed too, and the
    plan's whole wall time."""
    report = chosen.solver.model_copy(update={
        "iterations": chosen.solver.iterations + sum(p.iterations for p in also),
        "total_time": time.perf_counter() - budget.started})
    return chosen.model_copy(update={"solver": report,
                                     "mesh_passes": [*also, *chosen.mesh_passes]})


def _passes(attempts: list[Attempt]) -> int:
    return sum(len(a.solves()) for a in attempts)


def _first_solves(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
                  first_pass: int) -> tuple[list[Outcome], Outcome]:
    """An attempt's preliminary solves (on its coarse mesh, or of the relaxed NLPs), and
    its first solve on its own mesh: from the preliminary plan where that converged, else
    from the start's guess; together within the start's share of the wall time."""
    with budget.capped_time(start.time_share):
        return _first_solves_within(scene, start, budget, progress, first_pass)


def _first_solves_within(scene: Scene, start: Start, budget: Budget,
                         progress: Handler | None,
                         first_pass: int) -> tuple[list[Outcome], Outcome]:
    guess, robot, T, preliminary = start.guess, start.robot, start.T, []
    if start.coarse is not None:
        preliminary = [_solve_on(scene, instance(scene, robot, start.coarse, T), robot, T,
                                 guess, budget, progress, first_pass, start.name,
                                 stall=start.may_stall)]
        if budget.spent:  # no time left for its own mesh: the coarse plan is the attempt's
            return [], preliminary[0]
        if preliminary[0].solution.success:
            guess, robot, T = (interpolant_guess(preliminary[0].interp, preliminary[0].T),
                               preliminary[0].robot, preliminary[0].T)
    if start.relaxed:
        preliminary = _continuation(scene, start, budget, progress, first_pass)
        last = preliminary[-1]
        if last.finite:
            guess = continuation.active_guess(last.interp, last.T, len(robot.active))
            robot, T = last.robot, last.T
    first = _solve_on(scene, instance(scene, robot, start.mesh, T), robot, T, guess, budget,
                      progress, first_pass + len(preliminary), start.name, start.point,
                      start.may_stall)
    return preliminary, first


def _continuation(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
                  first_pass: int) -> list[Outcome]:
    """The relaxed NLPs' solves, each weight of `continuation.VIRTUAL_WEIGHTS` in turn from
    the solution before, until the virtual torques are negligible, a solve fails or the
    budget is spent (at least one solve)."""
    na = len(start.robot.active)
    outcomes: list[Outcome] = []
    for weight in continuation.VIRTUAL_WEIGHTS:
        before = outcomes[-1].solution if outcomes else None
        point = None if before is None else (before.x, before.lam_x, before.lam_g)
        inst = instance(scene, start.robot, start.mesh, start.T, weight)
        outcome = _relaxed_solve(scene, inst, start.robot, start.T, start.name, start.guess,
                                 point, budget, progress, first_pass + len(outcomes), weight)
        outcomes.append(outcome)
        if not (outcome.finite and outcome.solution.success) or budget.spent:
            break
        if continuation.virtual_peak(outcome.interp, na) < continuation.NEGLIGIBLE:
            break
    return outcomes


def _warm_starts(scene: Scene, robot: Robot, T: float, warm_start: Plan | None,
                 stall: bool = True) -> Iterator[Start]:
    """The attempt an earlier plan gives, tried before the scene's own (`_starts`), which
    follow it unchanged when it fails: its NLP solution, primal and dual, where it solved
    the same problem on a mesh at least as fine as the scene's (its refined mesh is kept);
    else its trajectory as the initial guess on the scene's own mesh, stopped when it
    stalls (stall: as the scene's own start)."""
    if warm_start is None:
        return
    guess = _earlier_guess(robot, warm_start)
    earlier, mesh = warm_start.solution, _first_mesh(scene)
    if earlier is not None:
        solved_on = Mesh(np.asarray(earlier.breaks))
        same = ProblemKey.of(scene, solved_on.intervals).fingerprint() == earlier.fingerprint
        if same and solved_on.intervals >= mesh.intervals:
            yield Start("warm start", solved_on, guess, "warm start", warm_start.duration,
                        robot, earlier)
            return
    yield Start("earlier plan as the guess", mesh, guess, "warm start", T, robot,
                may_stall=stall)


def _starts(scene: Scene, robot: Robot, T: float, attempts: list[Attempt],
            probe: _DurationProbe | None = None, stall: bool = True) -> Iterator[Start]:
    """The scene's own attempts, in order, each tried while the ones before it have not
    given a converged plan (with mesh refinement on: an accurate one; docs/planner.md,
    "Retries"): the scene's own start (with refinement on, a uniform mesh of over
    COARSE_INTERVALS intervals solved on that many first); the continuation from relaxed
    dynamics (`planner.ocp.continuation`), where it applies; a restart from the last
    iterate of the scene's start where that neither converged nor stalled;
    the classical inverse dynamics as the initial guess; a first mesh of twice, then of
    half the intervals. After the scene's own start, `probe` (where given) runs: when it
    shows the duration too short no start follows, and a time-optimal plan it found
    within the task's durations is the next start; where the probe applies, the scene's
    own start may take `shortest.FIRST_SHARE` of the wall time before it runs. stall: the
    scene's own start is stopped when it stalls (where no companion process solves the
    continuation meanwhile)."""
    tr = scene.transcription
    mesh = _first_mesh(scene)
    guess, used = _guess(scene, robot, T)
    share = shortest.FIRST_SHARE if probe is not None and shortest.applies(scene) else 1.0
    if tr.refinement.enabled and tr.breaks is None and tr.intervals > COARSE_INTERVALS:
        yield Start("coarse to fine", mesh, guess, used, T, robot,
                    coarse=Mesh.uniform(COARSE_INTERVALS), may_stall=stall, time_share=share)
    else:
        yield Start("direct", mesh, guess, used, T, robot, may_stall=stall, time_share=share)
    if probe is not None:
        probe.run(attempts)
        if probe.too_short:
            return
        fastest = probe.start()
        if fastest is not None:
            yield fastest
    if continuation.applies(scene):
        yield _continuation_start(scene, robot, T)
    last = [a for a in attempts if not a.start.relaxed][-1].outcomes[-1]
    if last.finite and not last.solution.success and last.solution.status != "Stalled":
        yield Start("restart from the last iterate", last.inst.mesh,
                    interpolant_guess(last.interp, last.T), "the last iterate", last.T,
                    last.robot)
    if used != "inverse-dynamics" and _inverse_dynamics_applies(robot):
        with contextlib.suppress(ValueError):
            yield Start("inverse-dynamics start", mesh, inverse_dynamics_guess(scene, robot, T),
                        "inverse-dynamics", T, robot)
    first = hermite_guess(scene, robot, T)
    for intervals in (2 * tr.intervals, max(tr.intervals // 2, 1)):
        yield Start(f"first mesh of {intervals} intervals", Mesh.uniform(intervals), first,
                    "interpolation", T, robot)


def _first_mesh(scene: Scene) -> Mesh:
    """The scene's own first mesh: its breaks, else equal intervals."""
    tr = scene.transcription
    return Mesh(np.asarray(tr.breaks)) if tr.breaks else Mesh.uniform(tr.intervals)


def _continuation_start(scene: Scene, robot: Robot, T: float) -> Start:
    """The continuation start (`planner.ocp.continuation`) on the scene's first mesh."""
    return Start("continuation", _first_mesh(scene), continuation.relaxed_guess(scene, robot, T),
                 "relaxed dynamics", T, robot, relaxed=True)


def _inverse_dynamics_applies(robot: Robot) -> bool:
    """The classical inverse dynamics needs passive joints and as many active ones."""
    return 0 < len(robot.passive) <= len(robot.active)


def _refine(scene: Scene, attempt: Attempt, budget: Budget,
            progress: Handler | None, first_pass: int) -> None:
    """Refine the mesh of the attempt's last outcome while it converged but is not
    accurate, and stop at an artefact of the mesh (`_artefact`): the next start follows."""
    refinement, tolerance = scene.transcription.refinement, scene.solver.resimulation_tolerance
    outcomes = attempt.outcomes
    while refinement.enabled and len(outcomes) <= refinement.max_passes and not budget.spent:
        last = outcomes[-1]
        if len(outcomes) > 1 and _artefact(outcomes[-2], last) \
                or not last.solution.success or last.accurate(tolerance):
            return
        mesh = refined(last.inst.mesh, last.errors, last.inst.problem.transcription.order,
                       tolerance, refinement.max_intervals)
        if mesh is None:
            return
        inst = instance(scene, last.robot, mesh, last.T)
        attempt.add(_solve_on(scene, inst, last.robot, last.T,
                              interpolant_guess(last.interp, last.T), budget, progress,
                              first_pass + len(attempt.passes) - 1, last.record.strategy))


ARTEFACT_GROWTH = 2.0
"""A refined plan whose objective exceeds its predecessor's by this factor, no more
accurate than half its error, left an optimum that the coarser mesh made up."""


def _artefact(before: Outcome, after: Outcome) -> bool:
    """Whether refining `before` into `after` moved away from a mesh artefact: a refined
    solve stays at a true optimum (a pass after the first changes the objective by the
    discretisation error), while at an artefact the objective grows pass after pass."""
    f0, f1 = before.solution.objective, after.solution.objective
    if not (before.solution.success and math.isfinite(f0) and math.isfinite(f1)) or f0 <= 0:
        return False
    error0, error1 = float(before.errors.max()), float(after.errors.max())
    return f1 > ARTEFACT_GROWTH * f0 and not error1 < error0 / 2


def _rank(outcome: Outcome) -> tuple[bool, float]:
    """Converged plans first, then the smallest interval error."""
    worst = float(outcome.errors.max()) if outcome.errors.size else math.inf
    return (not outcome.solution.success, worst if math.isfinite(worst) else math.inf)


def _solve_on(scene: Scene, inst: Instance, robot: Robot, T: float, guess: Guess,
              budget: Budget, progress: Handler | None, mesh_pass: int,
              strategy: str, point: NlpSolution | None = None,
              stall: bool = False) -> Outcome:
    """Solve on the instance's mesh from a guess (or from an earlier solution, primal and
    dual; stall: a cold solve is stopped when it stalls), and estimate the plan's interval
    errors."""
    started = time.perf_counter()
    if point is None:
        solution = solve(inst, initial_point(inst, guess, T, robot), budget, progress,
                         mesh_pass, stall=stall)
    else:
        solution = solve(inst, np.asarray(point.x), budget, progress, mesh_pass,
                         (np.asarray(point.lam_x), np.asarray(point.lam_g)))
    outcome = _outcome(scene, inst, robot, T, solution, strategy, started)
    if not outcome.finite:
        return outcome
    checked = time.perf_counter()
    errors, status = interval_errors(outcome.robot, outcome.interp, scene.solver.jit,
                                     budget.deadline)
    replayed = open_loop(outcome.robot, outcome.interp, scene.solver.jit, budget.deadline)
    budget.measured = time.perf_counter() - checked  # what the final checks will scale with
    record = outcome.record.model_copy(update={
        "max_local_error": _finite_or_none(float(errors.max())),
        "resimulation_error": replayed[0], "time": time.perf_counter() - started})
    return replace(outcome, errors=errors, errors_status=status, replayed=replayed,
                   record=record)


def _relaxed_solve(scene: Scene, inst: Instance, robot: Robot, T: float, name: str,
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
    return _outcome(scene, inst, robot, T, solution,
                    f"{name}: relaxed, virtual weight {weight:g}", started)


def _outcome(scene: Scene, inst: Instance, robot: Robot, T: float, solution: Solution,
             strategy: str, started: float) -> Outcome:
    """What a solve gives (solved robot, duration, interpolant), its errors not yet
    estimated (inf)."""
    finite = bool(np.all(np.isfinite(solution.x)))
    solved = _solved_robot(inst, robot, solution.x) if finite else robot
    duration = _duration(scene, inst, solution.x) if finite else T
    interp = _interpolant(inst, solved, duration, solution.x)
    errors = np.full(inst.mesh.intervals, np.inf)
    status = NOT_FINITE if not finite else "not estimated: a preliminary solve"
    record = MeshPass(strategy=strategy, intervals=inst.mesh.intervals,
                      iterations=solution.iterations,
                      status=solution.status, objective=_finite_or_none(solution.objective),
                      max_local_error=None, resimulation_error=None,
                      time=time.perf_counter() - started)
    return Outcome(inst, solution, solved, duration, interp, finite, errors, status,
                   (None, status), record)


def _earlier_guess(robot: Robot, earlier: Plan) -> Guess:
    """An earlier plan's trajectory as the initial guess; InputError when it is of
    another arm."""
    shape = (len(earlier.q[0]), len(earlier.tau[0]))
    if shape != (robot.n, len(robot.active)):
        raise InputError(f"warm_start: the earlier plan is of an arm with {shape[0]} joints, "
                         f"{shape[1]} of them active; this one has {robot.n}, "
                         f"{len(robot.active)}")
    return plan_guess(earlier)


def _guess(scene: Scene, robot: Robot, T: float) -> tuple[Guess, str]:
    """The scene's initial guess (`solver.initial_guess`) and what it was: an inverse
    dynamics that cannot be computed leaves the interpolation."""
    if scene.solver.initial_guess == "inverse-dynamics":
        try:
            return inverse_dynamics_guess(scene, robot, T), "inverse-dynamics"
        except ValueError as exc:
            return hermite_guess(scene, robot, T), f"interpolation; inverse-dynamics refused: {exc}"
    return hermite_guess(scene, robot, T), "interpolation"


def _design_robot(scene: Scene) -> Robot:
    """The robot whose numbers seed the NLP: co-designed joints get their fixed frequency
    and a starting amplitude of half the bound."""
    co = scene.task.co_design
    if co is None:
        return scene.robot
    waves = {}
    for col, joint in enumerate(scene.robot.active):
        link = scene.robot.links[joint]
        amp = min(co.amplitude_max, 0.95 * link.length) / 2
        phase = link.wave.phase if link.wave is not None else 0.0
        waves[joint] = Wave(amplitude=amp, frequency=co.frequency[col], phase=phase)
    return scene.robot.with_waves(waves)


def _duration_guess(scene: Scene) -> float:
    d = scene.task.duration
    return math.sqrt(d.min * d.max) if isinstance(d, DurationRange) else d


def _duration(scene: Scene, inst: Instance, x: np.ndarray) -> float:
    """The duration [s]: the solution's own where it is free (a duration range)."""
    duration = scene.task.duration
    if isinstance(duration, DurationRange):  # the key's free_time
        return float(inst.problem.layout.view(x, "T")[0, 0])
    return float(duration)


def _solved_robot(inst: Instance, robot: Robot, x: np.ndarray) -> Robot:
    """The robot with the co-designed waves of the solution (unchanged otherwise)."""
    if not inst.problem.key.codesign:
        return robot
    values = inst.problem.layout.view(x, "wave").ravel()
    amp, phase = values[0::2], values[1::2]
    waves = {}
    for col, joint in enumerate(robot.active):
        wave = robot.links[joint].wave
        if wave is None:
            raise ValueError(f"co-designed joint {joint} has no wave to take its frequency from")
        freq = wave.frequency
        a = float(np.clip(amp[col], 0.0, 0.95 * robot.links[joint].length))
        waves[joint] = Wave(amplitude=a, frequency=freq, phase=float(phase[col]))
    return robot.with_waves(waves)


def _interpolant(inst: Instance, robot: Robot, T: float, x: np.ndarray) -> Interpolant:
    """The solution's states and torques between its knots, on the mesh in seconds."""
    lay = inst.problem.layout
    blocks = {name: lay.view(x, name) for name, (kind, _) in lay.blocks.items()
              if kind != "global"}
    dynamics = Dynamics(robot)
    return inst.problem.transcription.interpolant(blocks, inst.mesh.breaks * T,
                                                  dynamics.forward_many)


def _result(scene: Scene, attempts: list[Attempt], budget: Budget,
            probe: _DurationProbe | None = None) -> Plan:
    """The plan of the best outcome of the attempts, checked (`verify`), with the
    infeasibility the attempts or the duration probe establish."""
    ranked = [(o, a) for a in attempts for o in a.outcomes]
    best, attempt = min(ranked, key=lambda pair: _rank(pair[0]))
    if infeasibility.agreed(attempts):  # the plan is the most informative one's iterate
        best, attempt = infeasibility.most_informative(attempts) or (best, attempt)
    outcomes = [o for a in attempts for o in a.solves()]
    sol, interp, robot = best.solution, best.interp, best.robot
    breaks = best.inst.mesh.breaks * best.T
    tolerance = scene.solver.resimulation_tolerance
    success, note = sol.success, sol.message
    if not best.finite:
        success, note = False, note or "the solve produced non-finite values"
    per = REPLAY_SAMPLES * max(1, math.ceil(DENSE_POINTS / (REPLAY_SAMPLES * len(breaks))))
    t_dense = np.concatenate([np.linspace(a, b, per, endpoint=False)
                              for a, b in itertools.pairwise(breaks)] + [breaks[-1:]])
    verification, feedback = (verify(robot, interp, t_dense, best.errors, best.errors_status,
                                     best.replayed, tolerance, scene.task.torque_limit,
                                     scene.solver.jit, scene.task.position_bounds,
                                     scene.task.velocity_bounds, scene.task.uncertainty,
                                     scene.solver.robustness, budget.deadline)
                              if best.finite else (_unverified(tolerance), None))
    built = [o.inst for o in outcomes if not o.inst.cache_hit]
    refined_by = " + mesh refinement" if best is not attempt.outcomes[0] else ""
    return infeasibility.annotate(Plan(
        t=breaks.tolist(), q=_finite(interp.q(breaks)), dq=_finite(interp.dq(breaks)),
        ddq=_finite(interp.dq(breaks, derivative=1)), tau=_finite(interp.tau(breaks)),
        dense=DenseTrajectory(t=t_dense.tolist(), q=_finite(interp.q(t_dense)),
                              tau=_finite(interp.tau(t_dense))),
        torque=TorquePolynomial(breaks=breaks.tolist(), coefficients=_finite(interp.tau.coeffs)),
        states=StatePolynomials(breaks=breaks.tolist(), q=_finite(interp.q.coeffs),
                                dq=_finite(interp.dq.coeffs)),
        duration=best.T,
        objective=sol.objective if math.isfinite(sol.objective) else None,
        waves=[WaveOut(joint=j, amplitude=link.wave.amplitude, frequency=link.wave.frequency,
                       phase=link.wave.phase)
               for j, link in enumerate(robot.links) if link.wave is not None],
        solver=SolverReport(status=sol.status, success=success, message=note,
                            iterations=budget.used,
                            build_time=sum(i.problem.build_time for i in built),
                            solve_time=sum(o.solution.time for o in outcomes),
                            total_time=time.perf_counter() - budget.started,
                            cache_hit=outcomes[0].inst.cache_hit,
                            compiled=outcomes[0].inst.problem.compiled,
                            initial_guess=attempt.start.guess_used,
                            strategy=attempt.start.name + refined_by),
        mesh_passes=_records(outcomes, probe),
        feedback=feedback,
        verification=verification,
        solution=_nlp_solution(best),
    ), scene, attempts, best, attempt, None if probe is None else probe.found)


def _records(outcomes: list[Outcome], probe: _DurationProbe | None) -> list[MeshPass]:
    """Every solve of the plan in the order they ran, the duration probe's included."""
    records = [o.record for o in outcomes]
    if probe is None or probe.found is None:
        return records
    return records[:probe.after] + probe.found.passes + records[probe.after:]


def _nlp_solution(outcome: Outcome) -> NlpSolution | None:
    """The outcome's NLP solution, to warm-start a later plan from (None without multipliers)."""
    sol = outcome.solution
    if sol.lam_x is None or sol.lam_g is None or not outcome.finite:
        return None
    return NlpSolution(fingerprint=outcome.inst.problem.key.fingerprint(),
                       breaks=outcome.inst.mesh.breaks.tolist(), x=sol.x.tolist(),
                       lam_x=np.nan_to_num(sol.lam_x).tolist(),
                       lam_g=np.nan_to_num(sol.lam_g).tolist())


def _unverified(tolerance: float) -> Verification:
    return Verification(resimulation_error=None, resimulation_status=NOT_FINITE,
                        verified=False, tolerance=tolerance, defect=None, min_sigma=None,
                        waveless_min_sigma=None, waveless_singular_crossings=[])


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _finite(a: np.ndarray) -> list:
    """Nested lists, with any non-finite entry replaced by 0 (the plan then says it failed)."""
    return np.where(np.isfinite(a), a, 0.0).tolist()
