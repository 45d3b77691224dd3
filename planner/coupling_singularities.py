"""Singular points of M_pa among configurations, each refined to where M_pa loses rank.

Sign changes of det between neighbouring configurations (square blocks) are refined on
the straight segment between them by the block's root finder
(`planner.coupling_block.refine`, all segments at once); local minima of sigma_min below
the threshold by a local minimisation, within the point's box of neighbours (a grid) or
along the polyline through its neighbours (a path).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from planner import budget
from planner.coupling_block import along, refine
from planner.coupling_report import SingularPoint
from planner.model import Robot, Structure, parameters

MAX_SINGULAR = 1_000
"""Largest number of singular points a report refines and lists."""
_REFINING = "the refinement of singular point {} of {}"

Pairs = list[tuple[np.ndarray, np.ndarray]]
"""Neighbouring configurations: pairs of arrays of indices, one pair per axis (a path's
one)."""
Box = Callable[[int], tuple[np.ndarray, np.ndarray]]
"""The lower and upper corner (n,) of the box of configuration k's neighbours."""


def sign_changes(robot: Robot, s: Structure, Q: np.ndarray, det: np.ndarray,
                 pairs: Pairs, deadline: float | None = None) -> tuple[list[SingularPoint], int]:
    """Grid points with det = 0, and every sign change of det between neighbours refined
    on the straight segment between them (all edges at once, to machine precision).

    Returns at most MAX_SINGULAR points and the number left out."""
    zeros = np.flatnonzero(det == 0.0)
    lo = np.concatenate([a[det[a] * det[b] < 0.0] for a, b in pairs] or [np.empty(0, int)])
    hi = np.concatenate([b[det[a] * det[b] < 0.0] for a, b in pairs] or [np.empty(0, int)])
    skipped = max(len(zeros) + len(lo) - MAX_SINGULAR, 0)
    zeros = zeros[:MAX_SINGULAR]
    lo, hi = lo[:MAX_SINGULAR - len(zeros)], hi[:MAX_SINGULAR - len(zeros)]
    found = [_singular(robot, s, Q[k], "det-sign-change") for k in zeros]
    if len(lo) == 0:
        return found, skipped
    start, step = Q[lo], Q[hi] - Q[lo]
    u = refine(s, parameters(robot, s), lambda x, k: start[k] + x[:, None] * step[k],
               np.zeros(len(lo)), np.ones(len(lo)), deadline)
    points = start + u[:, None] * step
    m = along(robot, points, s, deadline)
    if m.det is None:
        raise ValueError("det M_pa needs a square coupling block")
    found += [SingularPoint(q=q.tolist(), det=float(d), sigma_min=float(a),
                            source="det-sign-change")
              for q, d, a in zip(points, m.det, m.sigma_min, strict=True)]
    return found, skipped


def _singular(robot: Robot, s: Structure, q: np.ndarray, source) -> SingularPoint:
    m = along(robot, q[None, :], s)
    return SingularPoint(q=q.tolist(), det=None if m.det is None else float(m.det[0]),
                         sigma_min=float(m.sigma_min[0]), source=source)


def _sigma_min(robot: Robot, s: Structure, q: np.ndarray) -> float:
    """sigma_min(M_pa) [kg m^2] at one configuration q (n,)."""
    return float(along(robot, q[None, :], s).sigma_min[0])


def local_minima(smin: np.ndarray, pairs: Pairs, threshold: float,
                 exclude: np.ndarray) -> np.ndarray:
    """Indices whose sigma_min is below threshold and not above any neighbour's."""
    is_min = smin < threshold
    for lo, hi in pairs:
        is_min[lo] &= smin[lo] <= smin[hi]
        is_min[hi] &= smin[hi] <= smin[lo]
    is_min &= ~exclude
    return np.flatnonzero(is_min)


def near_sign_change(det: np.ndarray | None, pairs: Pairs, size: int) -> np.ndarray:
    """Points at an edge across which det changes sign (already found by Brent)."""
    near = np.zeros(size, dtype=bool)
    if det is None:
        return near
    near[det == 0.0] = True
    for lo, hi in pairs:
        change = det[lo] * det[hi] < 0.0
        near[lo[change]] = True
        near[hi[change]] = True
    return near


def _refine_minimum(robot: Robot, s: Structure, lower: np.ndarray, upper: np.ndarray,
                    q0: np.ndarray, deadline: float | None, what: str) -> np.ndarray:
    """Local minimum of sigma_min in the box [lower, upper] around q0 (free axes only),
    the deadline checked at every evaluation (a minimisation takes up to thousands)."""
    free = upper > lower
    if not free.any():
        return q0

    def objective(x: np.ndarray | float) -> float:
        budget.check(deadline, what)
        q = q0.copy()
        q[free] = x
        return _sigma_min(robot, s, q)

    if free.sum() == 1:
        (i,) = np.flatnonzero(free)
        line = minimize_scalar(objective, bounds=(lower[i], upper[i]), method="bounded",
                               options={"xatol": 1e-12})
        x = np.array([line.x])
    else:
        res = minimize(objective, q0[free], method="Nelder-Mead",
                       bounds=list(zip(lower[free], upper[free], strict=True)),
                       options={"xatol": 1e-11, "fatol": 1e-15, "maxiter": 4000})
        x = np.asarray(res.x)
    q = q0.copy()
    q[free] = x
    return q


def minima_points(robot: Robot, s: Structure, Q: np.ndarray, idx: np.ndarray,
                  boxes: Box, deadline: float | None = None) -> list[SingularPoint]:
    found: list[SingularPoint] = []
    for k in idx:
        what = _REFINING.format(len(found), len(idx))
        budget.check(deadline, what)
        lower, upper = boxes(k)
        q = _refine_minimum(robot, s, lower, upper, Q[k], deadline, what)
        found.append(_singular(robot, s, q, "sigma-minimum"))
    return found


def path_minima(robot: Robot, s: Structure, Q: np.ndarray, idx: np.ndarray,
                deadline: float | None = None) -> list[SingularPoint]:
    """Refine local minima of sigma_min along the polyline through the configurations."""
    found: list[SingularPoint] = []
    K = len(Q)
    for k in idx:
        budget.check(deadline, _REFINING.format(len(found), len(idx)))
        prev, nxt = Q[max(k - 1, 0)], Q[min(k + 1, K - 1)]

        def point(u: float, k: int = k, prev: np.ndarray = prev,
                  nxt: np.ndarray = nxt) -> np.ndarray:
            return Q[k] + u * (Q[k] - prev) if u < 0 else Q[k] + u * (nxt - Q[k])

        res = minimize_scalar(lambda u: _sigma_min(robot, s, point(u)),
                              bounds=(-1.0, 1.0), method="bounded", options={"xatol": 1e-12})
        found.append(_singular(robot, s, point(float(res.x)), "sigma-minimum"))
    return found
