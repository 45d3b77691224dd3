"""Certified wave design: a numerical form of the seed's Proposition 1.

Every active joint j gets a wave r_j = l_j + a_j sin(n_j q_j + eps_j), with an amplitude
0 <= a_j <= amplitude_max (and below the link length), an integer frequency
1 <= n_j <= frequency_max and a free phase, so that sigma_min(M_pa) >= margin over a box
of configurations, or along the motion that the inverse dynamics then produces. Waves
already on the robot are replaced.

How:
1. Screening. Every frequency combination with a few phases per joint (full amplitude)
   is scored: over a box by sigma_min at the optimisation samples; along a motion by a
   fixed-step RK4 inverse dynamics of all candidates at once. The best starts, one per
   frequency combination first, go to the NLP.
2. NLP (Ipopt). With the frequencies fixed, maximise s over amplitudes and phases
   subject to lambda_min(M_pa M_pa^T) >= s^2 at every sample, as smooth dimensionless
   constraints (see `_bound`). Along a motion the samples are the nodes of a collocation
   of the inverse dynamics whose active states are NLP variables (passive rows
   M_pp ddq_p + M_pa ddq_a + h_p = 0 at the nodes, ddq_a piecewise linear in time).
3. Certification, independent of the NLP's samples: a dense grid of the box with a
   Lipschitz bound between grid points, or the inverse dynamics of `planner.inverse.solve`
   at dense samples with a bound between samples. Where the dense check falls below the
   NLP's bound, the worst configurations join the samples (or the collocation intervals
   around the worst times are halved) and the NLP is solved again (exchange method).

The result is "certified" when the certified value reaches the margin, else
"infeasible" with the best value found (which proves nothing about other waves).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import casadi as ca
import numpy as np
from pydantic import BaseModel, Field, model_validator

from planner import budget
from planner.coupling_block import evaluate, measures
from planner.dynamics import derive
from planner.exclusive import Exclusive
from planner.inverse import (ActiveState, InverseDynamicsRequest, InverseDynamicsResult,
                             active_acceleration, check_motion, check_prescribable, solve)
from planner.model import Robot, Structure, Wave, parameters, wave_slots
from planner.profiles import PassiveMotion
from planner.schema import REQUEST as _STRICT


AMPLITUDE_FRACTION = 0.95
"""Largest amplitude as a fraction of the link length (r stays >= 5 % of l)."""
CERTIFY_FLOOR = 1e-3
"""sigma_min [kg m^2] down to which the certificate of a motion follows it: a design short
of the margin still reports what it certifies."""
EXCHANGE_ROUNDS = 6
"""Largest number of NLP solves per starting point (exchange iterations)."""
EXCHANGE_TOL = 0.01
"""The exchange stops when the dense minimum is within this fraction of the NLP bound."""
MAX_SCREENING = 5_000_000
"""Largest number of configurations the screening of one design may evaluate
(candidates x samples of each, `WaveDesignRequest.screening`)."""
SCREEN_STEPS = 100
"""RK4 steps of the screening's inverse dynamics along a motion."""
_WHAT = "the wave design"
_IPOPT = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
          "ipopt.max_iter": 250, "ipopt.tol": 1e-9, "ipopt.acceptable_tol": 1e-6}
"""Ipopt settings. The motion NLP is also expanded to SX (builds once per ladder size,
then evaluates ten times faster); the region NLP, rebuilt at every exchange, is not."""


# --------------------------------------------------------------------------- requests


class Region(BaseModel):
    """A box of configurations [rad], one bound per joint; lower == upper fixes a joint."""

    model_config = _STRICT

    lower: list[float] = Field(min_length=1)
    upper: list[float] = Field(min_length=1)


class Motion(BaseModel):
    """A prescribed passive motion and the active joints' initial state (as for
    `planner.inverse.InverseDynamicsRequest`)."""

    model_config = _STRICT

    passive_motion: PassiveMotion
    duration: float = Field(gt=0.0, le=1e4, description="T [s]")
    active_initial: ActiveState


