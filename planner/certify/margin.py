"""Proven lower bounds of the coupling margin sigma_least(M_pa) over a box of
configurations, and along a piecewise polynomial motion interval by interval.

M_pa is enclosed over a box by running its CasADi expression graph in ball arithmetic
(`ball`), bounded below by Weyl's inequality (`singular`), and the boxes are cut until the
bound decides (`boxes`). Along a motion each interval's polynomial q(s), s in [0, 1], is
itself evaluated on balls of s, so the bound holds between every pair of samples.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from flint import arb

from planner.certify.ball import BallFunction
from planner.certify.boxes import Bound, Status, minimise
from planner.certify.singular import least_lower
from planner.coupling_block import block_function, block_jacobian
from planner.margin_rows import margin_function
from planner.model import Robot, Structure, parameters

if TYPE_CHECKING:  # planner.ocp imports the planner, which proves its margin with these
    from planner.ocp.interpolant import PiecewisePolynomial

RTOL = 0.01
"""Without a target, the bound is decided when within this fraction of the sampled minimum."""
REGION_BOXES = 20_000
"""Boxes a region may take before it is undecided."""
INTERVAL_BOXES = 200
"""Boxes one interval of a motion may take before it is undecided."""


@lru_cache(maxsize=64)
def _functions(s: Structure) -> tuple[BallFunction, BallFunction]:
    """M_pa(q, p) and d vec(M_pa) / dq of a structure on balls."""
    return BallFunction(block_function(s)), BallFunction(block_jacobian(s))


@lru_cache(maxsize=64)
def _rows(s: Structure) -> tuple[BallFunction, BallFunction]:
    """The margin's rows (`planner.margin_rows`) and their Jacobian in q on balls."""
    f = margin_function(s)
    args = [f.sx_in(i) for i in range(f.n_in())]
    rows = f(*args)
    return (BallFunction(ca.Function("rows", args, [rows])),
            BallFunction(ca.Function("drows", args, [ca.jacobian(rows, args[0])])))


@dataclass(frozen=True)
class Piece:
    """A piece of an interval of a motion q(s): dq/ds over it (n balls), s - s_c over it
    (a ball) and q(s_c) (n balls holding the exact value at the piece's centre s_c)."""

    tangent: list[arb]
    step: arb
    centre: list[arb]


class Block:
    """Enclosures of M_pa (r x c) [kg m^2] of one robot over boxes of configurations."""

    def __init__(self, robot: Robot):
        s = Structure.of(robot)
        self.value, self.jacobian = _functions(s)
        self.rows, self.row_slopes = _rows(s)
        self.square = len(robot.passive) == len(robot.active)
        self.p = [arb(float(x)) for x in parameters(robot, s)]

    def at(self, q: np.ndarray) -> list[list[arb]]:
        """M_pa at one configuration q (n,) [rad] (balls of rounding width)."""
        return self.value([[arb(float(x)) for x in q], self.p])[0]

    def over(self, box: list[arb], centre: np.ndarray) -> tuple[list[list[arb]], float]:
        """Enclosure of M_pa over the configurations in `box` (n balls [rad]) joined to
        `centre` (n,): the intersection of the direct enclosure and the mean-value form
        M_pa(centre) + sum_i dM_pa/dq_i(box) (q_i - centre_i), which is tighter on small
        boxes; and sigma_least at the centre (a float, not a bound)."""
        box = [b.union(arb(float(c))) for b, c in zip(box, centre, strict=True)]
        direct = self.value([box, self.p])[0]
        mid = self.at(centre)
        slopes = self.jacobian([box, self.p])[0]  # (r c) x n, column-major vec
        shifts = [b - arb(float(c)) for b, c in zip(box, centre, strict=True)]
        rows = len(mid)
        out = []
        for i, row in enumerate(direct):
            line = []
            for j, entry in enumerate(row):
                form = mid[i][j]
                for slope, shift in zip(slopes[j * rows + i], shifts, strict=True):
                    form += slope * shift
                line.append(entry.intersection(form))
            out.append(line)
        return out, _least(mid)


    def keeps(self, box: list[arb], centre: np.ndarray, target: float,
              along: Piece | None = None) -> bool:
        """Whether sigma_least(M_pa) >= target is proven on the box (n balls [rad], joined
        to `centre` (n,)): every margin row, in the mean-value form row(centre) +
        sum_i drow/dq_i(box) (q_i - centre_i), is positive, the sign of a square block's
        determinant taken at the centre. On a piece of a motion q(s), `along` makes it the
        form in s, row(q(s_c)) + (sum_i drow/dq_i(box) dq_i/ds(piece)) (s - s_c): where the motion
        keeps sigma_least nearly constant, that derivative nearly vanishes while M_pa and
        the rows' gradient do not, so this decides on pieces far wider than Weyl's bound
        needs."""
        box = [b.union(arb(float(c))) for b, c in zip(box, centre, strict=True)]
        mid = np.array([[float(b.mid()) for b in row] for row in self.at(centre)])
        sign = 1.0 if not self.square or np.linalg.det(mid) >= 0 else -1.0
        extra = [[arb(target)], [arb(sign)]]
        point = [arb(float(c)) for c in centre] if along is None else along.centre
        at = self.rows([point, self.p, *extra])[0]
        slopes = self.row_slopes([box, self.p, *extra])[0]
        shifts = [b - arb(float(c)) for b, c in zip(box, centre, strict=True)]
        for value, row in zip(at, slopes, strict=True):
            if along is None:
                form = value[0] + sum((g * d for g, d in zip(row, shifts, strict=True)), arb(0))
            else:
                rate = sum((g * d for g, d in zip(row, along.tangent, strict=True)), arb(0))
                form = value[0] + rate * along.step
            if not form > 0:
                return False
        return True


