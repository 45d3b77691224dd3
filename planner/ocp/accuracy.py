"""Accuracy of a plan, interval by interval: does the delivered torque move the robot along
the plan?

Every interval is re-integrated by CVODES (rtol = atol = 1e-10, `planner.ocp.flow`) from
the plan's own state at its start, with the plan's torque polynomial, and compared with
the plan at `SAMPLES` points across it. The interval's error is the largest
max(|q_sim - q_plan|, h |dq_sim - dq_plan|) there [rad] (h the interval's length: a rate
error counts as the angle it adds over one more such interval). Starting every interval
from the plan's state separates the transcription's error, which mesh refinement drives
down, from the growth of errors along an unstable motion, which no transcription removes
(`planner.ocp.feedback`).
"""

from __future__ import annotations

from time import perf_counter

import numpy as np

from planner.model import Robot, Structure
from planner.ocp.flow import flow, inputs
from planner.ocp.transcription import Interpolant

SAMPLES = 4  # comparison points per interval, at s = 1/4, 1/2, 3/4, 1


CHUNK = 25
"""Intervals integrated per CVODES call (stacked, `planner.ocp.flow`); a deadline is
watched between calls. The same with a deadline or without, so that a plan's errors do
not depend on whether it had one."""


def interval_errors(robot: Robot, interp: Interpolant, compiled: bool = False,
                    deadline: float | None = None) -> tuple[np.ndarray, str]:
    """(N,) error of every interval [rad] (inf where CVODES failed) and a status: "completed"
    or on which intervals CVODES failed. compiled: the dynamics compiled to C. CHUNK
    intervals at a time; with a `deadline` (time.perf_counter() seconds), the intervals
    left when it has passed are not integrated (inf; the status says where it stopped):
    on a far-from-converged iterate CVODES can take seconds."""
    s = Structure.of(robot)
    coeffs = interp.tau.coeffs
    N, degree = coeffs.shape[0], coeffs.shape[1] - 1
    starts, params = inputs(robot, interp)
    ends = np.full((2 * s.n, SAMPLES * N), np.nan)
    statuses = []
    for first in range(0, N, CHUNK):
        if deadline is not None and perf_counter() > deadline:
            statuses.append(f"stopped at interval {first} of {N}: the plan's wall-time "
                            "budget (solver.max_wall_time) ran out")
            break
        last = min(first + CHUNK, N)
        cols = slice(first * SAMPLES, last * SAMPLES)
        zero = np.zeros((len(s.active_idx), SAMPLES * (last - first)))
        try:
            ends[:, cols] = flow(s, degree, SAMPLES, last - first, compiled=compiled)(
                starts[:, first:last], params[:, first:last], zero)
        except RuntimeError:
            part, status = _one_by_one(s, degree, starts[:, first:last],
                                       params[:, first:last], compiled)
            ends[:, cols] = part
            statuses.append(f"from interval {first}: {status}")
    return _errors(s, interp, ends), "; ".join(statuses) or "completed"


def _errors(s: Structure, interp: Interpolant, ends: np.ndarray) -> np.ndarray:
    """Every interval's error from the integrated states at its SAMPLES points."""
    N = interp.tau.coeffs.shape[0]
    breaks = interp.q.breaks
    h = np.diff(breaks)
    t = (breaks[:-1, None] + h[:, None] * np.arange(1, SAMPLES + 1)[None, :] / SAMPLES).ravel()
    q_err = np.abs(ends[:s.n].T - interp.q(t))
    dq_err = np.abs(ends[s.n:].T - interp.dq(t)) * np.repeat(h, SAMPLES)[:, None]
    worst = np.maximum(q_err.max(axis=1), dq_err.max(axis=1)).reshape(N, SAMPLES).max(axis=1)
    return np.where(np.isfinite(worst), worst, np.inf)


def _one_by_one(s: Structure, degree: int, starts: np.ndarray, params: np.ndarray,
                compiled: bool) -> tuple[np.ndarray, str]:
    """Each interval on its own, so that one that CVODES cannot integrate marks only itself."""
    N = starts.shape[1]
    ends = np.full((2 * s.n, SAMPLES * N), np.nan)
    zero = np.zeros((len(s.active_idx), SAMPLES))
    one = flow(s, degree, SAMPLES, 1, compiled=compiled)
    failed = []
    for k in range(N):
        try:
            ends[:, k * SAMPLES:(k + 1) * SAMPLES] = one(starts[:, k:k + 1],
                                                         params[:, k:k + 1], zero)
        except RuntimeError:
            failed.append(k)
    return ends, f"CVODES failed on {len(failed)} interval(s), the first is interval {failed[0]}"
