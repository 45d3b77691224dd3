"""Branch and bound over boxes: a proven lower bound of a function's minimum over a box.

A box's enclosure gives a proven lower bound of the function on the box and its value at
the centre (an upper bound of the minimum); a half keeps its parent's bound where its own
is lower, so the lowest bound never falls as the boxes are cut. The box with the lowest
bound is bisected along its widest side (measured against the first box) until one of:
- "certified": every box's bound reaches the target;
- "refuted": a centre's value is below the target (the target fails there);
- "decided" (no target): the lowest bound is within `rtol` of the smallest centre value;
- "undecided": the box cap or the deadline came first. The lowest bound still holds.
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

Enclosure = Callable[[np.ndarray, np.ndarray], tuple[float, float]]
"""(lower corner, upper corner) -> (proven lower bound on the box, value at its centre)."""

Status = Literal["certified", "refuted", "decided", "undecided"]


@dataclass(frozen=True)
class Bound:
    """What the branch and bound proved: `lower` holds on the whole box, `sampled` is the
    smallest centre value seen and `where` its point; `boxes` enclosures were evaluated in
    `seconds` of wall time."""

    lower: float
    sampled: float
    where: np.ndarray
    status: Status
    boxes: int
    seconds: float


def minimise(enclose: Enclosure, lo: np.ndarray, hi: np.ndarray, *, target: float | None,
             rtol: float, max_boxes: int, deadline: float | None = None) -> Bound:
    """Bound the minimum of a function over the box [lo, hi] (see the module's rules)."""
    start = time.perf_counter()
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    scale = np.where(hi > lo, hi - lo, 1.0)
    bound, value = enclose(lo, hi)
    best, where = value, (lo + hi) / 2
    heap = [(bound, 0, lo, hi)]
    count = 1
    while True:
        lowest = heap[0][0]
        status = _status(lowest, best, target, rtol)
        out_of_time = deadline is not None and time.monotonic() > deadline
        if status != "undecided" or count + 2 > max_boxes or out_of_time:
            return Bound(lowest, best, where, status, count, time.perf_counter() - start)
        parent, _, a, b = heapq.heappop(heap)
        for half in _halves(a, b, scale):
            bound, value = enclose(*half)
            bound = max(bound, parent)  # a half lies in its parent: the parent's bound holds
            count += 1
            if value < best:
                best, where = value, (half[0] + half[1]) / 2
            heapq.heappush(heap, (bound, count, *half))


def _status(lowest: float, best: float, target: float | None, rtol: float) -> Status:
    if target is not None:
        if best < target:
            return "refuted"
        return "certified" if lowest >= target else "undecided"
    return "decided" if lowest >= best * (1.0 - rtol) else "undecided"


def _halves(lo: np.ndarray, hi: np.ndarray,
            scale: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The two halves of a box across its widest side relative to `scale`."""
    axis = int(np.argmax((hi - lo) / scale))
    mid = (lo[axis] + hi[axis]) / 2
    left_hi, right_lo = hi.copy(), lo.copy()
    left_hi[axis] = right_lo[axis] = mid
    return (lo, left_hi), (right_lo, hi)
