"""Checks of a plan computed independently of its NLP.

- accuracy: every interval re-integrated from the plan's own state (planner.ocp.accuracy);
- open-loop re-simulation: the delivered torque (the transcription's own torque
  polynomial) fed to CVODES (rtol = atol = 1e-10) from the planned initial state over the
  whole horizon (planner.ocp.feedback.replay);
- the delivered torque against the task's torque limit and the planned angles and rates
  against its position and velocity bounds, on the dense samples and at every interior
  extremum of their polynomials (exact: roots of the derivative), within `LIMIT_RTOL`
  and `BOUND_TOL`;
- open-loop sensitivity, a time-varying LQR feedback along the plan and its closed-loop
  replay (planner.ocp.feedback);
- the dynamics defect of the interpolant, integral of |M ddq + h - B tau|_2 dt by
  5-point Gauss-Legendre quadrature per interval;
- sigma_min(M_pa) at the dense samples, with and without waves, and the configurations
  that are singular for the waveless robot (zeros of det in the square case,
  `planner.coupling_block.zeros_along`; near-zero minima of sigma_min otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from time import perf_counter

import casadi as ca
import numpy as np
from scipy.optimize import minimize_scalar

from planner import buffered, coupling_block
from planner.dynamics import functions
from planner.model import Robot, Structure, parameters
from planner.ocp.check_threads import pool
from planner.ocp.feedback import (
    PERTURBATION,
    Linearisation,
    gains,
    growth_factor,
    linearise,
    replay,
    torque_scale,
)
from planner.ocp.flow import inputs
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.margin_proof import MarginProof, prove
from planner.ocp.replays import Lane, planned_state, reference, replays
from planner.ocp.robustness import corners, report
from planner.ocp.task_checks import Requirements, requirements
from planner.ocp.transcription import Interpolant
from planner.ocp.verification import Crossing, Feedback, Robustness, Verification
from planner.scene import Bounds, SolverSettings, Task

RESIM_TOL = 1e-10
LIMIT_RTOL = 1e-6
"""A delivered torque keeps its limit L when |tau| <= L (1 + LIMIT_RTOL) (+ 1e-12 N m of
rounding, for L = 0) everywhere."""
BOUND_TOL = 1e-6
"""A planned angle or rate keeps its bound b when it is beyond it by at most
BOUND_TOL max(1, |b|) [rad, rad/s] anywhere."""
_GAUSS_S, _GAUSS_W = np.polynomial.legendre.leggauss(5)


def coupling_along(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The plan's sigma_min (K,) of M_pa, its smallest singular value (what the coupling
    margin bounds; NaN without passive joints), and det (K,) or None, at the
    configurations q (K, n)."""
    m = coupling_block.along(robot, q)
    return m.least, m.det


def open_loop(robot: Robot, interp: Interpolant, compiled: bool = False,
              deadline: float | None = None) -> tuple[float | None, str]:
    """The whole-horizon replay of the delivered torque from the planned initial state:
    max |q_sim - q_plan| [rad] and "completed", or None and where CVODES failed or, past
    `deadline`, where it stopped."""
    start = planned_state(interp, interp.q.breaks[0])
    return replay(robot, interp, start[None, :], None, RESIM_TOL, compiled,
                  deadline=deadline)[0]


def defect(robot: Robot, interp: Interpolant) -> float:
    """Integral of |M ddq + h - B tau|_2 [N m s] along the interpolant."""
    s = Structure.of(robot)
    breaks = interp.q.breaks
    h = np.diff(breaks)
    t = (breaks[:-1, None] + h[:, None] * (_GAUSS_S[None, :] + 1) / 2).ravel()
    ddq = interp.dq(t, derivative=1)
    (res,) = buffered.call(_residuals(s, len(t)), interp.q(t).T,
                           interp.dq(t).T, ddq.T, interp.tau(t).T, parameters(robot, s))
    norms = np.linalg.norm(res, axis=0).reshape(len(h), -1)
    return float(np.sum(norms * (_GAUSS_W[None, :] / 2) * h[:, None]))


@lru_cache(maxsize=64)
def _residuals(s: Structure, points: int) -> ca.Function:
    """The dynamics' residual M ddq + h - B tau mapped over `points` columns, p shared."""
    return functions(s)["residual"].map(points)