class WaveDesignRequest(BaseModel):
    """Bounds of the waves and what they must keep regular: a region or a motion."""

    model_config = _STRICT

    robot: Robot
    amplitude_max: float = Field(gt=0.0, description="largest amplitude a [m]")
    frequency_max: int = Field(ge=1, le=12, description="largest integer frequency n")
    margin: float = Field(gt=0.0, description="required sigma_min(M_pa) [kg m^2]")
    region: Region | None = None
    motion: Motion | None = None
    starts: int = Field(default=4, ge=1, le=32, description="NLP starting points")
    certification_points: int | None = Field(
        default=None, ge=100, le=200_000,
        description="dense check: grid points of the region (default 40,000) or "
                    "inverse-dynamics samples of the motion (default 2,001)")

    @model_validator(mode="after")
    def _consistent(self) -> WaveDesignRequest:
        check_prescribable(self.robot)
        n = self.robot.n
        if (self.region is None) == (self.motion is None):
            raise ValueError("region: give exactly one of region and motion")
        if self.region is not None:
            if len(self.region.lower) != n or len(self.region.upper) != n:
                raise ValueError(f"region: lower and upper need {n} entries each, one per joint")
            if any(u < lo for lo, u in zip(self.region.lower, self.region.upper)):
                raise ValueError("region.upper: every entry must be >= the matching entry "
                                 "of lower")
        else:
            m = self.motion
            check_motion(self.robot, m.passive_motion, m.duration, m.active_initial, "motion.")
        if self.screening > MAX_SCREENING:
            raise ValueError(f"frequency_max: the screening would evaluate {self.screening:,} "
                             f"configurations, more than the limit of {MAX_SCREENING:,}; lower "
                             "frequency_max or fix joints of the region (lower == upper)")
        return self

    @property
    def screening(self) -> int:
        """Configurations the screening evaluates, counted without building anything:
        every frequency and phase combination of the active joints times its samples (the
        region's coarse grid, or the motion's RK4 steps)."""
        na = len(self.robot.active)
        candidates = (self.frequency_max * _phases_per_joint(na)) ** na
        if self.region is None:
            return candidates * (SCREEN_STEPS + 1)
        free = sum(hi > lo for lo, hi in zip(self.region.lower, self.region.upper))
        return candidates * _coarse_points(free) ** free


class WaveSpec(BaseModel):
    """The wave of one active joint (0-based index)."""

    joint: int
    amplitude: float
    frequency: int
    phase: float


class WaveDesignResult(BaseModel):
    """The designed waves, the certified smallest sigma_min [kg m^2] and how it was
    certified. `robot` is the request's robot carrying these waves."""

    status: Literal["certified", "infeasible"]
    waves: list[WaveSpec]
    certified_sigma_min: float
    method: str
    robot: Robot


# --------------------------------------------------------------------------- symbolic pieces


def wave_structure(robot: Robot) -> Structure:
    """The robot's structure with wave terms on every active joint."""
    return Structure.of(robot, wavy=tuple(link.joint == "active" for link in robot.links))


def _with_waves(s: Structure, base, amplitude, frequency, phase) -> ca.MX:
    """The parameter vector `base` with the active joints' (a, n, eps) put in their slots."""
    entries = [base[i] for i in range(s.n_params)]
    for k, slot in enumerate(sorted(wave_slots(s).values())):  # active joints in order
        entries[slot:slot + 3] = [amplitude[k], frequency[k], phase[k]]
    return ca.vertcat(*entries)


def _bound(G, s2, c):
    """Smooth constraints, all >= 0, for lambda_min(G) >= s2 (G symmetric r x r), each
    made dimensionless by the normalisers c (see `_normalisers`), so that Ipopt's
    tolerances mean the same relative accuracy for every r and every arm.

    r = 1: G - s2. r = 2: the closed-form smaller eigenvalue minus s2. r >= 3: the leading
    principal minors of G - s2 I (for k < r these only exclude indefinite matrices).
    """
    r = G.shape[0]
    if r == 1:
        return (G - s2) / c[0]
    if r == 2:
        half_trace, half_gap = (G[0, 0] + G[1, 1]) / 2, (G[0, 0] - G[1, 1]) / 2
        spread = ca.sqrt(half_gap**2 + G[0, 1] ** 2 + (1e-12 * half_trace) ** 2)
        return (half_trace - spread - s2) / c[0]
    D = G - s2 * ca.SX.eye(r)
    return ca.vertcat(*[ca.det(D[:k, :k]) / c[k - 1] for k in range(1, r + 1)])


