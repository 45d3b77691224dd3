"""Replays of a plan's torque over its whole horizon, many at once.

A replay (a lane) starts from a state x0 (2n,) on a model of the robot (its parameters)
and simulates the plan's torque interval by interval with CVODES, `planner.ocp.flow`'s
flow of one interval: on interval k, with gains K_k (na, 2n), the feedback adds the
offset u_k = -K_k (x(t_k) - x_plan(t_k)), held over the interval; without gains, the
torque alone. It is compared with the plan at REPLAY_SAMPLES points per interval.

Every lane of a call runs in one CasADi call per CHUNK intervals, so that Python steps
in between only to watch the deadline: on each interval, the lanes' states are stacked
into one ODE that one CVODES run integrates (`planner.ocp.flow.stepper`, at the tolerance
divided by the square root of the lanes, which holds each lane within its own: one run's
start-up and steps serve every lane), accumulated over the intervals. Where a chunk
fails (CVODES stops, or a state is not finite), it and the rest of the horizon are
replayed lane by lane and interval by interval, by Adams and by BDF where Adams fails, as
each replay stands on its own: one that diverges leaves the others whole, and says where
it failed.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from time import perf_counter

import casadi as ca
import numpy as np

from planner.model import Structure
from planner.ocp.flow import Flow, flow, quiet, ready, stepper
from planner.ocp.transcription import Interpolant

REPLAY_SAMPLES = 4  # comparison points per interval
CHUNK = 25
"""Intervals one call replays for every lane; the deadline is watched between calls (as
the interval check's, `planner.ocp.accuracy.CHUNK`). Ten took a tenth longer on the
suite's plans: each call converts its inputs and outputs."""


@dataclass(frozen=True)
class Reference:
    """What the replays follow: the breaks (N + 1,) [s], the plan's state at every break
    planned (N + 1, 2n), its angles at each interval's comparison points q_plan
    (N, REPLAY_SAMPLES, n), its torques at the interval's start and comparison points
    tau_plan (N, REPLAY_SAMPLES + 1, na) and the degree of its torque polynomials."""

    breaks: np.ndarray
    planned: np.ndarray
    q_plan: np.ndarray
    tau_plan: np.ndarray
    degree: int


def planned_state(interp: Interpolant, at: float) -> np.ndarray:
    """The plan's state (q, dq) (2n,) at the time `at` [s]."""
    t = np.array([at], dtype=float)
    return np.concatenate([interp.q(t)[0], interp.dq(t)[0]])


def reference(interp: Interpolant) -> Reference:
    """What replays of the plan `interp` follow."""
    breaks = interp.q.breaks
    N = len(breaks) - 1
    fractions = np.arange(0, REPLAY_SAMPLES + 1) / REPLAY_SAMPLES
    t = (breaks[:-1, None] + np.diff(breaks)[:, None] * fractions[None, :]).ravel()
    return Reference(breaks, np.hstack([interp.q(breaks), interp.dq(breaks)]),
                     interp.q(t).reshape(N, REPLAY_SAMPLES + 1, -1)[:, 1:],
                     interp.tau(t).reshape(N, REPLAY_SAMPLES + 1, -1),
                     interp.tau.coeffs.shape[1] - 1)


@dataclass(frozen=True)
class Lane:
    """One replay: its start x0 (2n,), the integrator's parameters of every interval
    params (n_p, N) (its model's, `planner.ocp.flow.inputs`) and the gains K (N, na, 2n)
    (None: the torque alone)."""

    x0: np.ndarray
    params: np.ndarray
    K: np.ndarray | None


@dataclass(frozen=True)
class Replayed:
    """A replay's largest |q_sim - q_plan| [rad] at the comparison points and "completed",
    or None and where it failed or stopped; its final state (2n,) (None unless
    completed) and the largest torque the plan and its feedback commanded [N m] (at each
    interval's start and comparison points, before any saturation)."""

    error: float | None
    status: str
    end: np.ndarray | None
    peak: float


def replays(s: Structure, ref: Reference, lanes: list[Lane], tol: float,
            compiled: bool = False, deadline: float | None = None) -> list[Replayed]:
    """Every lane replayed along `ref` (CVODES rtol = atol = tol; compiled: the dynamics
    compiled to C), CHUNK intervals at a time; past `deadline` (time.perf_counter()
    seconds) the lanes stop at the next chunk (None, and where they stopped)."""
    N, degree = len(ref.breaks) - 1, ref.degree
    compiled = ready(s, degree, compiled)
    x = np.stack([lane.x0 for lane in lanes], axis=1).astype(float)
    worst, peak = np.zeros(len(lanes)), np.zeros(len(lanes))
    for first in range(0, N, CHUNK):
        if deadline is not None and perf_counter() > deadline:
            return [_stopped(ref, first, p) for p in peak]
        last = min(first + CHUNK, N)
        states = _chunk(s, degree, last - first, len(lanes), tol, compiled, lanes, x,
                        first, ref)
        if states is None:  # the rest lane by lane, interval by interval
            one = flow(s, degree, REPLAY_SAMPLES, 1, tol, compiled)
            return [_one_lane(one, ref, lane, x[:, i], first, worst[i], peak[i], deadline)
                    for i, lane in enumerate(lanes)]
        starts = np.concatenate([x.T[:, None, :], states[:, :-1, -1, :]], axis=1)
        peak = np.maximum(peak, _commanded(ref, lanes, starts, first))
        q_sim = states[:, :, :, :s.n]  # (lanes, intervals, samples, n)
        worst = np.maximum(worst, np.abs(q_sim - ref.q_plan[first:last]).max(axis=(1, 2, 3)))
        x = states[:, -1, -1, :].T
    return [Replayed(float(w), "completed", x[:, i].copy(), float(p))
            for i, (w, p) in enumerate(zip(worst, peak, strict=True))]


def _chunk(s: Structure, degree: int, intervals: int, count: int, tol: float,
           compiled: bool, lanes: list[Lane], x: np.ndarray, first: int,
           ref: Reference) -> np.ndarray | None:
    """The states (lanes, intervals, REPLAY_SAMPLES, 2n) of every lane over the intervals
    from `first`, each lane from its state in x (2n, lanes); None where CVODES failed or
    a state is not finite."""
    cols = slice(first, first + intervals)
    n2, na = 2 * s.n, len(s.active_idx)
    params = np.stack([lane.params[:, cols] for lane in lanes], axis=2)  # (n_p, k, lane)
    gains = np.stack([np.zeros((intervals, na, n2)) if lane.K is None else lane.K[cols]
                      for lane in lanes], axis=1)  # (k, lane, na, 2n)
    run, step = _mapped(s, degree, intervals, count, tol, compiled)
    try:
        out = quiet(run, runs=step, x0=x, p=params.reshape(params.shape[0], -1),
                    planned=ref.planned[cols].T, K=gains.transpose(2, 0, 1, 3).reshape(na, -1))
    except RuntimeError:
        return None
    states = out.T.reshape(intervals, count, REPLAY_SAMPLES, n2).transpose(1, 0, 2, 3)
    return states if np.all(np.isfinite(states)) else None


def _commanded(ref: Reference, lanes: list[Lane], starts: np.ndarray,
               first: int) -> np.ndarray:
    """The largest torque (lanes,) [N m] each lane commands on the intervals from `first`
    whose start states are `starts` (lanes, intervals, 2n)."""
    count = starts.shape[1]
    tau = ref.tau_plan[first:first + count]  # (intervals, samples + 1, na)
    out = []
    for lane, x in zip(lanes, starts, strict=True):
        u = np.zeros((count, tau.shape[2])) if lane.K is None else np.einsum(
            "kij,kj->ki", -lane.K[first:first + count], x - ref.planned[first:first + count])
        out.append(float(np.abs(tau + u[:, None, :]).max(initial=0.0)))
    return np.asarray(out)


@lru_cache(maxsize=64)
def _mapped(s: Structure, degree: int, intervals: int, count: int, tol: float,
            compiled: bool) -> tuple[ca.Function, ca.Function]:
    """(x0 (2n x count), p (n_p x intervals count), planned (2n x intervals),
    K (na x 2n count intervals)) -> xf (2n x REPLAY_SAMPLES count intervals), the columns
    of p, K and xf interval by interval and lane by lane within it: `count` lanes over
    `intervals` intervals, each with its feedback, all lanes of an interval in one CVODES
    run by Adams (`planner.ocp.flow.stepper`: the lanes stacked into one ODE); and that
    integrator, whose lock its calls hold (`planner.ocp.flow.quiet`)."""
    step = stepper(s, degree, REPLAY_SAMPLES, count, tol, compiled, "adams")
    n2, na = 2 * s.n, len(s.active_idx)
    x, planned = ca.MX.sym("x", n2, count), ca.MX.sym("planned", n2)
    p, K = ca.MX.sym("p", step.size1_in("p"), count), ca.MX.sym("K", na, n2 * count)
    offsets = [ca.repmat(-ca.mtimes(K[:, b * n2:(b + 1) * n2], x[:, b] - planned),
                         1, REPLAY_SAMPLES) for b in range(count)]
    xf = step(x0=x, p=p, u=ca.horzcat(*offsets))["xf"]
    ends = xf[:, [(b + 1) * REPLAY_SAMPLES - 1 for b in range(count)]]
    along = ca.Function("replay_interval", [x, p, planned, K], [ends, xf]).mapaccum(
        "replay_intervals", intervals)
    x0, ps = ca.MX.sym("x0", n2, count), ca.MX.sym("p", p.size1(), count * intervals)
    plans, gains = ca.MX.sym("planned", n2, intervals), ca.MX.sym("K", na, n2 * count * intervals)
    return ca.Function("replay_lanes", [x0, ps, plans, gains],
                       [along(x0, ps, plans, gains)[1]], ["x0", "p", "planned", "K"],
                       ["xf"]), step


def _one_lane(integrate: Flow, ref: Reference, lane: Lane, x: np.ndarray, first: int,
              worst: float, peak: float, deadline: float | None) -> Replayed:
    """One lane from the state x (2n,) at interval `first` on, interval by interval (its
    error and peak so far: `worst`, `peak`), stopped past `deadline`."""
    n = x.size // 2
    for k in range(first, len(ref.breaks) - 1):
        if deadline is not None and perf_counter() > deadline:
            return _stopped(ref, k, peak)
        u = np.zeros(ref.tau_plan.shape[2]) if lane.K is None \
            else -lane.K[k] @ (x - ref.planned[k])
        peak = max(peak, float(np.abs(ref.tau_plan[k] + u[None, :]).max(initial=0.0)))
        where = f"between t = {ref.breaks[k]:.6g} s and t = {ref.breaks[k + 1]:.6g} s"
        try:
            states = integrate(x[:, None], lane.params[:, k:k + 1],
                               np.repeat(u[:, None], REPLAY_SAMPLES, axis=1))
        except RuntimeError:
            return Replayed(None, f"CVODES failed {where}", None, peak)
        if not np.all(np.isfinite(states)):
            return Replayed(None, f"the state became non-finite {where}", None, peak)
        worst = max(worst, float(np.abs(states[:n].T - ref.q_plan[k]).max()))
        x = states[:, -1]
    return Replayed(worst, "completed", x, peak)


def _stopped(ref: Reference, k: int, peak: float) -> Replayed:
    """A replay stopped at interval k: the plan's wall-time budget ran out."""
    return Replayed(None, f"stopped at t = {ref.breaks[k]:.6g} s: the plan's wall-time "
                          "budget (solver.max_wall_time) ran out", None, float(peak))
