"""The motion problem: keep sigma_min(M_pa) >= s along the motion that the inverse
dynamics of a prescribed passive motion produces.

Samples: the nodes of a collocation of the inverse dynamics whose active states are NLP
variables (passive rows M_pp ddq_p + M_pa ddq_a + h_p = 0 at the nodes, ddq_a piecewise
linear in time); the intervals around the worst times are halved at every exchange.
Screening: a fixed-step RK4 inverse dynamics of all candidates at once. Check: the
inverse dynamics of `planner.inverse.solve` at dense samples. Proof: `planner.certify.path`
along the piecewise cubic Hermite interpolant of those samples (their angles and rates),
which is how the motion between samples is represented: the inverse dynamics returns
samples only.
"""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from planner import budget
from planner.certify import PROOF_RTOL, Bound, CouplingCertificate, decide, path
from planner.coupling_block import evaluate, measures
from planner.inverse import (
    InverseDynamicsRequest,
    InverseDynamicsResult,
    active_acceleration,
    solve,
)
from planner.model import Robot, Structure, parameters
from planner.ocp.interpolant import PiecewisePolynomial, hermite
from planner.rk4 import rk4_step
from planner.waves import motion_nlp
from planner.waves.certificate import EXCHANGE_TOL, Check
from planner.waves.motion_nlp import n_bound
from planner.waves.nlp import WHAT, candidate_from, lbx, normalisers, ubx
from planner.waves.schemas import WaveDesignRequest
from planner.waves.screening import SCREEN_STEPS, Candidate, params

ROLLOUT_CHUNK = 16
"""Candidates per call of the screening's RK4 (0.07 s on an 8-link arm): the deadline is
checked between calls."""
CHECK_FLOOR = 1e-3
"""sigma_min [kg m^2] down to which the check of a motion follows it: a design short of
the margin still gets a whole motion to prove its bound along."""