def _n_bound(s: Structure) -> int:
    r = len(s.passive_idx)
    return 1 if r <= 2 else r


def _normalisers(mpa: np.ndarray) -> np.ndarray:
    """Scales of the constraints of `_bound` at each block of a batch (K, r, c) -> (K, r).

    With G = M_pa M_pa^T and g its largest eigenvalue over the batch: c[k-1] = g times the
    product of the k - 1 largest eigenvalues of G's leading k x k block, so that the k-th
    minor of G - s2 I divided by c[k-1] is about (its smallest eigenvalue - s2) / g.
    """
    G = mpa @ mpa.transpose(0, 2, 1)
    K, r = G.shape[:2]
    scale = max(float(np.linalg.eigvalsh(G)[:, -1].max()), 1e-300)
    c = np.full((K, r), scale)
    for k in range(2, r + 1):
        eig = np.linalg.eigvalsh(G[:, :k, :k])[:, 1:]  # the k - 1 largest
        c[:, k - 1] *= np.maximum(eig.prod(axis=1), (1e-12 * scale) ** (k - 1))
    return c


@lru_cache(maxsize=16)
def _sample_bound(s: Structure) -> ca.Function:
    """bound(q, p, s2, c): the constraints of `_bound` for M_pa(q) M_pa(q)^T at one point."""
    sym = derive(s)
    mpa = sym.mass[s.passive_idx, s.active_idx]
    s2, c = ca.SX.sym("s2"), ca.SX.sym("c", len(s.passive_idx))
    return ca.Function("bound", [sym.q, sym.p, s2, c], [_bound(ca.mtimes(mpa, mpa.T), s2, c)])


def _decision(na: int):
    return ca.MX.sym("a", na), ca.MX.sym("eps", na), ca.MX.sym("s")


@lru_cache(maxsize=16)
def _region_nlp(s: Structure, count: int) -> Exclusive:
    """maximise s over (a, eps, s) s.t. the bound holds at `count` configurations."""
    na = len(s.active_idx)
    a, eps, sig = _decision(na)
    base, freq = ca.MX.sym("p", s.n_params), ca.MX.sym("n", na)
    Q, C = ca.MX.sym("Q", s.n, count), ca.MX.sym("C", len(s.passive_idx), count)
    p = _with_waves(s, base, a, freq, eps)
    g = _sample_bound(s).map(count)(Q, p, sig**2, C)
    nlp = {"x": ca.vertcat(a, eps, sig), "p": ca.vertcat(base, freq, ca.vec(Q), ca.vec(C)),
           "f": -sig, "g": ca.vec(g)}
    return Exclusive(ca.nlpsol("waves_region", "ipopt", nlp,
                               {**_IPOPT, **budget.ipopt_stop(nlp)}))


@lru_cache(maxsize=16)
def _node(s: Structure) -> ca.Function:
    """Passive-row residual and bound at one collocation node."""
    sym = derive(s)
    P, A = s.passive_idx, s.active_idx
    na, npas = len(A), len(P)
    z = ca.SX.sym("z", 3 * na + (npas if na > npas else 0))
    qp, dqp, ddqp = ca.SX.sym("qp", npas), ca.SX.sym("dqp", npas), ca.SX.sym("ddqp", npas)
    s2, c = ca.SX.sym("s2"), ca.SX.sym("c", npas)
    q, dq = ca.SX.zeros(s.n), ca.SX.zeros(s.n)
    q[P], q[A], dq[P], dq[A] = qp, z[:na], dqp, z[na:2 * na]
    mass = ca.Function("Mh", [sym.q, sym.dq, sym.p], [sym.mass, sym.bias])
    M, h = mass(q, dq, sym.p)
    mpa = M[P, A]
    ddqa = z[2 * na:3 * na]
    residual = [ca.mtimes(M[P, P], ddqp) + ca.mtimes(mpa, ddqa) + h[P]]
    if na > npas:  # minimum norm: ddq_a in the row space of M_pa
        residual.append(ddqa - ca.mtimes(mpa.T, z[3 * na:]))
    return ca.Function("node", [z, qp, dqp, ddqp, sym.p, s2, c],
                       [ca.vertcat(*residual), _bound(ca.mtimes(mpa, mpa.T), s2, c)])


