"""The design loop: screen the candidates, then from the best starts solve the NLP, check
it densely, and exchange samples until the check meets the NLP's bound; the best checked
design wins and is proven (`planner.certify`)."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from planner import budget
from planner.certify import CouplingCertificate
from planner.model import Robot
from planner.waves.certificate import EXCHANGE_TOL, Check
from planner.waves.motion import MotionProblem
from planner.waves.nlp import WHAT, wave_structure
from planner.waves.region import RegionProblem
from planner.waves.schemas import Status, WaveDesignRequest, WaveDesignResult, WaveSpec
from planner.waves.screening import Candidate, candidates, diverse, phases_per_joint

AMPLITUDE_FRACTION = 0.95
"""Largest amplitude as a fraction of the link length (r stays >= 5 % of l)."""
EXCHANGE_ROUNDS = 6
"""Largest number of NLP solves per starting point (exchange iterations)."""
STATUS: dict[str, Status] = {"certified": "certified", "refuted": "infeasible",
                             "undecided": "undecided"}
"""The design's status by its certificate's."""


class Problem(Protocol):
    """What the loop asks of the region or the motion problem."""

    SAMPLES: str
    """What the NLP's samples are, in words."""

    def screen(self, cands: list[Candidate]) -> list[float]:
        """A score per candidate: the larger, the better a start."""

    def optimise(self, c: Candidate, upper: np.ndarray) -> Candidate:
        """The NLP from c, amplitudes below `upper` [m]."""

    def check(self, c: Candidate) -> Check:
        """The dense check of c's waves."""

    def prove(self, c: Candidate, check: Check) -> tuple[CouplingCertificate, str]:
        """c's waves proven against the margin where `check` sampled, and how in words."""

    def exchange(self, check: Check) -> None:
        """Add samples where the check fell short."""


def design(request: WaveDesignRequest, *, deadline: float | None = None) -> WaveDesignResult:
    """Waves that keep sigma_min(M_pa) >= margin, proven over the region or along the
    motion ("certified"), refuted at a sample ("infeasible"), or neither ("undecided").

    Past `deadline` (a `time.monotonic()` value) it raises BudgetExceeded: between starts
    and exchange rounds, between chunks of evaluations, inside the inverse dynamics, and
    at the next Ipopt iteration."""
    with budget.part_of(WHAT):
        return _design(request, deadline)


def _design(request: WaveDesignRequest, deadline: float | None) -> WaveDesignResult:
    base = request.robot.without_waves()
    s = wave_structure(base)
    upper = np.array([min(request.amplitude_max, AMPLITUDE_FRACTION * base.links[j].length)
                      for j in base.active])
    kind = RegionProblem if request.region is not None else MotionProblem
    problem: Problem = kind(request, s, base, deadline)

    phases = phases_per_joint(len(upper))
    cands = candidates(len(upper), request.frequency_max, upper, phases)
    scores = problem.screen(cands)
    order = diverse(cands, scores, request.starts)

    best: tuple[Candidate, Check] | None = None
    for i, k in enumerate(order):
        budget.check(deadline, f"{WHAT} (after {i} of {len(order)} starts)")
        start = cands[k]
        start.bound = float(scores[k])
        floor = max(request.margin, best[1].sampled if best else -math.inf)
        c, check = _exchange(problem, start, upper, floor)
        if check.beats(best[1] if best else None):
            best = (c, check)
    assert best is not None  # starts >= 1, and the first check beats None
    c, check = best
    certificate, proof = problem.prove(c, check)
    method = (f"From the {len(order)} best of {len(cands)} screened starts (integer "
              f"frequencies 1..{request.frequency_max}, {phases} phases "
              f"per joint), Ipopt maximised a lower bound on sigma_min(M_pa) at the "
              f"{problem.SAMPLES}; checked: {check.describe}; {proof}.")
    return WaveDesignResult(status=STATUS[certificate.status], waves=_specs(c, base),
                            certified_sigma_min=certificate.bound, certificate=certificate,
                            method=method, robot=c.robot(base))


def _specs(c: Candidate, base: Robot) -> list[WaveSpec]:
    """The candidate's waves on the base robot's active joints."""
    return [WaveSpec(joint=j, amplitude=float(a), frequency=int(n), phase=float(e))
            for j, a, n, e in zip(base.active, c.amplitude, c.frequency, c.phase, strict=True)]


def _exchange(problem: Problem, start: Candidate, upper: np.ndarray,
              floor: float) -> tuple[Candidate, Check]:
    """Solve the NLP, check, add the failing samples, solve again; keep the best checked.

    Stops early when the NLP's bound falls below `floor` (the margin, or the best value
    checked so far): more samples would only lower it further."""
    c, previous = start, math.inf
    best: tuple[Candidate, Check] | None = None
    for _ in range(EXCHANGE_ROUNDS):
        c = problem.optimise(c, upper)
        check = problem.check(c)
        if check.beats(best[1] if best else None):
            best = (c, check)
        stalled = c.bound > previous * (1 - EXCHANGE_TOL)  # the added samples changed nothing
        if check.converged or not c.solved or stalled or c.bound < floor:
            break
        previous = c.bound
        problem.exchange(check)
    assert best is not None  # the first round's check beats None
    return best