def singular_crossings(robot: Robot, interp: Interpolant, t: np.ndarray, own_sigma: np.ndarray,
                       own_det: np.ndarray | None) -> tuple[list[Crossing], np.ndarray]:
    """Configurations along the plan where the waveless M_pa is singular, and the waveless
    sigma_min at the times t (see `coupling_along`); own_sigma, own_det: the robot's own
    sigma_min and det at t, which are the waveless ones where it has no waves."""
    waveless = robot.without_waves()
    wavy = any(link.wave is not None for link in robot.links)
    sigma, det = coupling_along(waveless, interp.q(t)) if wavy else (own_sigma, own_det)
    if not np.all(np.isfinite(sigma)):
        return [], sigma
    times: list[float] = []
    zeros = coupling_block.zeros_along(waveless, interp.q, t, det=det) \
        if det is not None else None
    if zeros is not None:
        times += zeros.tolist()
    else:
        floor = 1e-3 * float(sigma.max())
        def sig_at(x: float) -> float:
            return coupling_along(waveless, interp.q(np.array([x])))[0][0]
        for k in range(1, len(t) - 1):
            if sigma[k] <= sigma[k - 1] and sigma[k] <= sigma[k + 1] and sigma[k] < floor:
                best = minimize_scalar(sig_at, bounds=(t[k - 1], t[k + 1]), method="bounded")
                times.append(float(best.x))
    crossings = []
    for time in sorted(times):
        q = interp.q(np.array([time]))
        crossings.append(Crossing(time=time, q=q[0].tolist(),
                                  sigma_min=float(coupling_along(waveless, q)[0][0])))
    return crossings, sigma


def _beyond(pp: PiecewisePolynomial, t: np.ndarray, lower: np.ndarray,
            upper: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per component (dim,): how far the piecewise polynomial goes below `lower` or above
    `upper` (0 within them; NaN bounds: none), the value where it goes furthest and its
    time [s]: on the samples t and at every interval's extrema (exact), whichever is
    further."""
    samples = pp(t)
    ext = pp.extrema()
    values = np.concatenate([samples, ext.low, ext.high])
    times = np.concatenate([np.repeat(t[:, None], samples.shape[1], axis=1), ext.t_low,
                            ext.t_high])
    over = np.fmax(np.nan_to_num(lower[None, :] - values, nan=-np.inf),
                   np.nan_to_num(values - upper[None, :], nan=-np.inf))
    where = over.argmax(axis=0)
    cols = np.arange(values.shape[1])
    return np.maximum(over[where, cols], 0.0), values[where, cols], times[where, cols]


def _limit_array(limit: list[float] | float | None, na: int) -> np.ndarray | None:
    """The torque limit (na,) [N m] of every active joint (None without one)."""
    return None if limit is None else np.broadcast_to(np.asarray(limit, float), (na,))


def _bound_array(values: list[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


@dataclass(frozen=True)
class Limits:
    """How far the plan goes beyond the task's limits ([N m], [rad], [rad/s]; None for a
    limit the task does not set) and, beyond the tolerances, each violation in words."""

    torque: float | None
    position: float | None
    velocity: float | None
    violations: list[str]


def limits(robot: Robot, interp: Interpolant, t: np.ndarray,
           torque_limit: list[float] | float | None, position: Bounds | None,
           velocity: Bounds | None) -> Limits:
    """The delivered torque against |tau| <= torque_limit (tolerance `LIMIT_RTOL`) and the
    planned angles and rates against the bounds (`BOUND_TOL`), each on the samples t [s] and
    at every interval's extrema."""
    violations: list[str] = []
    torque = None
    if torque_limit is not None:
        L = np.broadcast_to(np.asarray(torque_limit, float), (len(robot.active),))
        over, value, at = _beyond(interp.tau, t, -L, L)
        torque = float(over.max(initial=0.0))
        for col in np.flatnonzero(over > LIMIT_RTOL * L + 1e-12):
            share = f", {100 * over[col] / L[col]:.3g} % over" if L[col] > 0 else ""
            violations.append(
                f"the delivered torque at joint {robot.active[col]} reaches {value[col]:.6g} N m "
                f"at t = {at[col]:.4g} s, beyond its limit of {L[col]:g} N m by "
                f"{over[col]:.3g} N m{share} (tolerance {LIMIT_RTOL:g} relative)")
    found: dict[str, float | None] = {}
    for name, bounds, pp, quantity, unit in (("position", position, interp.q, "angle", "rad"),
                                             ("velocity", velocity, interp.dq, "rate", "rad/s")):
        if bounds is None:
            found[name] = None
            continue
        lower, upper = _bound_array(bounds.lower), _bound_array(bounds.upper)
        over, value, at = _beyond(pp, t, lower, upper)
        found[name] = float(over.max(initial=0.0))
        for j in range(len(over)):
            side, bound = ("lower", lower[j]) if value[j] < np.nan_to_num(lower[j], nan=-np.inf) \
                else ("upper", upper[j])
            if over[j] > BOUND_TOL * max(1.0, abs(bound)):
                violations.append(
                    f"the planned {quantity} of joint {j} reaches {value[j]:.6g} {unit} at "
                    f"t = {at[j]:.4g} s, beyond its {side} bound of {bound:g} {unit} by "
                    f"{over[j]:.3g} {unit} (tolerance {BOUND_TOL:g} x max(1, |bound|))")
    return Limits(torque, found["position"], found["velocity"], violations)


