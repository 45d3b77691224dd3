"""Open-loop sensitivity of a plan and a time-varying LQR feedback along it.

Along many optimal motions of underactuated arms the dynamics are strongly unstable: a
replay of the whole horizon from the start departs from the plan however exact the
transcription. Linearised along the plan (the variational equations of the dynamics,
integrated by RK4 with SUBSTEPS steps per interval along the plan's own states and
torques), x_{k+1} = A_k x_k + B_k u_k with u_k a torque offset held over interval k:

- the growth factor is max_k ||A_{k-1} ... A_0||_2, how much an error of the initial
  state grows at most along the plan;
- the feedback is the discrete LQR of that linearisation with state weights 1/Q_SCALE^2
  (angles) and 1/DQ_SCALE^2 (rates) and torque weights 1/tau_scale^2 (tau_scale the torque
  limit, else the plan's largest torque, at least 1 N m), each times the interval's length
  h_k; the correction -K_k (x(t_k) - x_plan(t_k)) is held over interval k;
- a replay simulates the plan's torque (and the feedback, when given) interval by
  interval with CVODES from a start state, many at once (`planner.ocp.replays`); the
  open-loop replay from the planned initial state (rtol = atol = 1e-10, as
  planner.simulate.run by default) is the plan's resimulation_error; the closed-loop ones
  start there and at a state perturbed by PERTURBATION on every angle and rate (a plan's
  verification replays them with the open loop, at its tolerance, `planner.ocp.verify`;
  `replay` alone at REPLAY_TOL by default).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from planner import buffered
from planner.compiled import library, source_digest
from planner.dynamics import functions
from planner.model import Robot, Structure, parameters
from planner.ocp.flow import inputs
from planner.ocp.replays import Lane, reference, replays
from planner.ocp.transcription import Interpolant
from planner.ocp.verification import Feedback

Q_SCALE = 0.01  # [rad] angle error worth one unit of LQR cost
DQ_SCALE = 0.1  # [rad/s] rate error worth one unit
PERTURBATION = 1e-3  # [rad, rad/s] added to every initial angle and rate
REPLAY_TOL = 1e-8  # CVODES rtol = atol of the closed-loop replays
SUBSTEPS = 4  # RK4 steps per interval of the variational equations
_SOURCES = [Path(__file__).resolve().parents[1] / name
            for name in ("dynamics.py", "model.py", "ocp/feedback.py")]


@dataclass(frozen=True)
class Linearisation:
    """A_k (N, 2n, 2n) and B_k (N, 2n, na) along a plan; None where CVODES failed."""

    A: np.ndarray
    B: np.ndarray


@lru_cache(maxsize=64)
def _jacobians(s: Structure) -> ca.Function:
    """(x, tau, p) -> (df/dx (2n x 2n), df/dtau (2n x na)) of the first-order dynamics,
    dense (read in place, `planner.buffered`)."""
    ode = functions(s)["ode_ldl"]
    x, tau, p = ode.sx_in()
    dx = ode(x, tau, p)
    return ca.Function("jacobians", [x, tau, p], [ca.densify(ca.jacobian(dx, x)),
                                                  ca.densify(ca.jacobian(dx, tau))])


@lru_cache(maxsize=64)
def _library_name(s: Structure) -> str:
    return f"jacobians_{source_digest(repr(s), sources=_SOURCES)}"


def _compiled_jacobians(s: Structure) -> ca.Function | None:
    """`_jacobians` compiled (`planner.compiled`) once it is on disk; None while it is
    built in the background."""
    loaded = library(_library_name(s), (_jacobians(s),), background=True)
    return None if loaded is None else loaded["jacobians"]


@lru_cache(maxsize=64)
def _mapped(s: Structure, points: int, compiled: bool) -> ca.Function:
    """`_jacobians` (compiled where `compiled`, which `linearise` asks only once it is
    loaded) mapped over `points` columns of (x, tau), p shared."""
    one = _compiled_jacobians(s) if compiled else None
    return (_jacobians(s) if one is None else one).map(points)


def linearise(robot: Robot, interp: Interpolant, compiled: bool = False) -> Linearisation | None:
    """The plan's interval-by-interval linearisation (None where it is not finite;
    compiled: the Jacobians compiled to C)."""
    s = Structure.of(robot)
    breaks = interp.q.breaks
    h = np.diff(breaks)
    N, n2, na = h.size, 2 * s.n, len(s.active_idx)
    fractions = np.arange(2 * SUBSTEPS + 1) / (2 * SUBSTEPS)  # substep ends and midpoints
    t = (breaks[:-1, None] + h[:, None] * fractions[None, :]).ravel()
    x = np.hstack([interp.q(t), interp.dq(t)])
    ready = compiled and _compiled_jacobians(s) is not None
    jac_x, jac_u = buffered.call(_mapped(s, t.size, ready), x.T, interp.tau(t).T,
                                 parameters(robot, s))
    Ax = jac_x.reshape(n2, t.size, n2).transpose(1, 0, 2).reshape(N, -1, n2, n2)
    Bu = jac_u.reshape(n2, t.size, na).transpose(1, 0, 2).reshape(N, -1, n2, na)
    phi = np.broadcast_to(np.eye(n2), (N, n2, n2)).copy()
    gamma = np.zeros((N, n2, na))
    dt = (h / SUBSTEPS)[:, None, None]
    for j in range(SUBSTEPS):
        a0, am, a1 = Ax[:, 2 * j], Ax[:, 2 * j + 1], Ax[:, 2 * j + 2]
        b0, bm, b1 = Bu[:, 2 * j], Bu[:, 2 * j + 1], Bu[:, 2 * j + 2]
        phi = _rk4(phi, a0, am, a1, 0, 0, 0, dt)
        gamma = _rk4(gamma, a0, am, a1, b0, bm, b1, dt)
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(gamma))):
        return None
    return Linearisation(phi, gamma)


def _rk4(y, a0, am, a1, b0, bm, b1, dt):
    """One RK4 step of y' = A(t) y + B(t) for a batch of intervals (A, B at the step's start,
    middle and end)."""
    k1 = a0 @ y + b0
    k2 = am @ (y + dt / 2 * k1) + bm
    k3 = am @ (y + dt / 2 * k2) + bm
    k4 = a1 @ (y + dt * k3) + b1
    return y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def growth_factor(lin: Linearisation) -> float | None:
    """max_k ||Phi(t_k, 0)||_2 along the plan; None where the product of the intervals'
    transition matrices overflows (a plan far too fast for its duration)."""
    phi, products = np.eye(lin.A.shape[1]), []
    with np.errstate(over="ignore", invalid="ignore"):
        for A in lin.A:
            phi = A @ phi
            if not np.all(np.isfinite(phi)):
                return None
            products.append(phi)
    return max(1.0, float(np.linalg.norm(np.stack(products), 2, axis=(1, 2)).max()))


def gains(lin: Linearisation, h: np.ndarray, tau_scale: float) -> Feedback | None:
    """The discrete LQR gains K_k (N, na, 2n) for interval lengths h [s]; None where the
    Riccati recursion overflows (a plan far too fast for its duration)."""
    N, n2, na = lin.B.shape
    n = n2 // 2
    q_weights = np.concatenate([np.full(n, Q_SCALE**-2), np.full(n, DQ_SCALE**-2)])
    r_weights = np.full(na, tau_scale**-2)
    S = np.diag(q_weights)
    K = np.zeros((N, na, n2))
    states, torques = np.diag_indices(n2), np.diag_indices(na)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(N - 1, -1, -1):
            A, B = lin.A[k], lin.B[k]
            SA, SB = S @ A, S @ B
            lhs = B.T @ SB
            lhs[torques] += r_weights * h[k]
            try:
                K[k] = np.linalg.solve(lhs, B.T @ SA)
            except np.linalg.LinAlgError:  # an overflow made it singular
                return None
            S = A.T @ (SA - SB @ K[k])
            S = (S + S.T) / 2
            S[states] += q_weights * h[k]
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(S))):
        return None
    return Feedback(gains=K.tolist(), state_weights=q_weights.tolist(),
                    torque_weights=r_weights.tolist())


def torque_scale(interp: Interpolant, torque_limit: list[float] | float | None) -> float:
    """[N m] the torque worth one unit of LQR cost: the largest torque limit, else the
    plan's largest torque at its breakpoints, at least 1 N m."""
    if torque_limit is not None:
        return max(float(np.max(torque_limit)), 1.0)
    return max(float(np.abs(interp.tau.coeffs[:, 0]).max(initial=0.0)), 1.0)


