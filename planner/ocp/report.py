"""The plan a strategy returns: the best outcome of its attempts, sampled, checked
(`planner.ocp.verify`) and reported with every solve and the infeasibility the attempts
or the duration probe establish (`planner.ocp.infeasibility`)."""

from __future__ import annotations

import itertools
import math
import time

import numpy as np

from planner.ocp import infeasibility
from planner.ocp.attempt import Attempt
from planner.ocp.outcome import NOT_FINITE, Outcome, finite_or_none
from planner.ocp.replays import REPLAY_SAMPLES
from planner.ocp.result import (
    DenseTrajectory,
    MeshPass,
    NlpSolution,
    Plan,
    SolverReport,
    StatePolynomials,
    waves_of,
)
from planner.ocp.shortest import Probe
from planner.ocp.solve import Budget, Clock
from planner.ocp.verdict import verdict
from planner.ocp.verification import Feedback, Verification
from planner.ocp.verify import verify
from planner.scene import Scene
from planner.torque import TorquePolynomial

DENSE_POINTS = 2000  # about this many dense samples per plan, at least REPLAY_SAMPLES per
# interval and a multiple of them, so that the replays' samples are among the dense ones


def best_of(attempts: list[Attempt], tolerance: float) -> tuple[Outcome, Attempt]:
    """The outcome the plan reports and its attempt: converged plans first, then those
    accurate within `tolerance` [rad] with their coupling margin proven, then the smallest
    interval error; where the attempts agree that the task is infeasible, the most
    informative of them."""
    ranked = [(o, a) for a in attempts for o in a.outcomes]
    best = min(ranked, key=lambda pair: (not pair[0].solution.success,
                                         not pair[0].accurate(tolerance),
                                         pair[0].worst_error()))
    if infeasibility.agreed(attempts):
        return infeasibility.most_informative(attempts) or best
    return best


def plan_of(scene: Scene, attempts: list[Attempt], budget: Budget,
            probe: Probe | None = None, probe_after: int = 0) -> Plan:
    """The plan of the best outcome of the attempts, checked, with the infeasibility the
    attempts or the duration probe (`probe`, which ran after the plan's first
    `probe_after` solves) establish."""
    best, attempt = best_of(attempts, scene.solver.resimulation_tolerance)
    outcomes = [o for a in attempts for o in a.passes]
    sol, interp = best.solution, best.interp
    breaks = best.inst.mesh.breaks * best.T
    t_dense = dense_times(breaks)
    success, note = sol.success, sol.message
    if not best.finite:
        success, note = False, note or "the solve produced non-finite values"
    verification, feedback = _checks(scene, best, t_dense, budget, success)
    built = [o.inst for o in outcomes if not o.inst.cache_hit]
    refined_by = " + mesh refinement" if best is not attempt.outcomes[0] else ""
    plan = Plan(
        t=breaks.tolist(), q=_finite(interp.q(breaks)), dq=_finite(interp.dq(breaks)),
        ddq=_finite(interp.dq(breaks, derivative=1)), tau=_finite(interp.tau(breaks)),
        dense=DenseTrajectory.model_construct(  # lists of floats by construction: a
            # validation of its 2000 rows took as long as a replay of a two-link plan
            t=t_dense.tolist(), q=_finite(interp.q(t_dense)), tau=_finite(interp.tau(t_dense))),
        torque=TorquePolynomial(breaks=breaks.tolist(), coefficients=_finite(interp.tau.coeffs)),
        states=StatePolynomials(breaks=breaks.tolist(), q=_finite(interp.q.coeffs),
                                dq=_finite(interp.dq.coeffs)),
        duration=best.T,
        objective=finite_or_none(sol.objective),
        waves=waves_of(best.robot),
        solver=SolverReport(status=sol.status, success=success, message=note,
                            iterations=budget.used,
                            build_time=sum(i.problem.build_time for i in built),
                            solve_time=sum(o.solution.time for o in outcomes),
                            total_time=time.perf_counter() - budget.started,
                            cache_hit=outcomes[0].inst.cache_hit,
                            compiled=outcomes[0].inst.problem.compiled,
                            initial_guess=attempt.start.guess_used,
                            strategy=attempt.start.name + refined_by),
        mesh_passes=_records(outcomes, best, verification, probe, probe_after),
        feedback=feedback, verification=verification, solution=_nlp_solution(best))
    return stamped(with_verdict(infeasibility.annotate(plan, scene, attempts, best, attempt,
                                                       probe)), budget)


