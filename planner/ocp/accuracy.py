"""Accuracy of a plan, interval by interval: does the delivered torque move the robot along
the plan?

Every interval is re-integrated by CVODES from the plan's own state at its start, with the
plan's torque polynomial, and compared with the plan at `SAMPLES` points across it. The
interval's error is the largest max(|q_sim - q_plan|, h |dq_sim - dq_plan|) there [rad]
(h the interval's length: a rate error counts as the angle it adds over one more such
interval). Starting every interval from the plan's state separates the transcription's
error, which mesh refinement drives down, from the growth of errors along an unstable
motion, which no transcription removes (see `planner.ocp.sensitivity`).
"""

from __future__ import annotations

import numpy as np

from planner.model import Robot, Structure, parameters
from planner.ocp.transcription import Interpolant
from planner.simulate import _integrator

SAMPLES = 4  # comparison points per interval, at s = 1/4, 1/2, 3/4, 1
TOL = 1e-10  # CVODES rtol = atol


def _inputs(robot: Robot, interp: Interpolant) -> tuple[np.ndarray, np.ndarray]:
    """Start states (2n x N) and CVODES parameters (robot, torque coefficients, h per interval)."""
    breaks = interp.q.breaks
    starts = np.hstack([interp.q(breaks[:-1]), interp.dq(breaks[:-1])]).T
    coeffs = interp.tau.coeffs  # (N, m, na)
    N = coeffs.shape[0]
    p = parameters(robot, Structure.of(robot))
    params = np.vstack([np.repeat(p[:, None], N, axis=1),
                        coeffs.reshape(N, -1).T, np.diff(breaks)[None, :]])
    return starts, params


def interval_errors(robot: Robot, interp: Interpolant) -> tuple[np.ndarray, str]:
    """(N,) error of every interval [rad] (inf where CVODES failed) and a status: "completed"
    or what failed where."""
    s = Structure.of(robot)
    coeffs = interp.tau.coeffs
    N, degree = coeffs.shape[0], coeffs.shape[1] - 1
    sim = _integrator(s, degree, SAMPLES, TOL, TOL, "adams")
    starts, params = _inputs(robot, interp)
    try:
        ends = np.array(sim.map(N)(x0=starts, p=params)["xf"])  # 2n x (SAMPLES N)
        status = "completed"
    except RuntimeError:
        ends, status = _one_by_one(sim, starts, params, s.n)
    breaks = interp.q.breaks
    h = np.diff(breaks)
    t = (breaks[:-1, None] + h[:, None] * np.arange(1, SAMPLES + 1)[None, :] / SAMPLES).ravel()
    dq_scale = np.repeat(h, SAMPLES)[:, None]
    q_err = np.abs(ends[:s.n].T - interp.q(t))
    dq_err = np.abs(ends[s.n:].T - interp.dq(t)) * dq_scale
    worst = np.maximum(q_err.max(axis=1), dq_err.max(axis=1)).reshape(N, SAMPLES).max(axis=1)
    return np.where(np.isfinite(worst), worst, np.inf), status


def _one_by_one(sim, starts: np.ndarray, params: np.ndarray, n: int) -> tuple[np.ndarray, str]:
    """Each interval on its own, so that one that CVODES cannot integrate marks only itself."""
    N = starts.shape[1]
    ends = np.full((2 * n, SAMPLES * N), np.nan)
    failed = []
    for k in range(N):
        try:
            ends[:, k * SAMPLES:(k + 1) * SAMPLES] = np.array(sim(x0=starts[:, k], p=params[:, k])["xf"])
        except RuntimeError:
            failed.append(k)
    return ends, f"CVODES failed on {len(failed)} interval(s), the first is interval {failed[0]}"