def replay(robot: Robot, interp: Interpolant, starts: np.ndarray, K: np.ndarray | None,
           tol: float = REPLAY_TOL, compiled: bool = False, ends: bool = False,
           deadline: float | None = None, limit: np.ndarray | None = None) -> list[tuple]:
    """Replays from each of `starts` (R, 2n) under the plan's torque and, with gains
    K (N, na, 2n), the feedback, the actuators saturating at `limit` (na,) [N m] where
    given (`planner.ocp.replays`): per start, max |q_sim - q_plan| [rad] over
    REPLAY_SAMPLES points per interval and "completed", or None and where CVODES failed
    (compiled: the dynamics compiled to C); ends: also the final state (2n,) (None where
    it failed) and the largest torque the plan and its feedback command [N m] (before the
    saturation; at each interval's start and comparison points). Each start is replayed
    on its own: one that diverges leaves the others' replays whole. Past `deadline`
    (time.perf_counter() seconds) a replay stops (None, and where it stopped): CVODES
    can take seconds per interval on a diverging motion."""
    params = inputs(robot, interp, limit)[1]
    lanes = [Lane(np.asarray(x, float), params, K) for x in starts]
    done = replays(Structure.of(robot), reference(interp), lanes, tol, compiled, deadline)
    return [(r.error, r.status, r.end, r.peak) if ends else (r.error, r.status) for r in done]