def _proven(m: Block, box: list[arb], centre: np.ndarray, target: float | None,
            along: Piece | None = None) -> tuple[float, float]:
    """A proven lower bound of sigma_least(M_pa) on the box (Weyl's, or the target where
    the margin's rows prove it; `along` as in `Block.keeps`) and sigma_least at the
    centre."""
    enclosure, value = m.over(box, centre)
    bound = least_lower(enclosure)
    if target is not None and bound < target and m.keeps(box, centre, target, along):
        return target, value
    return bound, value


def _balls(lo: np.ndarray, hi: np.ndarray) -> list[arb]:
    """The smallest balls arb gives that hold [lo_i, hi_i]."""
    return [arb(float(a)).union(arb(float(b))) for a, b in zip(lo, hi, strict=True)]


def _least(values: list[list[arb]]) -> float:
    """sigma_least of the midpoint matrix (a float, not a bound)."""
    a = np.array([[float(b.mid()) for b in row] for row in values])
    return float(np.linalg.svd(a, compute_uv=False)[-1])


def region(robot: Robot, lower, upper, *, target: float | None = None, rtol: float = RTOL,
           max_boxes: int = REGION_BOXES, deadline: float | None = None) -> Bound:
    """Bound sigma_least(M_pa(q)) [kg m^2] below over the box lower <= q <= upper (n,)
    [rad] (see `boxes.minimise` for target, rtol and the status)."""
    m = Block(robot)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    free = np.flatnonzero(upper > lower)

    def enclose(lo: np.ndarray, hi: np.ndarray) -> tuple[float, float]:
        qlo, qhi = lower.copy(), upper.copy()
        qlo[free], qhi[free] = lo, hi
        return _proven(m, _balls(qlo, qhi), (qlo + qhi) / 2, target)

    if not len(free):
        bound, value = enclose(lower[free], upper[free])
        return Bound(bound, value, lower, "certified" if target is not None and bound >= target
                     else "decided", 1, 0.0)
    return minimise(enclose, lower[free], upper[free], target=target, rtol=rtol,
                    max_boxes=max_boxes, deadline=deadline)


def _horner(coeffs: np.ndarray, s: arb) -> list[arb]:
    """q(s) on a ball s for ascending coefficients (m, n)."""
    out = [arb(0)] * coeffs.shape[1]
    for row in coeffs[::-1]:
        out = [o * s + arb(float(c)) for o, c in zip(out, row, strict=True)]
    return out


def along(robot: Robot, q: PiecewisePolynomial, *, target: float | None = None,
          rtol: float = RTOL, max_boxes: int = INTERVAL_BOXES,
          deadline: float | None = None) -> list[Bound]:
    """Bound sigma_least(M_pa(q(t))) below on every interval of a piecewise polynomial
    q (coefficients (K, m, n) in s in [0, 1]): one Bound per interval, its `where` the
    fraction s of the interval's smallest sampled value. Past `deadline`
    (time.monotonic()) an interval is not evaluated: lower 0, nothing sampled (inf),
    undecided, 0 boxes."""
    m = Block(robot)
    out = []
    for coeffs in q.coeffs:
        if deadline is not None and time.monotonic() > deadline:
            out.append(Bound(0.0, math.inf, np.array([0.5]), "undecided", 0, 0.0))
            continue

        def enclose(lo: np.ndarray, hi: np.ndarray, c: np.ndarray = coeffs) -> tuple[float, float]:
            s, mid = _balls(lo, hi)[0], float(lo[0] + hi[0]) / 2
            centre = np.array([float(v.mid()) for v in _horner(c, arb(mid))])
            rate = c[1:] * np.arange(1, len(c))[:, None]  # dq/ds, ascending
            piece = Piece(_horner(rate, s), s - arb(mid), _horner(c, arb(mid)))
            return _proven(m, _horner(c, s), centre, target, piece if len(rate) else None)
        out.append(minimise(enclose, np.zeros(1), np.ones(1), target=target, rtol=rtol,
                            max_boxes=max_boxes, deadline=deadline))
    return out


def path(robot: Robot, q: PiecewisePolynomial, *, target: float | None = None,
         rtol: float = RTOL, max_boxes: int = INTERVAL_BOXES,
         deadline: float | None = None) -> Bound:
    """`along`, joined over the whole motion: the least interval bound and sampled value,
    `where` the time [s] of that value, the boxes summed and the whole wall time [s].
    Refuted when an interval is, certified (decided) when every interval is, else
    undecided."""
    started = time.perf_counter()
    bounds = along(robot, q, target=target, rtol=rtol, max_boxes=max_boxes,
                   deadline=deadline)
    k = int(np.argmin([b.sampled for b in bounds]))
    h = q.breaks[k + 1] - q.breaks[k]
    statuses = {b.status for b in bounds}
    status: Status = ("refuted" if "refuted" in statuses else
                      statuses.pop() if len(statuses) == 1 else "undecided")
    return Bound(min(b.lower for b in bounds), bounds[k].sampled,
                 np.array([q.breaks[k] + h * float(bounds[k].where[0])]), status,
                 sum(b.boxes for b in bounds), time.perf_counter() - started)
