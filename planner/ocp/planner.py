"""plan(): solve a scene's NLP, refine its mesh until the plan is accurate, verify it.

The first solve runs on the scene's uniform mesh from the initial guess. While the plan
is not accurate (an interval re-integrated from the plan's own state departs from it by
more than `solver.resimulation_tolerance`, see `planner.ocp.accuracy`) and the budget
allows, the mesh is refined where the error is (`planner.ocp.refine`) and the NLP solved
again from the previous plan interpolated onto the new mesh, so that the refined solve
stays at the same local optimum.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from planner.dynamics import Dynamics
from planner.model import Robot, Wave
from planner.ocp.accuracy import interval_errors
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
from planner.ocp.refine import refined
from planner.ocp.result import (
    DenseTrajectory,
    MeshPass,
    Plan,
    SolverReport,
    TorquePolynomial,
    Verification,
    WaveOut,
)
from planner.ocp.solve import Budget, Solution, solve
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import resimulation_error, verify
from planner.scene import DurationRange, Scene

DENSE_POINTS = 2000  # about this many dense samples per plan
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

    def accurate(self, tolerance: float) -> bool:
        return self.finite and bool(np.all(self.errors <= tolerance))


def plan(scene: Scene, progress: Handler | None = None, warm_start: Plan | None = None) -> Plan:
    """Plan feed-forward torques for a scene.

    progress is called once per Ipopt iteration; returning False stops the plan.
    warm_start: an earlier plan whose trajectory seeds the initial guess.
    A failed solve is returned (success False, Ipopt's last iterate), never raised.
    """
    budget = Budget.of(scene.solver.max_iter, scene.solver.max_wall_time)
    robot, T = _design_robot(scene), _duration_guess(scene)
    guess, guess_used = _guess(scene, robot, T, warm_start)
    tr = scene.transcription
    mesh = Mesh(np.asarray(tr.breaks)) if tr.breaks else Mesh.uniform(tr.intervals)
    inst = instance(scene, robot, mesh, T)
    build_time = 0.0 if inst.cache_hit else inst.problem.build_time
    outcomes = [_solve_on(scene, inst, robot, T, guess, budget, progress, 0)]
    refinement = scene.transcription.refinement
    while refinement.enabled and len(outcomes) <= refinement.max_passes and not budget.spent:
        last = outcomes[-1]
        if not last.solution.success or last.accurate(scene.solver.resimulation_tolerance):
            break
        mesh = refined(last.inst.mesh, last.errors, last.inst.problem.transcription.order,
                       scene.solver.resimulation_tolerance, refinement.max_intervals)
        if mesh is None:
            break
        inst = instance(scene, last.robot, mesh, last.T)
        build_time += 0.0 if inst.cache_hit else inst.problem.build_time
        outcomes.append(_solve_on(scene, inst, last.robot, last.T,
                                  interpolant_guess(last.interp, last.T), budget, progress,
                                  len(outcomes)))
    best = min(outcomes, key=_rank)
    strategy = "direct" if best is outcomes[0] else "refined"
    return _result(scene, best, outcomes, budget, build_time, outcomes[0].inst.cache_hit,
                   guess_used, strategy)


def _rank(outcome: Outcome) -> tuple[bool, float]:
    """Converged plans first, then the smallest interval error."""
    worst = float(outcome.errors.max()) if outcome.errors.size else math.inf
    return (not outcome.solution.success, worst if math.isfinite(worst) else math.inf)


def _solve_on(scene: Scene, inst: Instance, robot: Robot, T: float, guess: Guess,
              budget: Budget, progress: Handler | None, mesh_pass: int) -> Outcome:
    """Solve on the instance's mesh from a guess, and estimate the plan's interval errors."""
    started = time.perf_counter()
    x0 = initial_point(inst, guess, T, robot)
    solution = solve(inst, x0, budget, progress, mesh_pass)
    finite = bool(np.all(np.isfinite(solution.x)))
    solved = _solved_robot(inst, robot, solution.x) if finite else robot
    duration = _duration(scene, inst, solution.x) if finite else T
    interp = _interpolant(inst, solved, duration, solution.x)
    errors, status, replay = np.full(inst.mesh.intervals, np.inf), NOT_FINITE, None
    if finite:
        errors, status = interval_errors(solved, interp)
        replay = resimulation_error(solved, interp, 1)[0]
    record = MeshPass(intervals=inst.mesh.intervals, iterations=solution.iterations,
                      status=solution.status, objective=_finite_or_none(solution.objective),
                      max_local_error=_finite_or_none(float(errors.max())),
                      resimulation_error=replay, time=time.perf_counter() - started)
    return Outcome(inst, solution, solved, duration, interp, finite, errors, status, record)


def _guess(scene: Scene, robot: Robot, T: float, warm_start: Plan | None) -> tuple[Guess, str]:
    """The initial guess (an earlier plan, else the scene's `solver.initial_guess`) and
    what it was: an inverse dynamics that cannot be computed leaves the interpolation."""
    if warm_start is not None:
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
    if inst.problem.key.free_time:
        return float(inst.problem.layout.view(x, "T")[0, 0])
    return float(scene.task.duration)


def _solved_robot(inst: Instance, robot: Robot, x: np.ndarray) -> Robot:
    """The robot with the co-designed waves of the solution (unchanged otherwise)."""
    if not inst.problem.key.codesign:
        return robot
    values = inst.problem.layout.view(x, "wave").ravel()
    amp, phase = values[0::2], values[1::2]
    waves = {}
    for col, joint in enumerate(robot.active):
        freq = robot.links[joint].wave.frequency
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


def _result(scene: Scene, best: Outcome, outcomes: list[Outcome], budget: Budget,
            build_time: float, cache_hit: bool, guess_used: str, strategy: str) -> Plan:
    sol, interp, robot = best.solution, best.interp, best.robot
    breaks = best.inst.mesh.breaks * best.T
    tolerance = scene.solver.resimulation_tolerance
    success, note = sol.success, sol.message
    if not best.finite:
        success, note = False, note or "the solve produced non-finite values"
    per = max(1, math.ceil(DENSE_POINTS / best.inst.mesh.intervals))
    t_dense = np.concatenate([np.linspace(a, b, per, endpoint=False)
                              for a, b in zip(breaks[:-1], breaks[1:])] + [breaks[-1:]])
    verification = (verify(robot, interp, t_dense, best.errors, best.errors_status, tolerance,
                           scene.task.torque_limit)
                    if best.finite else _unverified(tolerance))
    return Plan(
        t=breaks.tolist(), q=_finite(interp.q(breaks)), dq=_finite(interp.dq(breaks)),
        ddq=_finite(interp.dq(breaks, derivative=1)), tau=_finite(interp.tau(breaks)),
        dense=DenseTrajectory(t=t_dense.tolist(), q=_finite(interp.q(t_dense)),
                              tau=_finite(interp.tau(t_dense))),
        torque=TorquePolynomial(breaks=breaks.tolist(), coefficients=_finite(interp.tau.coeffs)),
        duration=best.T,
        objective=sol.objective if math.isfinite(sol.objective) else None,
        waves=[WaveOut(joint=j, amplitude=link.wave.amplitude, frequency=link.wave.frequency,
                       phase=link.wave.phase)
               for j, link in enumerate(robot.links) if link.wave is not None],
        solver=SolverReport(status=sol.status, success=success, message=note,
                            iterations=budget.used, build_time=build_time,
                            solve_time=sum(o.solution.time for o in outcomes),
                            total_time=time.perf_counter() - budget.started,
                            cache_hit=cache_hit, initial_guess=guess_used, strategy=strategy),
        mesh_passes=[o.record for o in outcomes],
        verification=verification,
    )


def _unverified(tolerance: float) -> Verification:
    return Verification(resimulation_error=None, resimulation_status=NOT_FINITE,
                        verified=False, tolerance=tolerance, defect=None, min_sigma=None,
                        waveless_min_sigma=None, waveless_singular_crossings=[])


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _finite(a: np.ndarray) -> list:
    """Nested lists, with any non-finite entry replaced by 0 (the plan then says it failed)."""
    return np.where(np.isfinite(a), a, 0.0).tolist()
