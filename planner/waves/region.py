"""The region problem: keep sigma_min(M_pa) >= s over a box of configurations.

Samples: a coarse grid of the box, joined by the dense grid's worst points at every
exchange. Certification: a dense grid with a Lipschitz bound between grid points.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np

from planner import budget
from planner.coupling_block import evaluate, measures
from planner.dynamics import derive
from planner.exclusive import Exclusive
from planner.model import Robot, Structure, parameters
from planner.waves.certificate import EXCHANGE_TOL, Certificate
from planner.waves.nlp import (
    IPOPT,
    WHAT,
    bound,
    candidate_from,
    decision,
    lbx,
    normalisers,
    ubx,
    with_waves,
)
from planner.waves.schemas import WaveDesignRequest
from planner.waves.screening import Candidate, coarse_points, params


class RegionProblem:
    """Keep sigma_min >= s over a box: samples, NLP and dense-grid certification."""

    SAMPLES = "grid points of the box, joined by the dense grid's worst points"

    def __init__(self, request: WaveDesignRequest, s: Structure, base: Robot,
                 deadline: float | None = None):
        self.s, self.base, self.deadline = s, base, deadline
        self.p = parameters(base, s)
        if request.region is None:
            raise ValueError("a region design needs request.region")
        lower, upper = np.array(request.region.lower), np.array(request.region.upper)
        self.free = np.flatnonzero(upper > lower)
        d = max(len(self.free), 1)
        coarse = coarse_points(len(self.free))
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
        P = np.repeat(params(self.s, self.p, cands), K, axis=0)
        smin = measures(evaluate(self.s, "Mpa", Q, P, self.deadline)).sigma_min
        return list(smin.reshape(len(cands), K).min(axis=1))

    def optimise(self, c: Candidate, upper: np.ndarray) -> Candidate:
        solver = _region_nlp(self.s, len(self.samples))
        x0 = np.concatenate([c.amplitude, c.phase, [max(c.bound, 0.0)]])
        p = params(self.s, self.p, [c])[0]
        C = normalisers(evaluate(self.s, "Mpa", self.samples, p, self.deadline))
        par = np.concatenate([self.p, c.frequency, self.samples.ravel(), C.ravel()])
        sol, stats = solver(self.deadline, WHAT, x0=x0, p=par, lbx=lbx(upper),
                            ubx=ubx(upper), lbg=0.0, ubg=np.inf)
        x = np.array(sol["x"]).ravel()
        return candidate_from(stats, x, c, upper)

    def certify(self, c: Candidate) -> Certificate:
        """Dense-grid minimum minus the Lipschitz bound between grid points."""
        p = params(self.s, self.p, [c])[0]
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


def _box_grid(lower: np.ndarray, upper: np.ndarray, points: int) -> np.ndarray:
    axes = [np.array([lo]) if hi == lo else np.linspace(lo, hi, points)
            for lo, hi in zip(lower, upper, strict=True)]
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)


@lru_cache(maxsize=16)
def _sample_bound(s: Structure) -> ca.Function:
    """bound(q, p, s2, c): the constraints of `bound` for M_pa(q) M_pa(q)^T at one point."""
    sym = derive(s)
    mpa = sym.mass[s.passive_idx, s.active_idx]
    s2, c = ca.SX.sym("s2"), ca.SX.sym("c", len(s.passive_idx))
    return ca.Function("bound", [sym.q, sym.p, s2, c], [bound(ca.mtimes(mpa, mpa.T), s2, c)])


@lru_cache(maxsize=16)
def _region_nlp(s: Structure, count: int) -> Exclusive:
    """maximise s over (a, eps, s) s.t. the bound holds at `count` configurations."""
    na = len(s.active_idx)
    a, eps, sig = decision(na)
    base, freq = ca.MX.sym("p", s.n_params), ca.MX.sym("n", na)
    Q, C = ca.MX.sym("Q", s.n, count), ca.MX.sym("C", len(s.passive_idx), count)
    p = with_waves(s, base, a, freq, eps)
    g = _sample_bound(s).map(count)(Q, p, sig**2, C)
    nlp = {"x": ca.vertcat(a, eps, sig), "p": ca.vertcat(base, freq, ca.vec(Q), ca.vec(C)),
           "f": -sig, "g": ca.vec(g)}
    return Exclusive(ca.nlpsol("waves_region", "ipopt", nlp,
                               {**IPOPT, **budget.ipopt_stop(nlp)}))
