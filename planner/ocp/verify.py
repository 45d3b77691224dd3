"""Checks of a plan computed independently of its NLP.

- accuracy: every interval re-integrated from the plan's own state (planner.ocp.accuracy);
- open-loop re-simulation: the delivered torque (the transcription's own torque
  polynomial) fed to CVODES (rtol = atol = 1e-10) from the planned initial state over the
  whole horizon (planner.ocp.feedback.replay);
- the delivered torque against the task's torque limit, on the dense samples;
- open-loop sensitivity, a time-varying LQR feedback along the plan and its closed-loop
  replay (planner.ocp.feedback);
- the dynamics defect of the interpolant, integral of |M ddq + h - B tau|_2 dt by
  5-point Gauss-Legendre quadrature per interval;
- sigma_min(M_pa) at the dense samples, with and without waves, and the configurations
  that are singular for the waveless robot (zeros of det in the square case,
  `planner.coupling_block.zeros_along`; near-zero minima of sigma_min otherwise).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from planner import coupling_block
from planner.dynamics import functions
from planner.model import Robot, Structure, parameters
from planner.ocp.feedback import PERTURBATION, gains, growth_factor, linearise, replay
from planner.ocp.result import Crossing, Feedback, Verification
from planner.ocp.transcription import Interpolant

RESIM_TOL = 1e-10
_GAUSS_S, _GAUSS_W = np.polynomial.legendre.leggauss(5)


def coupling_along(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The plan's sigma_min (K,) of M_pa, its smallest singular value (what the coupling
    margin bounds; NaN without passive joints), and det (K,) or None, at the
    configurations q (K, n)."""
    m = coupling_block.along(robot, q)
    return m.least, m.det


def open_loop(robot: Robot, interp: Interpolant,
              compiled: bool = False) -> tuple[float | None, str]:
    """The whole-horizon replay of the delivered torque from the planned initial state:
    max |q_sim - q_plan| [rad] and "completed", or None and where CVODES failed."""
    breaks = interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    return replay(robot, interp, start[None, :], None, RESIM_TOL, compiled)[0]


def defect(robot: Robot, interp: Interpolant) -> float:
    """Integral of |M ddq + h - B tau|_2 [N m s] along the interpolant."""
    s = Structure.of(robot)
    breaks = interp.q.breaks
    h = np.diff(breaks)
    t = (breaks[:-1, None] + h[:, None] * (_GAUSS_S[None, :] + 1) / 2).ravel()
    ddq = interp.dq(t, derivative=1)
    res = functions(s)["residual"].map(len(t))(interp.q(t).T, interp.dq(t).T, ddq.T,
                                               interp.tau(t).T, parameters(robot, s))
    norms = np.linalg.norm(np.array(res), axis=0).reshape(len(h), -1)
    return float(np.sum(norms * (_GAUSS_W[None, :] / 2) * h[:, None]))


def singular_crossings(robot: Robot, interp: Interpolant,
                       t: np.ndarray) -> tuple[list[Crossing], np.ndarray]:
    """Configurations along the plan where the waveless M_pa is singular, and the waveless
    sigma_min at the times t (see `coupling_along`)."""
    waveless = robot.without_waves()
    sigma, det = coupling_along(waveless, interp.q(t))
    if not np.all(np.isfinite(sigma)):
        return [], sigma
    times: list[float] = []
    zeros = coupling_block.zeros_along(waveless, interp.q, t) if det is not None else None
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


def torque_excess(tau: np.ndarray, limit: list[float] | float | None) -> float | None:
    """How far torques (K, n_active) [N m] exceed |tau| <= limit (0 within it; None: no limit)."""
    if limit is None:
        return None
    bound = np.broadcast_to(np.asarray(limit, float), (tau.shape[1],))
    return float(np.maximum(np.abs(tau) - bound[None, :], 0.0).max(initial=0.0))


def _feedback(robot: Robot, interp: Interpolant, torque_limit: list[float] | float | None,
              compiled: bool) -> tuple[Feedback | None, dict]:
    """The plan's LQR feedback and what it and the open-loop sensitivity measure."""
    lin = linearise(robot, interp, compiled)
    if lin is None:
        return None, {}
    scale = max(float(np.max(torque_limit)) if torque_limit is not None
                else float(np.abs(interp.tau.coeffs[:, 0]).max(initial=0.0)), 1.0)
    growth = growth_factor(lin)
    fb = gains(lin, np.diff(interp.q.breaks), scale)
    if fb is None:
        return None, {"growth_factor": growth}
    K = np.asarray(fb.gains)
    breaks = interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    (closed, _), (perturbed, _) = replay(robot, interp,
                                         np.stack([start, start + PERTURBATION]), K,
                                         compiled=compiled)
    return fb, {"growth_factor": growth, "closed_loop_error": closed,
                "perturbed_closed_loop_error": perturbed, "perturbation": PERTURBATION}


def verify(robot: Robot, interp: Interpolant, t_dense: np.ndarray, errors: np.ndarray,
           errors_status: str, replayed: tuple[float | None, str], tolerance: float,
           torque_limit: list[float] | float | None,
           compiled: bool = False) -> tuple[Verification, Feedback | None]:
    """All checks of a plan of `robot` whose interpolant is `interp`, whose interval errors
    [rad] are `errors` and whose open-loop replay gave `replayed`; verified when every
    interval error is at most `tolerance` [rad]. Also the plan's feedback (None where the
    linearisation failed)."""
    error, status = replayed
    sigma, _ = coupling_along(robot, interp.q(t_dense))
    crossings, waveless = singular_crossings(robot, interp, t_dense)
    local = float(errors.max())
    fb, measured = _feedback(robot, interp, torque_limit, compiled)
    return Verification(
        local_error=local if np.isfinite(local) else None,
        interval_errors=[float(e) if np.isfinite(e) else None for e in errors],
        local_status=errors_status,
        verified=errors_status == "completed" and local <= tolerance,
        tolerance=tolerance,
        resimulation_error=error,
        resimulation_status=status,
        defect=defect(robot, interp),
        torque_excess=torque_excess(interp.tau(t_dense), torque_limit),
        min_sigma=_minimum(sigma),
        waveless_min_sigma=_minimum(waveless),
        waveless_singular_crossings=crossings,
        sigma_min=_samples(sigma),
        waveless_sigma_min=_samples(waveless),
        **measured,
    ), fb


def _minimum(values: np.ndarray) -> float | None:
    """The smallest finite value, None without one."""
    finite = values[np.isfinite(values)]
    return float(finite.min()) if finite.size else None


def _samples(values: np.ndarray) -> list[float | None]:
    """Values as a list, None where not finite."""
    return [float(v) if np.isfinite(v) else None for v in values]


def unverified_reason(v: Verification) -> str | None:
    """Why a plan failed its accuracy check; None when it passed (or predates the check)."""
    if v.verified is not False:
        return None
    if v.local_error is None:
        return f"the plan's intervals could not all be re-integrated ({v.local_status})"
    return (f"re-integrated interval by interval, the delivered torque departs from the plan "
            f"by {v.local_error:.3g} rad (tolerance {v.tolerance:g} rad): the mesh refinement "
            f"ran out of budget; raise transcription.refinement's max_intervals or max_passes, "
            f"or solver.max_iter and max_wall_time")