SKIPPED_REPLAYS = ("closed-loop replays: not run, the plan's wall-time budget "
                   "(solver.max_wall_time) had run out")


def _feedback(robot: Robot, interp: Interpolant, torque_limit: list[float] | float | None,
              compiled: bool) -> tuple[Feedback | None, Linearisation | None]:
    """The plan's LQR feedback (None where the linearisation or the Riccati recursion
    fails) and the linearisation it was made from (None where that failed)."""
    lin = linearise(robot, interp, compiled)
    if lin is None:
        return None, None
    return gains(lin, np.diff(interp.q.breaks), torque_scale(interp, torque_limit)), lin


def _replays(robot: Robot, interp: Interpolant, fb: Feedback | None, task: Task,
             settings: SolverSettings, deadline: float | None = None,
             ) -> tuple[tuple[float | None, str], dict, Robustness | None]:
    """The plan's replays over its whole horizon as the lanes of one stacked replay, which
    shares CVODES' start-up and steps on every interval (`planner.ocp.replays`, at
    RESIM_TOL): the delivered torque alone from the planned start (as `open_loop`: its
    largest error [rad] and status) and, with the feedback `fb`, the closed loop from there
    and from it perturbed (what `Verification` reports of them) and, with task.uncertainty,
    the corner models (`planner.ocp.robustness`; None without one or without feedback).
    Past the deadline (time.perf_counter() seconds) they stop: the open loop says where,
    the closed loop that it was skipped, and a corner model's replay counts as one that
    did not stay within the bound."""
    limit = _limit_array(task.torque_limit, len(robot.active))
    start = planned_state(interp, interp.q.breaks[0])
    free = inputs(robot, interp)[1]
    lanes, made = [Lane(start, free, None)], None
    if fb is not None:
        K = np.asarray(fb.gains)
        params = free if limit is None else inputs(robot, interp, limit)[1]
        lanes += [Lane(start, params, K), Lane(start + PERTURBATION, params, K)]
        if task.uncertainty is not None:
            made = corners(robot, interp, K, task.uncertainty, limit)
    skipped = deadline is not None and perf_counter() > deadline
    done = replays(Structure.of(robot), reference(interp),
                   lanes + ([] if made is None else made.lanes), RESIM_TOL, settings.jit,
                   deadline)
    closed = {} if fb is None else {"skipped": [SKIPPED_REPLAYS]} if skipped else {
        "closed_loop_error": done[1].error, "perturbed_closed_loop_error": done[2].error,
        "perturbation": PERTURBATION}
    robust = None if made is None else report(made, done[3:], settings.robustness, limit)
    return (done[0].error, done[0].status), closed, robust


