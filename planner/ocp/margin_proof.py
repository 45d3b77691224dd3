"""The coupling margin proven on whole intervals of a plan, not only at its samples.

The NLP holds sigma_least(M_pa) >= m at its knots; between them the configurations follow
each interval's polynomial and the margin may dip. `prove` bounds sigma_least below on
every interval of the delivered q(t) in ball arithmetic (`planner.certify.along`). An
interval is proven when its bound reaches m (1 - MARGIN_RTOL); one that is refuted (a
sample below that) or undecided within the boxes is cut by the mesh refinement, whose
finer mesh puts knots where the margin dipped, and a plan with such an interval is not
verified.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from planner.certify import Bound, along
from planner.model import Robot
from planner.ocp.transcription import Interpolant
from planner.ocp.verification import MarginCertificate

MARGIN_RTOL = 1e-3
"""A plan keeps the margin m where sigma_least is at least m (1 - MARGIN_RTOL), proven on
every interval. A margin that binds at the knots dips between them by O(h^2), and the
proven bound approaches a minimum only linearly in the boxes' width: without a relative
tolerance, no binding margin would ever be proven."""
BOXES = 200
"""Boxes an interval may take before it is undecided."""


@dataclass(frozen=True)
class MarginProof:
    """Per interval of a plan (K,): the proven bounds, for the margin [kg m^2]."""

    margin: float
    bounds: list[Bound]
    seconds: float

    @property
    def target(self) -> float:
        return self.margin * (1.0 - MARGIN_RTOL)

    def unproven(self) -> np.ndarray:
        """(K,) bool: the intervals where the margin is not proven."""
        return np.array([b.status != "certified" for b in self.bounds], dtype=bool)

    def certificate(self) -> MarginCertificate:
        """What the proof says, for the plan's verification."""
        bad = [k for k, b in enumerate(self.bounds) if b.status != "certified"]
        seen = min(b.sampled for b in self.bounds)
        refuted = any(self.bounds[k].status == "refuted" for k in bad)
        return MarginCertificate(
            bound=max(min(b.lower for b in self.bounds), 0.0),
            sampled_min=seen if math.isfinite(seen) else None,
            target=self.target,
            status="refuted" if refuted else "undecided" if bad else "certified",
            unproven_intervals=bad, boxes=sum(b.boxes for b in self.bounds),
            seconds=self.seconds)

    def violation(self, breaks: np.ndarray) -> str | None:
        """The proof's failure in words (None when every interval is proven)."""
        bad = np.flatnonzero(self.unproven())
        if not bad.size:
            return None
        k = int(min(bad, key=lambda i: self.bounds[i].sampled))
        b = self.bounds[k]
        t = breaks[k] + float(b.where[0]) * (breaks[k + 1] - breaks[k])
        if b.status == "refuted":
            return (f"sigma_min(M_pa) falls to {b.sampled:.6g} at t = {t:.4g} s, between "
                    f"the plan's samples, below the task's coupling margin of "
                    f"{self.margin:g} (proven on {len(self.bounds) - bad.size} of "
                    f"{len(self.bounds)} intervals)")
        return (f"the coupling margin of {self.margin:g} is not proven on {bad.size} of "
                f"{len(self.bounds)} intervals: on interval {k} sigma_min(M_pa) is only "
                f"proven above {max(b.lower, 0.0):.6g} after {b.boxes} boxes")


def prove(robot: Robot, interp: Interpolant, margin: float | None,
          deadline: float | None = None) -> MarginProof | None:
    """Prove the margin [kg m^2] on every interval of the plan's angles (None without a
    margin or without passive joints). Past `deadline` (time.perf_counter() seconds) the
    intervals left are undecided."""
    if margin is None or not robot.passive:
        return None
    started = time.perf_counter()
    until = None if deadline is None else time.monotonic() + (deadline - started)
    bounds = along(robot, interp.q, target=margin * (1.0 - MARGIN_RTOL), max_boxes=BOXES,
                   deadline=until)
    return MarginProof(margin, bounds, time.perf_counter() - started)