class MotionProblem:
    """Keep sigma_min >= s along the inverse-dynamics motion: collocation NLP, a dense
    inverse-dynamics check and the proof along it."""

    SAMPLES = ("collocation nodes of the inverse dynamics, refined around the times where "
               "the dense check fell short")

    LADDER = (40, 80, 160, 320)  # collocation intervals: few sizes, few NLP builds

    def __init__(self, request: WaveDesignRequest, s: Structure, base: Robot,
                 deadline: float | None = None):
        if request.motion is None:
            raise ValueError("a motion design needs request.motion")
        self.s, self.base, self.motion, self.deadline = s, base, request.motion, deadline
        self.p = parameters(base, s)
        self.times = np.linspace(0.0, self.motion.duration, self.LADDER[0] + 1)
        self.dense = request.certification_points or 2001
        self.threshold, self.margin = request.margin / 2, request.margin

    def screen(self, cands: list[Candidate]) -> list[float]:
        """Score every candidate by a fixed-step RK4 inverse dynamics (all at once).

        Score: the smallest sigma_min along a motion that keeps sigma_min >= margin / 2,
        else the fraction of the duration reached minus one (negative).
        """
        steps, T = SCREEN_STEPS, self.motion.duration
        t = np.linspace(0.0, T, 2 * steps + 1)
        qp, dqp, ddqp = self.motion.passive_motion.evaluate(t, T)
        stages = np.hstack([qp, dqp, ddqp])  # (2 steps + 1, 3 npas)
        U = np.hstack([stages[0:-1:2], stages[1::2], stages[2::2]]).T  # (9 npas, steps)
        init = self.motion.active_initial
        x0 = np.concatenate([init.q, init.dq])
        P = params(self.s, self.p, cands)
        X = self._rollouts(x0, U, T / steps, P)
        na, C = len(x0) // 2, len(cands)
        q = np.empty((steps + 1, C, self.s.n))
        q[:, :, self.s.passive_idx] = qp[0::2][:, None, :]
        q[0, :, self.s.active_idx] = np.array(init.q)[:, None]
        q[1:, :, self.s.active_idx] = X[:na].reshape(na, C, steps).transpose(2, 1, 0)
        finite = np.isfinite(q).all(axis=2)
        q[~finite] = 0.0
        mpa = evaluate(self.s, q.reshape(-1, self.s.n), np.tile(P, (steps + 1, 1)),
                       self.deadline)
        sigma = measures(mpa).sigma_min.reshape(steps + 1, C)
        bad = (sigma < self.threshold) | ~finite
        reached = np.where(bad.any(axis=0), bad.argmax(axis=0) / steps, 1.0)
        return [float(sigma[:, k].min()) if reached[k] == 1.0 else float(reached[k] - 1.0)
                for k in range(C)]

    def _rollouts(self, x0: np.ndarray, U: np.ndarray, h: float, P: np.ndarray) -> np.ndarray:
        """The screening's RK4 of every candidate (parameter rows P), ROLLOUT_CHUNK at a
        time with the deadline checked before each: (2 na, steps x candidates)."""
        f = _rollouts(self.s, SCREEN_STEPS, ROLLOUT_CHUNK)
        out = []
        for part in budget.chunks(len(P), ROLLOUT_CHUNK, self.deadline,
                                  "the screening's inverse dynamics", "candidate"):
            rows = P[part]
            padded = np.vstack([rows, np.repeat(rows[-1:], ROLLOUT_CHUNK - len(rows), axis=0)])
            out.append(np.array(f(x0, U, h, padded.T))[:, :len(rows) * SCREEN_STEPS])
        return np.hstack(out)

    def inverse(self, c: Candidate, samples: int, rtol: float = 1e-10,
                threshold: float | None = None) -> InverseDynamicsResult:
        """The inverse dynamics with c's waves, stopping where sigma_min falls below
        `threshold` (default margin / 2)."""
        m = self.motion
        return solve(InverseDynamicsRequest(
            robot=c.robot(self.base), passive_motion=m.passive_motion, duration=m.duration,
            active_initial=m.active_initial, samples=samples,
            sigma_threshold=self.threshold if threshold is None else threshold,
            rtol=rtol, atol=rtol), deadline=self.deadline)

    def _guess(self, c: Candidate, nz: int) -> np.ndarray:
        """Node states of the NLP: c's own, else from its inverse dynamics."""
        Z = np.zeros((nz, len(self.times)))
        if c.guess is not None and c.guess.shape[1] == len(self.times):
            states = c.guess
        else:
            states = self._states(self.inverse(c, 4 * len(self.times), rtol=1e-8))
        Z[:len(states)] = states
        return Z

    def _states(self, result: InverseDynamicsResult) -> np.ndarray:
        """(q_a, dq_a, ddq_a) at the nodes, interpolated from an inverse-dynamics result;
        held at rest after a singular stop."""
        na, A = len(self.s.active_idx), self.s.active_idx
        Z = np.zeros((3 * na, len(self.times)))
        Z[:na] = np.array(self.motion.active_initial.q)[:, None]
        if not result.t:
            return Z
        t = np.array(result.t)
        for rows, arr in ((slice(0, na), np.array(result.q)[:, A]),
                          (slice(na, 2 * na), np.array(result.dq)[:, A]),
                          (slice(2 * na, 3 * na), np.array(result.ddq)[:, A])):
            Z[rows] = np.array([np.interp(self.times, t, col) for col in arr.T])
        Z[na:, self.times > t[-1]] = 0.0
        return Z

    def optimise(self, c: Candidate, upper: np.ndarray) -> Candidate:
        K = len(self.times) - 1
        solver, nz = motion_nlp.solver(self.s, K, self.deadline, f"{WHAT}'s NLP")
        Z = self._guess(c, nz)
        qp, dqp, ddqp = self.motion.passive_motion.evaluate(self.times, self.motion.duration)
        x0 = np.concatenate([c.amplitude, c.phase, [max(c.bound, 0.0)], Z.ravel(order="F")])
        init = self.motion.active_initial
        q = np.empty((len(self.times), self.s.n))
        q[:, self.s.passive_idx], q[:, self.s.active_idx] = qp, Z[:len(init.q)].T
        C = normalisers(evaluate(self.s, q, params(self.s, self.p, [c])[0],
                                  self.deadline))
        par = np.concatenate([self.p, c.frequency, qp.ravel(), dqp.ravel(), ddqp.ravel(),
                              np.diff(self.times), init.q, init.dq, C.ravel()])
        extra = Z.size
        n_res = solver.size_out("g")[0] - (K + 1) * n_bound(self.s)
        lbg = np.concatenate([np.zeros(n_res), np.zeros((K + 1) * n_bound(self.s))])
        ubg = np.concatenate([np.zeros(n_res), np.inf * np.ones((K + 1) * n_bound(self.s))])
        sol, stats = solver(self.deadline, WHAT, x0=x0, p=par, lbx=lbx(upper, extra),
                            ubx=ubx(upper, extra), lbg=lbg, ubg=ubg)
        x = np.array(sol["x"]).ravel()
        na = len(upper)
        Z = x[2 * na + 1:].reshape(nz, K + 1, order="F")
        return candidate_from(stats, x, c, upper, Z)

    def check(self, c: Candidate) -> Check:
        """sigma_min at dense inverse-dynamics samples. The inverse dynamics runs on below
        the margin, down to CHECK_FLOOR, so that a design short of the margin still has a
        whole motion to prove its bound along."""
        floor = min(self.threshold, CHECK_FLOOR)
        result = self.inverse(c, self.dense, threshold=floor)
        sigma = np.array(result.sigma_min)
        if result.status != "completed" or len(sigma) == 0:
            stop = result.singularity.time if result.singularity else 0.0
            least = result.singularity.sigma_min if result.singularity else 0.0
            return Check(least, False,
                         f"the inverse dynamics with these waves stopped at t = {stop:.4g} s "
                         f"of {self.motion.duration:g} s, where sigma_min fell to {floor:g}",
                         np.array([stop]), reached=stop / self.motion.duration)
        t, q, dq = np.array(result.t), np.array(result.q), np.array(result.dq)
        converged = sigma.min() >= c.bound * (1 - EXCHANGE_TOL)
        describe = (f"sigma_min evaluated at {self.dense:,} evenly spaced samples of the "
                    f"inverse dynamics (DOP853, rtol = atol = 1e-10), independent of the "
                    f"{len(self.times) - 1} collocation intervals of the NLP")
        low = t[sigma < c.bound * (1 - EXCHANGE_TOL)]
        return Check(float(sigma.min()), bool(converged), describe, low,
                     motion=PiecewisePolynomial(t, hermite(q, dq, np.diff(t))))

    def prove(self, c: Candidate, check: Check) -> tuple[CouplingCertificate, str]:
        """sigma_min proven along the whole checked motion, and what that is in words."""
        robot, q = c.robot(self.base), check.motion

        def run(target: float | None) -> Bound:
            if q is None:  # the motion stopped: there is no whole motion to prove along
                return Bound(0.0, math.inf, np.zeros(1), "undecided", 0, 0.0)
            return path(robot, q, target=target, rtol=PROOF_RTOL, deadline=self.deadline)
        cert = decide(run, self.margin, check.sampled)
        if q is None:
            return cert, "nothing proven: the motion stopped"
        return cert, (f"proven along the piecewise cubic Hermite interpolant of those "
                      f"samples (their angles and rates; {len(q.coeffs):,} intervals), "
                      f"interval by interval, by ball arithmetic on M_pa in {cert.boxes:,} "
                      f"boxes ({cert.seconds:.2g} s)")

    def exchange(self, check: Check) -> None:
        """Halve the collocation intervals around the failing times (all of them when
        none is given), then split the longest ones up to the next size of LADDER."""
        t, K = self.times, len(self.times) - 1
        k = np.clip(np.searchsorted(t, check.worst) - 1, 0, K - 1)
        split = np.zeros(K, bool)
        for shift in (-1, 0, 1):
            split[np.clip(k + shift, 0, K - 1)] = True
        if not split.any():
            split[:] = True
        t = np.sort(np.concatenate([t, (t[:-1] + t[1:])[split] / 2]))
        target = next((size for size in self.LADDER if size >= len(t) - 1), None)
        if target is None:
            return
        while len(t) - 1 < target:
            i = int(np.argmax(np.diff(t)))
            t = np.insert(t, i + 1, (t[i] + t[i + 1]) / 2)
        self.times = t