def stamped(plan: Plan, budget: Budget) -> Plan:
    """The plan with what its checks cost since the budget's latest solve ended, in wall
    and CPU time (unchanged before any solve)."""
    if budget.solved is None:
        return plan
    now = Clock.now()
    report = plan.solver.model_copy(update={"checks_time": now.wall - budget.solved.wall,
                                            "checks_cpu_time": now.cpu - budget.solved.cpu})
    return plan.model_copy(update={"solver": report})


def with_verdict(plan: Plan) -> Plan:
    """The plan with its status and message (`planner.ocp.verdict`)."""
    status, message = verdict(plan.solver.success, plan.solver.status, plan.solver.message,
                              plan.verification, plan.infeasibility)
    return plan.model_copy(update={"status": status, "message": message})


def dense_times(breaks: np.ndarray) -> np.ndarray:
    """The plan's dense sample times [s] (about DENSE_POINTS, REPLAY_SAMPLES per interval
    or a multiple of them, and the last break)."""
    per = REPLAY_SAMPLES * max(1, math.ceil(DENSE_POINTS / (REPLAY_SAMPLES * len(breaks))))
    return np.concatenate([np.linspace(a, b, per, endpoint=False)
                           for a, b in itertools.pairwise(breaks)] + [breaks[-1:]])


def _checks(scene: Scene, best: Outcome, t_dense: np.ndarray, budget: Budget,
            converged: bool) -> tuple[Verification, Feedback | None]:
    """The outcome's verification and feedback (`planner.ocp.verify`); none for a
    non-finite one."""
    if not best.finite:
        return unverified(scene.solver.resimulation_tolerance), None
    return verify(best.robot, best.interp, t_dense, best.errors, best.errors_status,
                  scene.task, scene.solver, converged, budget.deadline, best.margin)


def _records(outcomes: list[Outcome], best: Outcome, verification: Verification,
             probe: Probe | None, after: int) -> list[MeshPass]:
    """Every solve of the plan in the order they ran, the duration probe's included; the
    reported one (`best`) with the open-loop replay error its `verification` measured."""
    replayed = {"resimulation_error": verification.resimulation_error}
    records = [o.record.model_copy(update=replayed) if o is best else o.record
               for o in outcomes]
    if probe is None:
        return records
    return records[:after] + probe.passes + records[after:]


def _nlp_solution(outcome: Outcome) -> NlpSolution | None:
    """The outcome's NLP solution, to warm-start a later plan from (None without multipliers)."""
    sol = outcome.solution
    if sol.lam_x is None or sol.lam_g is None or not outcome.finite:
        return None
    return NlpSolution(fingerprint=outcome.inst.problem.key.fingerprint(),
                       breaks=outcome.inst.mesh.breaks.tolist(), x=sol.x.tolist(),
                       lam_x=np.nan_to_num(sol.lam_x).tolist(),
                       lam_g=np.nan_to_num(sol.lam_g).tolist())


def unverified(tolerance: float) -> Verification:
    """The verification of a plan whose solve gave non-finite values: nothing checked."""
    return Verification(resimulation_error=None, resimulation_status=NOT_FINITE,
                        verified=False, converged=False, tolerance=tolerance, defect=None,
                        min_sigma=None,
                        waveless_min_sigma=None, waveless_singular_crossings=[])


def joined(chosen: Plan, also: list[MeshPass], budget: Budget) -> Plan:
    """The chosen plan, with the solves of the process that lost listed too, and the
    plan's whole wall time."""
    report = chosen.solver.model_copy(update={
        "iterations": chosen.solver.iterations + sum(p.iterations for p in also),
        "total_time": time.perf_counter() - budget.started})
    return chosen.model_copy(update={"solver": report,
                                     "mesh_passes": [*also, *chosen.mesh_passes]})


def _finite(a: np.ndarray) -> list:
    """Nested lists, with any non-finite entry replaced by 0 (the plan then says it failed)."""
    return np.where(np.isfinite(a), a, 0.0).tolist()
