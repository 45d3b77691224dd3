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
from dataclasses import dataclass

import numpy as np

from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import Robot, Wave
from planner.ocp.accuracy import interval_errors
from planner.ocp.feedback import REPLAY_SAMPLES
from planner.ocp.guess import (
    Guess,
    hermite_guess,
    interpolant_guess,
    inverse_dynamics_guess,
    plan_guess,
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


@dataclass
class Attempt:
    """The solves of one start: on its coarse mesh if it has one (`coarse`), then on its
    mesh and the refinements of that (`outcomes`)."""

    start: Start
    coarse: list[Outcome]
    outcomes: list[Outcome]

    def solves(self) -> list[Outcome]:
        return [*self.coarse, *self.outcomes]


def plan(scene: Scene, progress: Handler | None = None, warm_start: Plan | None = None) -> Plan:
    """Plan feed-forward torques for a scene.

    progress is called once per Ipopt iteration; returning False stops the plan.
    warm_start: an earlier plan whose trajectory seeds the initial guess.
    A failed solve is returned (success False, Ipopt's last iterate), never raised.
    """
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    robot, T = _design_robot(scene), _duration_guess(scene)
    tolerance = scene.solver.resimulation_tolerance
    attempts: list[Attempt] = []
    starts = itertools.islice(_starts(scene, robot, T, warm_start, attempts),
                              1 + scene.solver.retries)
    for start in starts:
        coarse, first = _first_solves(scene, start, budget, progress, _passes(attempts))
        outcomes = [first]
        attempts.append(Attempt(start, coarse, outcomes))
        _refine(scene, outcomes, budget, progress, _passes(attempts))
        last = outcomes[-1]
        settled = last.accurate(tolerance) or not scene.transcription.refinement.enabled
        if last.solution.success and settled or budget.spent \
                or last.solution.status == "User_Requested_Stop":
            break
    return _result(scene, attempts, budget)


def _passes(attempts: list[Attempt]) -> int:
    return sum(len(a.solves()) for a in attempts)


def _first_solves(scene: Scene, start: Start, budget: Budget, progress: Handler | None,
                  first_pass: int) -> tuple[list[Outcome], Outcome]:
    """An attempt's solve on its coarse mesh (if any), and its first solve on its own
    mesh: from the coarse plan where that converged, else from the start's guess."""
    guess, robot, T, coarse = start.guess, start.robot, start.T, []
    if start.coarse is not None:
        coarse = [_solve_on(scene, instance(scene, robot, start.coarse, T), robot, T, guess,
                            budget, progress, first_pass, start.name)]
        if coarse[0].solution.success:
            guess, robot, T = (interpolant_guess(coarse[0].interp, coarse[0].T),
                               coarse[0].robot, coarse[0].T)
    first = _solve_on(scene, instance(scene, robot, start.mesh, T), robot, T, guess, budget,
                      progress, first_pass + len(coarse), start.name, start.point)
    return coarse, first


def _starts(scene: Scene, robot: Robot, T: float, warm_start: Plan | None,
            attempts: list[Attempt]) -> Iterator[Start]:
    """The attempts of a plan, in order, each tried while the ones before it have not
    given a converged plan (with mesh refinement on: an accurate one; docs/planner.md,
    "Retries"): an earlier plan's own NLP solution where it solved the same problem on a
    mesh at least as fine as the scene's (its refined mesh is kept); the scene's own start
    (with refinement on, a uniform mesh of over COARSE_INTERVALS intervals solved on that
    many first, unless an earlier plan is the guess); a restart from the last iterate of
    a solve that did not converge;
    the classical inverse dynamics as the initial guess; a first mesh of twice, then of
    half the intervals."""
    tr = scene.transcription
    mesh = Mesh(np.asarray(tr.breaks)) if tr.breaks else Mesh.uniform(tr.intervals)
    guess, used = _guess(scene, robot, T, warm_start)
    earlier = warm_start.solution if warm_start is not None else None
    if warm_start is not None and earlier is not None:
        solved_on = Mesh(np.asarray(earlier.breaks))
        same = ProblemKey.of(scene, solved_on.intervals).fingerprint() == earlier.fingerprint
        if same and solved_on.intervals >= mesh.intervals:
            yield Start("warm start", solved_on, guess, used, warm_start.duration, robot, earlier)
    if tr.refinement.enabled and warm_start is None and tr.breaks is None \
            and tr.intervals > COARSE_INTERVALS:
        yield Start("coarse to fine", mesh, guess, used, T, robot,
                    coarse=Mesh.uniform(COARSE_INTERVALS))
    else:
        yield Start("direct", mesh, guess, used, T, robot)
    last = attempts[-1].outcomes[-1]
    if last.finite and not last.solution.success:
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


def _inverse_dynamics_applies(robot: Robot) -> bool:
    """The classical inverse dynamics needs passive joints and as many active ones."""
    return 0 < len(robot.passive) <= len(robot.active)


def _refine(scene: Scene, outcomes: list[Outcome], budget: Budget,
            progress: Handler | None, first_pass: int) -> None:
    """Refine the mesh of the last outcome while it converged but is not accurate."""
    refinement, tolerance = scene.transcription.refinement, scene.solver.resimulation_tolerance
    while refinement.enabled and len(outcomes) <= refinement.max_passes and not budget.spent:
        last = outcomes[-1]
        if not last.solution.success or last.accurate(tolerance):
            return
        mesh = refined(last.inst.mesh, last.errors, last.inst.problem.transcription.order,
                       tolerance, refinement.max_intervals)
        if mesh is None:
            return
        inst = instance(scene, last.robot, mesh, last.T)
        outcomes.append(_solve_on(scene, inst, last.robot, last.T,
                                  interpolant_guess(last.interp, last.T), budget, progress,
                                  first_pass + len(outcomes) - 1, last.record.strategy))


def _rank(outcome: Outcome) -> tuple[bool, float]:
    """Converged plans first, then the smallest interval error."""
    worst = float(outcome.errors.max()) if outcome.errors.size else math.inf
    return (not outcome.solution.success, worst if math.isfinite(worst) else math.inf)


def _solve_on(scene: Scene, inst: Instance, robot: Robot, T: float, guess: Guess,
              budget: Budget, progress: Handler | None, mesh_pass: int,
              strategy: str, point: NlpSolution | None = None) -> Outcome:
    """Solve on the instance's mesh from a guess (or from an earlier solution, primal and
    dual), and estimate the plan's interval errors."""
    started = time.perf_counter()
    if point is None:
        solution = solve(inst, initial_point(inst, guess, T, robot), budget, progress, mesh_pass)
    else:
        solution = solve(inst, np.asarray(point.x), budget, progress, mesh_pass,
                         (np.asarray(point.lam_x), np.asarray(point.lam_g)))
    finite = bool(np.all(np.isfinite(solution.x)))
    solved = _solved_robot(inst, robot, solution.x) if finite else robot
    duration = _duration(scene, inst, solution.x) if finite else T
    interp = _interpolant(inst, solved, duration, solution.x)
    errors, status = np.full(inst.mesh.intervals, np.inf), NOT_FINITE
    replayed: tuple[float | None, str] = (None, NOT_FINITE)
    if finite:
        errors, status = interval_errors(solved, interp, scene.solver.jit)
        replayed = open_loop(solved, interp, scene.solver.jit)
    record = MeshPass(strategy=strategy, intervals=inst.mesh.intervals,
                      iterations=solution.iterations,
                      status=solution.status, objective=_finite_or_none(solution.objective),
                      max_local_error=_finite_or_none(float(errors.max())),
                      resimulation_error=replayed[0], time=time.perf_counter() - started)
    return Outcome(inst, solution, solved, duration, interp, finite, errors, status, replayed,
                   record)


def _guess(scene: Scene, robot: Robot, T: float, warm_start: Plan | None) -> tuple[Guess, str]:
    """The initial guess (an earlier plan, else the scene's `solver.initial_guess`) and
    what it was: an inverse dynamics that cannot be computed leaves the interpolation."""
    if warm_start is not None:
        shape = (len(warm_start.q[0]), len(warm_start.tau[0]))
        if shape != (robot.n, len(robot.active)):
            raise InputError(f"warm_start: the earlier plan is of an arm with {shape[0]} joints, "
                             f"{shape[1]} of them active; this one has {robot.n}, "
                             f"{len(robot.active)}")
        return plan_guess(warm_start), "warm start"
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


def _result(scene: Scene, attempts: list[Attempt], budget: Budget) -> Plan:
    ranked = [(o, a) for a in attempts for o in a.outcomes]
    best, attempt = min(ranked, key=lambda pair: _rank(pair[0]))
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
                                     scene.solver.jit)
                              if best.finite else (_unverified(tolerance), None))
    built = [o.inst for o in outcomes if not o.inst.cache_hit]
    refined_by = " + mesh refinement" if best is not attempt.outcomes[0] else ""
    return Plan(
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
        mesh_passes=[o.record for o in outcomes],
        feedback=feedback,
        verification=verification,
        solution=_nlp_solution(best),
    )


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
