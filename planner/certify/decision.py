"""Whether sigma_least(M_pa) keeps a target, as the wave design and the co-design report it.

`decide` runs a proof (`region` or `path`, as a function of its target) first without a
target: the bound then tightens until it is within the proof's rtol of the smallest
sampled value or the box cap (or deadline) stops it. The target is read off that bound:
certified when the proven bound reaches it, refuted when a sampled value falls below it,
undecided otherwise. Both kinds of run cut the same boxes in the same order (the lowest
bound first, and that bound never falls), so a run stopped by its cap with the target
between bound and samples would have stopped there with the target too; only when the
bound stopped within rtol of the samples is the proof run again for the target itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from planner.certify.boxes import Bound

PROOF_RTOL = 0.05
"""The rtol the wave design and the co-design give their proofs: the boxes are cut until
the bound is within this fraction of the smallest sampled value (or the target is settled,
or the box cap or the deadline stops them)."""

Run = Callable[[float | None], Bound]
"""A proof as a function of its target [kg m^2] (None: tighten within rtol)."""


class CouplingCertificate(BaseModel):
    """sigma_min(M_pa) proven over a whole region or along a whole motion, against a
    target (ball arithmetic on M_pa, branch and bound over boxes; docs/model.md, "Proven
    coupling margins")."""

    model_config = ConfigDict(frozen=True)

    bound: float = Field(description="[kg m^2] proven: sigma_min(M_pa) is at least this "
                                     "everywhere it covers (0 where nothing is proven)")
    sampled_min: float | None = Field(
        description="[kg m^2] the smallest sigma_min(M_pa) evaluated, at the dense samples "
                    "and the centres of the proof's boxes: the true minimum lies between "
                    "bound and sampled_min (None: the deadline came before any sample)")
    target: float = Field(description="[kg m^2] what the bound must reach")
    status: Literal["certified", "refuted", "undecided"] = Field(
        description="certified: bound >= target; refuted: sampled_min < target (the target "
                    "fails there); undecided: neither, within the box cap or the deadline")
    boxes: int = Field(description="enclosures evaluated (boxes of the region, pieces of "
                                   "the motion's intervals)")
    seconds: float = Field(description="[s] wall time of the proof")


def decide(run: Run, target: float, sampled: float = math.inf) -> CouplingCertificate:
    """The certificate of `run` against `target` [kg m^2]; `sampled` is the least value
    sampled elsewhere (a dense check) [kg m^2]."""
    first = run(None)
    low, seen = first.lower, min(first.sampled, sampled)
    boxes, seconds = first.boxes, first.seconds
    if first.status == "decided" and low < target <= seen:
        again = run(target)
        low, seen = max(low, again.lower), min(seen, again.sampled)
        boxes, seconds = boxes + again.boxes, seconds + again.seconds
    status: Literal["certified", "refuted", "undecided"] = (
        "certified" if low >= target else "refuted" if seen < target else "undecided")
    return CouplingCertificate(bound=max(low, 0.0),
                               sampled_min=seen if math.isfinite(seen) else None,
                               target=target,
                               status=status, boxes=boxes, seconds=seconds)
