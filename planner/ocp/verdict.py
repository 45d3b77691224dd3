"""What happened to a plan, in one word (`PlanStatus`) and one message: the plan's top-level
verdict, with the last solve's own status kept beneath it as a detail (`solver.status`)."""

from __future__ import annotations

from typing import Literal

from planner.ocp.evidence import Infeasibility
from planner.ocp.verification import Verification

PlanStatus = Literal["verified", "unverified", "infeasible", "out-of-budget",
                     "solver-failure", "cancelled"]
"""verified: converged and every check passed (the task is done); unverified: converged,
but a check failed; infeasible: the task cannot be done, with evidence
(`Plan.infeasibility`: a check's proof before any solve, or the duration probe's verified
plan at a longer duration); out-of-budget: no converged plan within solver.max_iter or
max_wall_time; solver-failure: no converged plan for another reason (a stall, an
evaluation error, a restoration failure without a second witness); cancelled: stopped on
request."""

OUT_OF_BUDGET = frozenset({"Maximum_Iterations_Exceeded", "Maximum_WallTime_Exceeded"})
"""Statuses of a solve stopped by the plan's iteration or wall-time budget."""
CANCELLED = "User_Requested_Stop"


def verdict(converged: bool, status: str, message: str, verification: Verification,
            infeasible: Infeasibility | None) -> tuple[PlanStatus, str]:
    """The plan's status and message from its last solve (`converged`, its `status` and
    `message`), its checks and its infeasibility (None: none shown). Attempts that agree
    the task is locally infeasible (source "solver") prove nothing: a solver failure."""
    if infeasible is not None and infeasible.source != "solver":
        return "infeasible", f"infeasible: {infeasible.summary}"
    if infeasible is not None:
        return "solver-failure", f"solver failure: {infeasible.summary}"
    reason = unverified_reason(verification)
    if converged and verification.verified:
        return "verified", "verified: the plan converged and does the task within every check"
    if converged:
        return "unverified", f"unverified: {reason}"
    if status == CANCELLED:
        return "cancelled", "cancelled: the plan was stopped on request"
    if status in OUT_OF_BUDGET:
        return "out-of-budget", (f"out of budget: no converged plan before {message} "
                                 f"({status})")
    return "solver-failure", f"solver failure: no converged plan ({status}: {message})"


def unverified_reason(v: Verification) -> str | None:
    """Why a plan failed its checks (convergence, accuracy, the task's limits and other
    requirements, robustness); None when it passed (or predates the checks)."""
    if v.verified is not False:
        return None
    reasons = []
    if v.converged is False:
        reasons.append("its last solve did not converge, so the returned iterate is no "
                       "solution of the task's NLP")
    accuracy = _accuracy(v)
    if accuracy is not None:
        reasons.append(accuracy)
    if v.limit_violations:
        reasons.append("the plan does not keep the task's limits everywhere: "
                       + "; ".join(v.limit_violations))
    if v.task_violations:
        reasons.append("the plan does not do what the task asks: "
                       + "; ".join(v.task_violations))
    if _fragile(v):
        r = v.robustness
        assert r is not None  # _fragile says so
        worst = "diverges" if r.worst_tracking_error is None else \
            f"departs from the plan by up to {r.worst_tracking_error:.3g} rad"
        reasons.append(f"with its feedback on the perturbed model {r.worst_model!r} the arm "
                       f"{worst} (solver.robustness {r.bound:g} rad)")
    return "; and ".join(reasons) if reasons else _refinement_message(v)


def _accuracy(v: Verification) -> str | None:
    """The accuracy part of the reason (None where the plan was accurate)."""
    if v.local_error is None:
        return f"the plan's intervals could not all be re-integrated ({v.local_status})"
    if v.tolerance is not None and v.local_error <= v.tolerance:
        return None
    if v.converged is False:
        return (f"re-integrated interval by interval, the delivered torque departs from the "
                f"plan by {v.local_error:.3g} rad (tolerance {v.tolerance:g} rad)")
    return _refinement_message(v)


def _refinement_message(v: Verification) -> str:
    return (f"re-integrated interval by interval, the delivered torque departs from the plan "
            f"by {v.local_error:.3g} rad (tolerance {v.tolerance:g} rad): the mesh refinement "
            f"ran out of budget; raise transcription.refinement's max_intervals or max_passes, "
            f"or solver.max_iter and max_wall_time")


def _fragile(v: Verification) -> bool:
    """Whether the plan failed its robustness bound."""
    return v.robustness is not None and v.robustness.within is False