def _interval(na: int, nz: int) -> ca.Function:
    """Continuity of (q_a, dq_a) over one interval with ddq_a linear in time."""
    z0, z1, h = ca.SX.sym("z0", nz), ca.SX.sym("z1", nz), ca.SX.sym("h")
    q0, v0, a0 = z0[:na], z0[na:2 * na], z0[2 * na:3 * na]
    q1, v1, a1 = z1[:na], z1[na:2 * na], z1[2 * na:3 * na]
    return ca.Function("interval", [z0, z1, h], [ca.vertcat(
        q1 - q0 - h * v0 - h**2 / 6 * (2 * a0 + a1), v1 - v0 - h / 2 * (a0 + a1))])


@lru_cache(maxsize=16)
def _motion_nlp(s: Structure, K: int) -> tuple[Exclusive, int]:
    """maximise s over (a, eps, s, node states) along K intervals; returns (solver, nz)."""
    na, npas = len(s.active_idx), len(s.passive_idx)
    nz = 3 * na + (npas if na > npas else 0)
    a, eps, sig = _decision(na)
    Z = ca.MX.sym("Z", nz, K + 1)
    base, freq = ca.MX.sym("p", s.n_params), ca.MX.sym("n", na)
    QP, DQP, DDQP = (ca.MX.sym(name, npas, K + 1) for name in ("qp", "dqp", "ddqp"))
    H, X0 = ca.MX.sym("h", 1, K), ca.MX.sym("x0", 2 * na)
    C = ca.MX.sym("C", npas, K + 1)
    p = _with_waves(s, base, a, freq, eps)
    residual, bound = _node(s).map(K + 1)(Z, QP, DQP, DDQP, p, sig**2, C)
    continuity = _interval(na, nz).map(K)(Z[:, :-1], Z[:, 1:], H)
    g = ca.vertcat(Z[:2 * na, 0] - X0, ca.vec(residual), ca.vec(continuity), ca.vec(bound))
    nlp = {"x": ca.vertcat(a, eps, sig, ca.vec(Z)), "f": -sig, "g": g,
           "p": ca.vertcat(base, freq, ca.vec(QP), ca.vec(DQP), ca.vec(DDQP), H.T, X0,
                           ca.vec(C))}
    options = {**_IPOPT, "expand": True, **budget.ipopt_stop(nlp)}
    return Exclusive(ca.nlpsol("waves_motion", "ipopt", nlp, options)), nz


# --------------------------------------------------------------------------- candidates


