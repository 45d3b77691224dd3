"""Checks of a plan computed independently of its NLP.

- re-simulation: the planned torque, interpolated exactly as the transcription assumes,
  fed to CVODES (rtol = atol = 1e-10) from the planned initial state;
- the dynamics defect of the interpolant, integral of |M ddq + h - B tau|_2 dt by
  5-point Gauss-Legendre quadrature per interval;
- sigma_min(M_pa) along the plan, with and without waves, and the configurations that are
  singular for the waveless robot (sign changes of det refined by root finding in the
  square case, near-zero minima of sigma_min otherwise).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from planner.dynamics import functions
from planner.model import Robot, Structure, parameters
from planner.ocp.result import Crossing, Verification
from planner.ocp.transcription import Interpolant
from planner.simulate import simulate

RESIM_TOL = 1e-10
_GAUSS_S, _GAUSS_W = np.polynomial.legendre.leggauss(5)


def coupling_along(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """sigma_min (K,) and det (K,) or None of M_pa at the configurations q (K, n)."""
    s = Structure.of(robot)
    blocks = np.array(functions(s)["Mpa"].map(len(q))(q.T, parameters(robot, s)))
    rows, cols = len(s.passive_idx), len(s.active_idx)
    if rows == 0:
        return np.full(len(q), np.inf), None
    mpa = blocks.reshape(rows, len(q), cols).transpose(1, 0, 2)
    sv = np.linalg.svd(mpa, compute_uv=False)[:, -1]
    return sv, (np.linalg.det(mpa) if rows == cols else None)


def resimulation_error(robot: Robot, interp: Interpolant, samples: int) -> tuple[float | None, str]:
    """max |q_sim - q_plan| [rad] over breakpoints and `samples` points per interval."""
    breaks = interp.q.breaks
    x0 = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    sim = simulate(robot, breaks, interp.tau.coeffs, x0, samples, RESIM_TOL, RESIM_TOL)
    if sim.status != "completed":
        return None, sim.message
    t = np.asarray(sim.t)
    return float(np.abs(np.asarray(sim.q) - interp.q(t)).max()), "completed"


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


def singular_crossings(robot: Robot, interp: Interpolant, t: np.ndarray) -> tuple[list[Crossing], float | None]:
    """Configurations along the plan where the waveless M_pa is singular, and its min sigma."""
    waveless = robot.without_waves()
    sigma, det = coupling_along(waveless, interp.q(t))
    if not np.all(np.isfinite(sigma)):
        return [], None
    times: list[float] = []
    if det is not None:
        det_at = lambda x: coupling_along(waveless, interp.q(np.array([x])))[1][0]
        for k in np.flatnonzero(np.sign(det[:-1]) * np.sign(det[1:]) < 0):
            times.append(brentq(det_at, t[k], t[k + 1], xtol=1e-12))
        times += [float(t[k]) for k in np.flatnonzero(det == 0.0)]
    else:
        floor = 1e-3 * float(sigma.max())
        sig_at = lambda x: coupling_along(waveless, interp.q(np.array([x])))[0][0]
        for k in range(1, len(t) - 1):
            if sigma[k] <= sigma[k - 1] and sigma[k] <= sigma[k + 1] and sigma[k] < floor:
                best = minimize_scalar(sig_at, bounds=(t[k - 1], t[k + 1]), method="bounded")
                times.append(float(best.x))
    crossings = []
    for time in sorted(times):
        q = interp.q(np.array([time]))
        crossings.append(Crossing(time=time, q=q[0].tolist(),
                                  sigma_min=float(coupling_along(waveless, q)[0][0])))
    return crossings, float(sigma.min())


def verify(robot: Robot, interp: Interpolant, t_dense: np.ndarray, samples: int,
           tolerance: float) -> Verification:
    """All checks of a plan of `robot` whose interpolant is `interp`; verified when the
    re-simulation error is at most `tolerance` [rad]."""
    error, status = resimulation_error(robot, interp, samples)
    sigma, _ = coupling_along(robot, interp.q(t_dense))
    crossings, waveless_min = singular_crossings(robot, interp, t_dense)
    finite = np.isfinite(sigma)
    return Verification(
        resimulation_error=error,
        resimulation_status=status,
        verified=error is not None and error <= tolerance,
        tolerance=tolerance,
        defect=defect(robot, interp),
        min_sigma=float(sigma[finite].min()) if finite.any() else None,
        waveless_min_sigma=waveless_min,
        waveless_singular_crossings=crossings,
    )


def unverified_reason(v: Verification) -> str | None:
    """Why a plan failed its re-simulation check; None when it passed (or predates the check)."""
    if v.verified is not False:
        return None
    if v.resimulation_error is None:
        return f"the re-simulation did not complete ({v.resimulation_status})"
    return (f"the planned torque departs from the plan by {v.resimulation_error:.3g} rad in "
            f"re-simulation (tolerance {v.tolerance:g} rad): refine the grid")
