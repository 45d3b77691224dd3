"""The region problem: keep sigma_min(M_pa) >= s over a box of configurations.

Samples: a coarse grid of the box, joined by the dense grid's worst points at every
exchange. Check: sigma_min on a dense grid. Proof: `planner.certify.region` over the
whole box.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np

from planner import budget
from planner.certify import PROOF_RTOL, Bound, CouplingCertificate, decide, region
from planner.coupling_block import evaluate, measures
from planner.dynamics import derive
from planner.exclusive import Exclusive
from planner.model import Robot, Structure, parameters
from planner.waves.certificate import EXCHANGE_TOL, Check
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

REGION_BOXES = 4_000
"""Boxes the proof over a region may take before it is undecided (about 3 s on the seed's
4-link arm over a box in all four joints)."""


class RegionProblem:
    """Keep sigma_min >= s over a box: samples, NLP, dense-grid check and proof."""

    SAMPLES = "grid points of the box, joined by the dense grid's worst points"

    def __init__(self, request: WaveDesignRequest, s: Structure, base: Robot,
                 deadline: float | None = None):
        self.s, self.base, self.deadline = s, base, deadline
        self.p = parameters(base, s)
        if request.region is None:
            raise ValueError("a region design needs request.region")
        lower, upper = np.array(request.region.lower), np.array(request.region.upper)
        self.lower, self.upper, self.margin = lower, upper, request.margin
        self.free = np.flatnonzero(upper > lower)
        d = max(len(self.free), 1)
        coarse = coarse_points(len(self.free))
        self.samples = _box_grid(lower, upper, coarse)
        points = request.certification_points or 40_000
        self.dense_points = max(3, int(points ** (1 / d)))
        if self.dense_points == coarse:
            self.dense_points += 1
        self.dense = _box_grid(lower, upper, self.dense_points)

    def screen(self, cands: list[Candidate]) -> list[float]:
        """Smallest sigma_min over the samples of each candidate."""
        K = len(self.samples)
        Q = np.tile(self.samples, (len(cands), 1))
        P = np.repeat(params(self.s, self.p, cands), K, axis=0)
        smin = measures(evaluate(self.s, Q, P, self.deadline)).sigma_min
        return list(smin.reshape(len(cands), K).min(axis=1))

    def optimise(self, c: Candidate, upper: np.ndarray) -> Candidate:
        solver = _region_nlp(self.s, len(self.samples))
        x0 = np.concatenate([c.amplitude, c.phase, [max(c.bound, 0.0)]])
        p = params(self.s, self.p, [c])[0]
        C = normalisers(evaluate(self.s, self.samples, p, self.deadline))
        par = np.concatenate([self.p, c.frequency, self.samples.ravel(), C.ravel()])
        sol, stats = solver(self.deadline, WHAT, x0=x0, p=par, lbx=lbx(upper),
                            ubx=ubx(upper), lbg=0.0, ubg=np.inf)
        x = np.array(sol["x"]).ravel()
        return candidate_from(stats, x, c, upper)

    def check(self, c: Candidate) -> Check:
        """sigma_min on the dense grid."""
        p = params(self.s, self.p, [c])[0]
        smin = measures(evaluate(self.s, self.dense, p, self.deadline)).sigma_min
        order = np.argsort(smin)[:8]
        converged = smin.min() >= c.bound * (1 - EXCHANGE_TOL)
        shape = " x ".join(str(self.dense_points) for _ in self.free)
        describe = (f"sigma_min evaluated on a dense {shape} grid of the region "
                    f"({len(self.dense):,} points, independent of the {len(self.samples)} "
                    f"optimisation samples)"
                    ) if len(self.free) else "sigma_min evaluated at the region's single point"
        return Check(float(smin.min()), bool(converged), describe, self.dense[order])

    def prove(self, c: Candidate, check: Check) -> tuple[CouplingCertificate, str]:
        """sigma_min proven over the whole box, and how in words."""
        robot = c.robot(self.base)

        def run(target: float | None) -> Bound:
            return region(robot, self.lower, self.upper, target=target, rtol=PROOF_RTOL,
                          max_boxes=REGION_BOXES, deadline=self.deadline)
        cert = decide(run, self.margin, check.sampled)
        return cert, (f"proven over the whole region by ball arithmetic on M_pa, branch and "
                      f"bound in {cert.boxes:,} boxes ({cert.seconds:.2g} s)")

    def exchange(self, check: Check) -> None:
        self.samples = np.vstack([self.samples, check.worst])


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
