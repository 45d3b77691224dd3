"""What the task asks of the delivered plan, checked on its polynomials: the initial and
final states, the tip target, the duration, the coupling margin and an exact passive
motion. Each requirement has its figure (0 when met exactly, None when the task does not
ask it) and, beyond its tolerance, a violation in words."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.dynamics import Dynamics
from planner.model import Robot
from planner.ocp.margin_proof import MARGIN_RTOL, MarginProof
from planner.ocp.replays import planned_state
from planner.ocp.transcription import Interpolant
from planner.ocp.verification import MarginCertificate
from planner.scene import Task

STATE_TOL = 1e-6
"""A planned boundary angle or rate meets the task's value v when within
STATE_TOL max(1, |v|) [rad, rad/s]."""
TIP_TOL = 1e-6
"""[m] A planned final tip meets its target when this close to it."""
DURATION_RTOL = 1e-6
"""A planned duration within its range up to this relative tolerance (Ipopt relaxes a
variable's bounds by 1e-8 of them)."""


@dataclass(frozen=True)
class Requirements:
    """How far the plan is from what the task asks: the largest departure of the initial
    state and of the given final entries [rad, rad/s], the final tip's distance to its
    target [m], how far the duration is outside the task's [s], how far sigma_min(M_pa)
    falls below the coupling margin [kg m^2] at the samples and what is proven of it on
    whole intervals, and the passive joints from an exact prescribed motion [rad]; each None
    when the task does not ask it."""

    initial_error: float
    final_error: float | None
    tip_error: float | None
    duration_excess: float
    margin_shortfall: float | None
    margin_certificate: MarginCertificate | None
    tracking_error: float | None
    violations: list[str]


def requirements(robot: Robot, interp: Interpolant, t: np.ndarray, task: Task,
                 sigma: np.ndarray, proof: MarginProof | None,
                 tracking_tol: float) -> Requirements:
    """The plan's figures against `task`: its states at the first and last breakpoint,
    its tip at the end, its duration, sigma_min (K,) of M_pa at the samples t (K,) [s] and
    the margin's `proof` on whole intervals, and the passive angles at the samples (an
    exact prescribed motion holds within `tracking_tol` [rad])."""
    violations: list[str] = []
    breaks = interp.q.breaks
    T = float(breaks[-1] - breaks[0])
    start, end = planned_state(interp, breaks[0]), planned_state(interp, breaks[-1])
    initial = _departure(start, [*task.initial.q, *task.initial.dq], "initial", violations)
    final = _departure(end, [*task.final.q, *task.final.dq], "final", violations)
    tip = _tip(robot, end[:robot.n], task, violations)
    duration = _duration(T, task, violations)
    margin = _margin(sigma, t, task.coupling_margin, violations)
    certificate = _proven(proof, task.coupling_margin, breaks, violations)
    tracking = _tracking(robot, interp, t, T, task, tracking_tol, violations)
    return Requirements(initial if initial is not None else 0.0, final, tip, duration,
                        margin, certificate, tracking, violations)


def _departure(state: np.ndarray, wanted: list[float | None], which: str,
               violations: list[str]) -> float | None:
    """The largest |state - wanted| over the given entries (None without one); each entry
    beyond STATE_TOL max(1, |v|) said in `violations`."""
    n = len(wanted) // 2
    worst: float | None = None
    for k, value in enumerate(wanted):
        if value is None:
            continue
        gap = abs(float(state[k]) - value)
        worst = gap if worst is None else max(worst, gap)
        if gap > STATE_TOL * max(1.0, abs(value)):
            name, unit = ("q", "rad") if k < n else ("dq", "rad/s")
            violations.append(f"the plan's {which} {name} of joint {k % n} is {state[k]:.6g} "
                              f"{unit} where the task asks {value:g} {unit} (off by "
                              f"{gap:.3g} {unit}, tolerance {STATE_TOL:g} x max(1, |value|))")
    return worst


def _tip(robot: Robot, q_end: np.ndarray, task: Task, violations: list[str]) -> float | None:
    """The final tip's distance [m] to the task's target (None without one)."""
    target = task.tip_target
    if target is None:
        return None
    tip = Dynamics(robot).tips(q_end)[-1]
    gap = float(np.hypot(tip[0] - target.x, tip[1] - target.y))
    if gap > TIP_TOL:
        violations.append(f"the plan's final tip is at ({tip[0]:.6g}, {tip[1]:.6g}) m, "
                          f"{gap:.3g} m from the task's target ({target.x:g}, {target.y:g}) m "
                          f"(tolerance {TIP_TOL:g} m)")
    return gap


def _duration(T: float, task: Task, violations: list[str]) -> float:
    """How far [s] the plan's duration T is outside the task's duration or range."""
    shortest, longest = task.duration_span
    excess = max(shortest - T, T - longest, 0.0)
    if excess > DURATION_RTOL * longest:
        violations.append(f"the plan lasts {T:.6g} s, outside the task's "
                          f"[{shortest:g}, {longest:g}] s")
    return excess


def _margin(sigma: np.ndarray, t: np.ndarray, margin: float | None,
            violations: list[str]) -> float | None:
    """How far [kg m^2] sigma_min falls below the coupling margin at the samples (None
    without a margin; the whole margin where sigma_min is not finite)."""
    if margin is None:
        return None
    finite = np.isfinite(sigma)
    if not finite.all():
        violations.append("sigma_min(M_pa) could not be computed along the plan, so its "
                          f"coupling margin of {margin:g} is not shown")
        return margin
    k = int(np.argmin(sigma))
    shortfall = max(margin - float(sigma[k]), 0.0)
    if shortfall > MARGIN_RTOL * margin:
        violations.append(f"sigma_min(M_pa) falls to {sigma[k]:.6g} at t = {t[k]:.4g} s, "
                          f"below the task's coupling margin of {margin:g} (relative "
                          f"tolerance {MARGIN_RTOL:g})")
    return shortfall


def _proven(proof: MarginProof | None, margin: float | None, breaks: np.ndarray,
            violations: list[str]) -> MarginCertificate | None:
    """The margin's certificate on whole intervals (None without a proof: no margin, or
    no passive joints), its failure said in `violations`."""
    if proof is None:
        return None
    said = proof.violation(breaks)
    if said is not None and margin is not None:
        violations.append(said)
    return proof.certificate()


def _tracking(robot: Robot, interp: Interpolant, t: np.ndarray, T: float, task: Task,
              tol: float, violations: list[str]) -> float | None:
    """The largest departure [rad] of the passive angles from an exact prescribed motion at
    the samples t (None without one)."""
    tracking = task.tracking
    if tracking is None or tracking.mode != "exact":
        return None
    reference = tracking.motion.evaluate(t, T)[0]
    gap = np.abs(interp.q(t)[:, robot.passive] - reference)
    worst = float(gap.max(initial=0.0))
    if worst > tol:
        k, col = np.unravel_index(int(np.argmax(gap)), gap.shape)
        violations.append(f"the passive joint {robot.passive[col]} departs from the prescribed "
                          f"motion by {worst:.3g} rad at t = {t[k]:.4g} s (tolerance "
                          f"{tol:g} rad)")
    return worst