@dataclass
class Candidate:
    """Waves of the active joints: amplitudes [m], integer frequencies, phases [rad]."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    bound: float = 0.0  # the NLP's s, or the screening score
    solved: bool = False  # the NLP converged
    guess: np.ndarray | None = field(default=None, repr=False)  # NLP node states (motion)

    def robot(self, base: Robot) -> Robot:
        waves = {j: Wave(amplitude=float(a), frequency=float(n), phase=float(e))
                 for j, a, n, e in zip(base.active, self.amplitude, self.frequency, self.phase)}
        return base.with_waves(waves)

    def specs(self, base: Robot) -> list[WaveSpec]:
        return [WaveSpec(joint=j, amplitude=float(a), frequency=int(n), phase=float(e))
                for j, a, n, e in zip(base.active, self.amplitude, self.frequency, self.phase)]


def _wrap(phase: np.ndarray) -> np.ndarray:
    """Phases in [-pi, pi)."""
    return (np.asarray(phase) + np.pi) % (2 * np.pi) - np.pi


def _candidates(na: int, frequency_max: int, amplitude: np.ndarray,
                starts: int) -> list[Candidate]:
    """Every frequency combination with `starts` evenly spaced phases per joint."""
    phases = 2 * np.pi * np.arange(starts) / starts - np.pi
    out = []
    for freq in itertools.product(range(1, frequency_max + 1), repeat=na):
        for phase in itertools.product(phases, repeat=na):
            out.append(Candidate(amplitude.copy(), np.array(freq, float), np.array(phase)))
    return out


def _params(s: Structure, base: np.ndarray, cands: list[Candidate]) -> np.ndarray:
    """One parameter vector per candidate (rows)."""
    P = np.tile(base, (len(cands), 1))
    for k, slot in enumerate(sorted(wave_slots(s).values())):
        P[:, slot] = [c.amplitude[k] for c in cands]
        P[:, slot + 1] = [c.frequency[k] for c in cands]
        P[:, slot + 2] = [c.phase[k] for c in cands]
    return P


@dataclass
class Certificate:
    """Dense check of one design: the certified value, whether the exchange may stop, and
    where to add samples."""

    value: float
    converged: bool
    describe: str
    worst: np.ndarray = field(default_factory=lambda: np.empty(0))
    reached: float = 1.0  # fraction of the motion the inverse dynamics completed

    def beats(self, other: Certificate | None) -> bool:
        """Higher certified value; among motions that stop, the one that gets further."""
        return other is None or (self.value, self.reached) > (other.value, other.reached)


# --------------------------------------------------------------------------- region


class _RegionProblem:
    """Keep sigma_min >= s over a box: samples, NLP and dense-grid certification."""

    SAMPLES = "grid points of the box, joined by the dense grid's worst points"

    def __init__(self, request: WaveDesignRequest, s: Structure, base: Robot,
                 deadline: float | None = None):
        self.s, self.base, self.deadline = s, base, deadline
        self.p = parameters(base, s)
        lower, upper = np.array(request.region.lower), np.array(request.region.upper)
        self.free = np.flatnonzero(upper > lower)
        d = max(len(self.free), 1)
        coarse = _coarse_points(len(self.free))
        self.samples = _box_grid(lower, upper, coarse)
        points = request.certification_points or 40_000
        self.dense_points = max(3, int(points ** (1 / d)))
        if self.dense_points == coarse:
            self.dense_points += 1
        self.dense = _box_grid(lower, upper, self.dense_points)
        self.steps = (upper - lower) / (self.dense_points - 1)

    def screen(self, cands: list[Candidate]) -> list[float]:
        """Smallest sigma_min over the samples of each candidate."""
        K = len(self.samples)
        Q = np.tile(self.samples, (len(cands), 1))
        P = np.repeat(_params(self.s, self.p, cands), K, axis=0)
        smin = measures(evaluate(self.s, "Mpa", Q, P, self.deadline)).sigma_min
        return list(smin.reshape(len(cands), K).min(axis=1))

    def optimise(self, c: Candidate, upper: np.ndarray) -> Candidate:
        solver = _region_nlp(self.s, len(self.samples))
        x0 = np.concatenate([c.amplitude, c.phase, [max(c.bound, 0.0)]])
        p = _params(self.s, self.p, [c])[0]
        C = _normalisers(evaluate(self.s, "Mpa", self.samples, p, self.deadline))
        par = np.concatenate([self.p, c.frequency, self.samples.ravel(), C.ravel()])
        sol, stats = solver(self.deadline, _WHAT, x0=x0, p=par, lbx=_lbx(upper),
                            ubx=_ubx(upper), lbg=0.0, ubg=np.inf)
        x = np.array(sol["x"]).ravel()
        return _candidate_from(stats, x, c, upper)

    def certify(self, c: Candidate) -> Certificate:
        """Dense-grid minimum minus the Lipschitz bound between grid points."""
        p = _params(self.s, self.p, [c])[0]
        smin = measures(evaluate(self.s, "Mpa", self.dense, p, self.deadline)).sigma_min
        jac = evaluate(self.s, "dMpa", self.dense, p, self.deadline)  # (K, r*c, n)
        slope = np.sqrt((jac**2).sum(axis=1)).max(axis=0)  # largest |dM_pa/dq_i|_F
        lipschitz = float((slope * self.steps / 2)[self.free].sum())
        value = float(smin.min()) - lipschitz
        order = np.argsort(smin)[:8]
        converged = smin.min() >= c.bound * (1 - EXCHANGE_TOL)
        shape = " x ".join(str(self.dense_points) for _ in self.free)
        describe = (f"sigma_min evaluated on a dense {shape} grid of the region "
                    f"({len(self.dense):,} points, independent of the "
                    f"{len(self.samples)} optimisation samples); between grid points it "
                    f"can fall by at most {lipschitz:.3g} (largest |dM_pa/dq_i| on the grid "
                    f"times half the spacing), which the certified value subtracts"
                    ) if len(self.free) else "sigma_min evaluated at the region's single point"
        return Certificate(value, bool(converged), describe, self.dense[order])

    def exchange(self, cert: Certificate) -> None:
        self.samples = np.vstack([self.samples, cert.worst])


def _coarse_points(free: int) -> int:
    """Optimisation samples per free axis of a region: about 300 in all, 3 to 17 a side."""
    return min(17, max(3, round(300 ** (1 / max(free, 1)))))


def _box_grid(lower: np.ndarray, upper: np.ndarray, points: int) -> np.ndarray:
    axes = [np.array([lo]) if hi == lo else np.linspace(lo, hi, points)
            for lo, hi in zip(lower, upper)]
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)


def _lbx(upper: np.ndarray, extra: int = 0) -> np.ndarray:
    na = len(upper)
    return np.concatenate([np.zeros(na), -np.inf * np.ones(na), [0.0], -np.inf * np.ones(extra)])


def _ubx(upper: np.ndarray, extra: int = 0) -> np.ndarray:
    na = len(upper)
    return np.concatenate([upper, np.inf * np.ones(na), [np.inf], np.inf * np.ones(extra)])


def _candidate_from(stats: dict, x: np.ndarray, start: Candidate,
                    upper: np.ndarray, guess: np.ndarray | None = None) -> Candidate:
    """The NLP's waves (amplitudes clipped to their bounds, phases wrapped); the start,
    marked unsolved, when the NLP returned a non-finite point."""
    na = len(start.frequency)
    if not np.all(np.isfinite(x)):
        return Candidate(start.amplitude, start.frequency, start.phase, start.bound, False)
    solved = stats["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    return Candidate(np.clip(x[:na], 0.0, upper), start.frequency.copy(), _wrap(x[na:2 * na]),
                     float(x[2 * na]), solved, guess)


# --------------------------------------------------------------------------- motion


class _MotionProblem:
    """Keep sigma_min >= s along the inverse-dynamics motion: collocation NLP and a dense
    inverse-dynamics check."""

    SAMPLES = ("collocation nodes of the inverse dynamics, refined around the times where "
               "the dense check fell short")

    LADDER = (40, 80, 160, 320)  # collocation intervals: few sizes, few NLP builds

    def __init__(self, request: WaveDesignRequest, s: Structure, base: Robot,
                 deadline: float | None = None):
        self.s, self.base, self.motion, self.deadline = s, base, request.motion, deadline
        self.p = parameters(base, s)
        self.times = np.linspace(0.0, self.motion.duration, self.LADDER[0] + 1)
        self.dense = request.certification_points or 2001
        self.threshold = request.margin / 2

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
        P = _params(self.s, self.p, cands)
        X = np.array(_rollout(self.s, steps).map(len(cands))(x0, U, T / steps, P.T))
        na, C = len(x0) // 2, len(cands)
        q = np.empty((steps + 1, C, self.s.n))
        q[:, :, self.s.passive_idx] = qp[0::2][:, None, :]
        q[0, :, self.s.active_idx] = np.array(init.q)[:, None]
        q[1:, :, self.s.active_idx] = X[:na].reshape(na, C, steps).transpose(2, 1, 0)
        finite = np.isfinite(q).all(axis=2)
        q[~finite] = 0.0
        mpa = evaluate(self.s, "Mpa", q.reshape(-1, self.s.n), np.tile(P, (steps + 1, 1)),
                       self.deadline)
        sigma = measures(mpa).sigma_min.reshape(steps + 1, C)
        bad = (sigma < self.threshold) | ~finite
        reached = np.where(bad.any(axis=0), bad.argmax(axis=0) / steps, 1.0)
        return [float(sigma[:, k].min()) if reached[k] == 1.0 else float(reached[k] - 1.0)
                for k in range(C)]

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
        solver, nz = _motion_nlp(self.s, K)
        Z = self._guess(c, nz)
        qp, dqp, ddqp = self.motion.passive_motion.evaluate(self.times, self.motion.duration)
        x0 = np.concatenate([c.amplitude, c.phase, [max(c.bound, 0.0)], Z.ravel(order="F")])
        init = self.motion.active_initial
        q = np.empty((len(self.times), self.s.n))
        q[:, self.s.passive_idx], q[:, self.s.active_idx] = qp, Z[:len(init.q)].T
        C = _normalisers(evaluate(self.s, "Mpa", q, _params(self.s, self.p, [c])[0],
                                  self.deadline))
        par = np.concatenate([self.p, c.frequency, qp.ravel(), dqp.ravel(), ddqp.ravel(),
                              np.diff(self.times), init.q, init.dq, C.ravel()])
        extra = Z.size
        n_res = solver.size_out("g")[0] - (K + 1) * _n_bound(self.s)
        lbg = np.concatenate([np.zeros(n_res), np.zeros((K + 1) * _n_bound(self.s))])
        ubg = np.concatenate([np.zeros(n_res), np.inf * np.ones((K + 1) * _n_bound(self.s))])
        sol, stats = solver(self.deadline, _WHAT, x0=x0, p=par, lbx=_lbx(upper, extra),
                            ubx=_ubx(upper, extra), lbg=lbg, ubg=ubg)
        x = np.array(sol["x"]).ravel()
        na = len(upper)
        Z = x[2 * na + 1:].reshape(nz, K + 1, order="F")
        return _candidate_from(stats, x, c, upper, Z)

    def certify(self, c: Candidate) -> Certificate:
        """Dense inverse-dynamics samples: their minimum minus the bound between samples.
        The inverse dynamics runs on below the margin, down to CERTIFY_FLOOR, so that a
        design short of the margin still certifies what it reaches."""
        result = self.inverse(c, self.dense, threshold=min(self.threshold, CERTIFY_FLOOR))
        sigma = np.array(result.sigma_min)
        if result.status != "completed" or len(sigma) == 0:
            stop = result.singularity.time if result.singularity else 0.0
            return Certificate(0.0, False,
                               f"the inverse dynamics with these waves stopped at t = "
                               f"{stop:.4g} s of {self.motion.duration:g} s, where sigma_min "
                               f"fell to {min(self.threshold, CERTIFY_FLOOR):g}",
                               np.array([stop]), reached=stop / self.motion.duration)
        q, dq = np.array(result.q), np.array(result.dq)
        p = _params(self.s, self.p, [c])[0]
        jac = evaluate(self.s, "dMpa", q, p, self.deadline)  # (K, r*c, n)
        rate = np.sqrt((np.einsum("kij,kj->ki", jac, dq) ** 2).sum(axis=1)).max()
        dt = self.motion.duration / (self.dense - 1)
        value = float(sigma.min() - rate * dt / 2)
        converged = sigma.min() >= c.bound * (1 - EXCHANGE_TOL)
        t = np.array(result.t)
        describe = (f"sigma_min evaluated at {self.dense:,} evenly spaced samples of the "
                    f"inverse dynamics (DOP853, rtol = atol = 1e-10), independent of the "
                    f"{len(self.times) - 1} collocation intervals of the NLP; between samples "
                    f"it can fall by at most {rate * dt / 2:.3g} (largest |dM_pa/dt| times "
                    f"half the spacing), which the certified value subtracts")
        low = t[sigma < c.bound * (1 - EXCHANGE_TOL)]
        return Certificate(value, bool(converged), describe, low)

    def exchange(self, cert: Certificate) -> None:
        """Halve the collocation intervals around the failing times (all of them when
        none is given), then split the longest ones up to the next size of LADDER."""
        t, K = self.times, len(self.times) - 1
        k = np.clip(np.searchsorted(t, cert.worst) - 1, 0, K - 1)
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

    def f(state, stage):
        qp, dqp, ddqp = (u[(3 * stage + i) * npas:(3 * stage + i + 1) * npas] for i in range(3))
        q, dq = ca.SX.zeros(s.n), ca.SX.zeros(s.n)
        q[P], q[A], dq[P], dq[A] = qp, state[:na], dqp, state[na:]
        return ca.vertcat(state[na:], accel(q, dq, ddqp, p))

    k1 = f(x, 0)
    k2 = f(x + h / 2 * k1, 1)
    k3 = f(x + h / 2 * k2, 1)
    k4 = f(x + h * k3, 2)
    step = ca.Function("step", [x, u, h, p], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    chain = step.mapaccum(steps)
    X0, U = ca.MX.sym("x0", 2 * na), ca.MX.sym("U", 9 * npas, steps)
    H, Pm = ca.MX.sym("h"), ca.MX.sym("p", s.n_params)
    return ca.Function("rollout", [X0, U, H, Pm], [chain(X0, U, H, Pm)])


# --------------------------------------------------------------------------- design


def design(request: WaveDesignRequest, *, deadline: float | None = None) -> WaveDesignResult:
    """Waves that keep sigma_min(M_pa) >= margin, certified on dense samples.

    Past `deadline` (a `time.monotonic()` value) it raises BudgetExceeded: between starts
    and exchange rounds, between chunks of evaluations, inside the inverse dynamics, and
    at the next Ipopt iteration."""
    with budget.part_of(_WHAT):
        return _design(request, deadline)


def _design(request: WaveDesignRequest, deadline: float | None) -> WaveDesignResult:
    base = request.robot.without_waves()
    s = wave_structure(base)
    upper = np.array([min(request.amplitude_max, AMPLITUDE_FRACTION * base.links[j].length)
                      for j in base.active])
    kind = _RegionProblem if request.region is not None else _MotionProblem
    problem = kind(request, s, base, deadline)

    phases = _phases_per_joint(len(upper))
    cands = _candidates(len(upper), request.frequency_max, upper, phases)
    scores = problem.screen(cands)
    order = _diverse(cands, scores, request.starts)

    best: tuple[Candidate, Certificate] | None = None
    for i, k in enumerate(order):
        budget.check(deadline, f"{_WHAT} (after {i} of {len(order)} starts)")
        start = cands[k]
        start.bound = float(scores[k])
        floor = max(request.margin, best[1].value if best else -math.inf)
        c, cert = _exchange(problem, start, upper, floor)
        if cert.beats(best[1] if best else None):
            best = (c, cert)
    c, cert = best
    status = "certified" if cert.value >= request.margin else "infeasible"
    certified = max(cert.value, 0.0)
    method = (f"From the {len(order)} best of {len(cands)} screened starts (integer "
              f"frequencies 1..{request.frequency_max}, {phases} phases "
              f"per joint), Ipopt maximised a lower bound on sigma_min(M_pa) at the "
              f"{problem.SAMPLES}; certified: {cert.describe}.")
    return WaveDesignResult(status=status, waves=c.specs(base), certified_sigma_min=certified,
                            method=method, robot=c.robot(base))


def _phases_per_joint(na: int) -> int:
    """Starting phases per joint of `na` active joints: about 36 phase combinations per
    frequency combination."""
    return max(2, min(8, math.floor(36 ** (1 / na) + 1e-9)))


def _diverse(cands: list[Candidate], scores: list[float], count: int) -> list[int]:
    """Indices of the `count` best candidates, the best of each frequency combination
    first, so that the starts do not all fall into one basin."""
    order = list(np.argsort(scores)[::-1])
    seen, first, rest = set(), [], []
    for k in order:
        key = tuple(cands[k].frequency)
        (rest if key in seen or scores[k] <= 0.0 else first).append(k)
        seen.add(key)
    return (first + rest)[:count]


def _exchange(problem, start: Candidate, upper: np.ndarray,
              floor: float) -> tuple[Candidate, Certificate]:
    """Solve the NLP, certify, add the failing samples, solve again; keep the best certified.

    Stops early when the NLP's bound falls below `floor` (the margin, or the best value
    certified so far): more samples would only lower it further."""
    c, previous = start, math.inf
    best: tuple[Candidate, Certificate] | None = None
    for _ in range(EXCHANGE_ROUNDS):
        c = problem.optimise(c, upper)
        cert = problem.certify(c)
        if cert.beats(best[1] if best else None):
            best = (c, cert)
        stalled = c.bound > previous * (1 - EXCHANGE_TOL)  # the added samples changed nothing
        if cert.converged or not c.solved or stalled or c.bound < floor:
            break
        previous = c.bound
        problem.exchange(cert)
    return best