def verify(robot: Robot, interp: Interpolant, t_dense: np.ndarray, errors: np.ndarray,
           errors_status: str, task: Task, settings: SolverSettings, converged: bool,
           deadline: float | None = None,
           proof: MarginProof | None = None) -> tuple[Verification, Feedback | None]:
    """All checks of a plan of `robot` whose interpolant is `interp` and whose interval
    errors [rad] are `errors`, against its `task` and `settings` (solver.resimulation_tolerance,
    robustness, jit), its open-loop replay among them (`_replays`; `open_loop` alone);
    verified when its solve `converged`, every interval error is at most the tolerance,
    the plan keeps the task's limits (`limits`) and meets its other requirements
    (`planner.ocp.task_checks`) everywhere and, with solver.robustness, when its feedback
    keeps the arm that close to the plan on every model of task.uncertainty
    (`planner.ocp.robustness`). The coupling
    margin's `proof` on whole intervals is made here unless the solve made it
    (`planner.ocp.margin_proof`). Also the plan's feedback (None where the linearisation
    failed). Past `deadline` (time.perf_counter() seconds), the closed-loop replays are
    skipped (`Verification.skipped`); a replay on a perturbed model stopped there counts
    as one that did not stay within the bound. Once the gains are known, the replays
    (`_replays`; CVODES, which lets go of Python's lock) run in a thread of their own
    (`planner.ocp.check_threads`) beside the other checks."""
    tolerance, compiled = settings.resimulation_tolerance, settings.jit
    fb, lin = _feedback(robot, interp, task.torque_limit, compiled)
    replaying = pool().submit(_replays, robot, interp, fb, task, settings, deadline)
    measured = {} if lin is None else {"growth_factor": growth_factor(lin)}
    kept = limits(robot, interp, t_dense, task.torque_limit, task.position_bounds,
                  task.velocity_bounds)
    sigma, det = coupling_along(robot, interp.q(t_dense))
    if proof is None:
        proof = prove(robot, interp, task.coupling_margin, deadline)
    asked = requirements(robot, interp, t_dense, task, sigma, proof, tolerance)
    crossings, waveless = singular_crossings(robot, interp, t_dense, sigma, det)
    flaw = defect(robot, interp)
    replayed, closed, robust = replaying.result()
    measured.update(closed)
    robust_ok = task.uncertainty is None or settings.robustness is None \
        or robust is not None and bool(robust.within)
    accurate = errors_status == "completed" and float(errors.max()) <= tolerance
    return Verification(
        **_intervals(errors, errors_status),
        verified=converged and accurate and not kept.violations and not asked.violations
        and robust_ok,
        converged=converged, tolerance=tolerance,
        resimulation_error=replayed[0], resimulation_status=replayed[1],
        defect=flaw, **_task(kept, asked), **_coupling(sigma, waveless, crossings),
        robustness=robust, **measured,
    ), fb


def _task(kept: Limits, asked: Requirements) -> dict:
    """The Verification's fields of the task's limits and other requirements."""
    return {"torque_excess": kept.torque, "position_excess": kept.position,
            "velocity_excess": kept.velocity, "limit_violations": kept.violations,
            "initial_error": asked.initial_error, "final_error": asked.final_error,
            "tip_error": asked.tip_error, "duration_excess": asked.duration_excess,
            "margin_shortfall": asked.margin_shortfall,
            "margin_certificate": asked.margin_certificate,
            "tracking_error": asked.tracking_error, "task_violations": asked.violations}


def _intervals(errors: np.ndarray, status: str) -> dict:
    """The Verification's fields of the interval errors (N,) [rad] and their status."""
    local = float(errors.max())
    return {"local_error": local if np.isfinite(local) else None,
            "interval_errors": [float(e) if np.isfinite(e) else None for e in errors],
            "local_status": status}


def _coupling(sigma: np.ndarray, waveless: np.ndarray, crossings: list[Crossing]) -> dict:
    """The Verification's fields of the coupling along the plan: sigma_min of M_pa (K,)
    [kg m^2] with the robot's waves and without, and the waveless singular crossings."""
    return {"min_sigma": _minimum(sigma), "waveless_min_sigma": _minimum(waveless),
            "waveless_singular_crossings": crossings, "sigma_min": _samples(sigma),
            "waveless_sigma_min": _samples(waveless)}


def _minimum(values: np.ndarray) -> float | None:
    """The smallest finite value, None without one."""
    finite = values[np.isfinite(values)]
    return float(finite.min()) if finite.size else None


def _samples(values: np.ndarray) -> list[float | None]:
    """Values as a list, None where not finite."""
    out = values.astype(object)
    out[~np.isfinite(values)] = None
    return out.tolist()