@lru_cache(maxsize=16)
def _rollout(s: Structure, steps: int) -> ca.Function:
    """RK4 of the active state along tabulated passive stages: (x0, U, h, p) -> X.

    U holds per step the passive (q, dq, ddq) at t, t + h/2 and t + h (9 n_passive rows);
    X the active state (q_a, dq_a) after each step.
    """
    accel = active_acceleration(s)
    P, A = s.passive_idx, s.active_idx
    na, npas = len(A), len(P)
    x, u = ca.SX.sym("x", 2 * na), ca.SX.sym("u", 9 * npas)
    h, p = ca.SX.sym("h"), ca.SX.sym("p", s.n_params)

    def f(state: ca.SX, c: float) -> ca.SX:
        stage = int(2 * c)  # the passive stage at t, t + h/2 or t + h
        qp, dqp, ddqp = (u[(3 * stage + i) * npas:(3 * stage + i + 1) * npas] for i in range(3))
        q, dq = ca.SX.zeros(s.n), ca.SX.zeros(s.n)
        q[P], q[A], dq[P], dq[A] = qp, state[:na], dqp, state[na:]
        return ca.vertcat(state[na:], accel(q, dq, ddqp, p))

    step = ca.Function("step", [x, u, h, p], [rk4_step(f, x, h)])
    chain = step.mapaccum(steps)
    X0, U = ca.MX.sym("x0", 2 * na), ca.MX.sym("U", 9 * npas, steps)
    H, Pm = ca.MX.sym("h"), ca.MX.sym("p", s.n_params)
    return ca.Function("rollout", [X0, U, H, Pm], [chain(X0, U, H, Pm)])


@lru_cache(maxsize=16)
def _rollouts(s: Structure, steps: int, size: int) -> ca.Function:
    """`_rollout` mapped over `size` candidates (one parameter column each)."""
    return _rollout(s, steps).map(size)
