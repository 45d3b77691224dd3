"""Error-controlled mesh refinement: where to cut the mesh so that the next plan is accurate.

The error of an interval of width h is modelled as C h^p, p the transcription's order
(`Transcription.order`). An interval whose error e exceeds the tolerance is cut into
m = ceil((e / target)^(1/p)) equal parts, target = SAFETY * tolerance, at least 2 and at
most MAX_SPLIT per pass (the model is rough far from convergence); intervals within the
tolerance are kept, but for those the coupling margin is not proven on (`cut`), which are
cut into MAX_SPLIT: the finer mesh's knots hold the margin where it dipped between them,
and a dip between knots shrinks as the square of their spacing. The number
of intervals is then rounded up to the next of `INTERVAL_STEPS`, the extra cuts going
where the model predicts the largest error, so that refined plans of different scenes
share built NLPs.
"""

from __future__ import annotations

import numpy as np

from planner.ocp.mesh import Mesh

SAFETY = 0.5
MAX_SPLIT = 4
INTERVAL_STEPS = tuple(int(round(m * 10**e)) for e in range(1, 4)
                       for m in (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8)) + (10000,)
"""Interval counts a refined mesh takes: 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100, ..."""


def _step_at_least(count: int) -> int:
    return next(step for step in INTERVAL_STEPS if step >= count)


def pieces(errors: np.ndarray, order: int, tolerance: float) -> np.ndarray:
    """How many parts each interval is cut into (1: kept)."""
    target = SAFETY * tolerance
    with np.errstate(over="ignore", invalid="ignore"):
        wanted = np.ceil((errors / target) ** (1.0 / order))
    cut = np.clip(np.nan_to_num(wanted, nan=MAX_SPLIT, posinf=MAX_SPLIT), 2, MAX_SPLIT)
    return np.where(errors > tolerance, cut, 1).astype(int)


def refined(mesh: Mesh, errors: np.ndarray, order: int, tolerance: float,
            max_intervals: int, cut: np.ndarray | None = None) -> Mesh | None:
    """The next mesh for interval errors (N,) [rad] and the intervals to cut into MAX_SPLIT
    (`cut`, (N,) bool), or None when every interval is within the tolerance and none is
    to be cut, or the refined mesh would exceed `max_intervals`."""
    cut = np.zeros(errors.shape, bool) if cut is None else cut
    if not np.any(errors > tolerance) and not cut.any():
        return None
    parts = np.where(cut, MAX_SPLIT, pieces(errors, order, tolerance))
    count = int(parts.sum())
    if count > max_intervals:
        return None
    predicted = np.nan_to_num(errors, posinf=np.finfo(float).max) / parts.astype(float)**order
    for _ in range(min(_step_at_least(count), max_intervals) - count):
        k = int(np.argmax(predicted))
        parts[k] += 1
        predicted[k] = errors[k] / parts[k]**order if np.isfinite(errors[k]) else predicted[k] / 2
    return mesh.split(parts)
