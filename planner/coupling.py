"""Inertial coupling analysis: det, sigma_min and condition of M_pa over many configurations.

M_pa(q) is the block of the mass matrix with the passive joints' rows and the active
joints' columns [kg m^2]. Prescribing the passive motion needs M_pa of full row rank;
configurations where it loses rank are inertial coupling singularities.

The block and its measures are evaluated in batches by `planner.coupling_block`.
Singular points are found by sign changes of det between neighbouring configurations
(square blocks), refined on the straight segment between them by the block's root
finder (`planner.coupling_block.refine`, all segments at once), and by local minima of
sigma_min below the threshold, refined by a local minimisation.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, model_validator
from scipy.optimize import minimize, minimize_scalar

from planner import budget
from planner.coupling_block import along, condition, refine
from planner.errors import InputError
from planner.model import Robot, Structure, parameters
from planner.schema import REQUEST as _STRICT
from planner.schema import Angle

MAX_POINTS = 200_000
"""Largest number of configurations one request may evaluate."""
MAX_RESULTS = 20_000
"""Largest number of per-configuration results a report lists (the rest are counted)."""
MAX_SINGULAR = 1_000
"""Largest number of singular points a report refines and lists."""
_REFINING = "the refinement of singular point {} of {}"


SplitKind = Literal["square", "fewer-active", "more-active"]


# --------------------------------------------------------------------------- requests


class Grid(BaseModel):
    """A box of configurations [rad]: `points` per axis (one number for all axes, or one
    per joint); an axis with lower == upper is a single point."""

    model_config = _STRICT

    lower: list[Angle] = Field(min_length=1, description="lower corner, one angle per joint [rad]")
    upper: list[Angle] = Field(min_length=1, description="upper corner, one angle per joint [rad]")
    points: int | list[int] = Field(
        default=51, description="grid points per axis (>= 2 where lower < upper)")

    @model_validator(mode="after")
    def _consistent(self) -> Grid:
        if len(self.upper) != len(self.lower):
            raise ValueError(f"upper: needs {len(self.lower)} entries, as many as lower")
        if any(u < lo for lo, u in zip(self.lower, self.upper, strict=True)):
            raise ValueError("upper: every entry must be >= the matching entry of lower")
        counts = self._requested()
        if len(counts) != len(self.lower):
            raise ValueError(f"points: needs 1 or {len(self.lower)} entries")
        if any(c < 1 or (c < 2 and u > lo)
               for c, lo, u in zip(counts, self.lower, self.upper, strict=True)):
            raise ValueError("points: an axis with lower < upper needs at least 2 points")
        return self

    def _requested(self) -> list[int]:
        """`points` as one count per axis."""
        return self.points if isinstance(self.points, list) else [self.points] * len(self.lower)

    def counts(self) -> list[int]:
        """Points of every axis (1 on a degenerate axis), computed without building the axes."""
        return [1 if u == lo else c
                for lo, u, c in zip(self.lower, self.upper, self._requested(), strict=True)]

    def axes(self) -> list[np.ndarray]:
        """Grid coordinates of every axis; a degenerate axis holds its single value."""
        return [np.array([lo]) if c == 1 else np.linspace(lo, u, c)
                for lo, u, c in zip(self.lower, self.upper, self.counts(), strict=True)]

    @property
    def size(self) -> int:
        """Number of grid points (arithmetic: nothing is allocated, whatever the request)."""
        return math.prod(self.counts())


class CouplingRequest(BaseModel):
    """Configurations to analyse: an explicit list (read as a path) or a grid box."""

    model_config = _STRICT

    robot: Robot
    configurations: list[list[Angle]] | None = Field(
        default=None, description="joint angles [rad], one row per configuration; "
                                  "consecutive rows are joined by straight segments")
    grid: Grid | None = None
    threshold: float = Field(
        default=1e-3, ge=0.0,
        description="local minima of sigma_min below this [kg m^2] are reported as singular")

    @model_validator(mode="after")
    def _consistent(self) -> CouplingRequest:
        check_split(self.robot)
        n = self.robot.n
        if (self.configurations is None) == (self.grid is None):
            raise ValueError("configurations: give exactly one of configurations and grid")
        if self.configurations is not None:
            if not self.configurations:
                raise ValueError("configurations: needs at least one configuration")
            if len(self.configurations) > MAX_POINTS:
                raise ValueError(f"configurations: {len(self.configurations):,} exceed the "
                                 f"limit of {MAX_POINTS:,}")
            if any(len(row) != n for row in self.configurations):
                raise ValueError(f"configurations: every row needs {n} entries, one per joint")
        elif self.grid is not None:  # (the other of the two)
            if len(self.grid.lower) != n:
                raise ValueError(f"grid.lower: needs {n} entries, one per joint")
            if self.grid.size > MAX_POINTS:
                raise ValueError(f"grid.points: {self.grid.size:,} points exceed the limit of "
                                 f"{MAX_POINTS:,}; use fewer points per axis")
        return self


def check_split(robot: Robot) -> None:
    """Raise InputError when the robot has no coupling block (no passive joint)."""
    if not robot.passive:
        raise InputError("robot: has no passive joint, so there is no coupling block "
                         "(the arm is fully actuated)")


# --------------------------------------------------------------------------- results


class Split(BaseModel):
    """Passive and active joints (0-based) and the shape of M_pa."""

    passive: list[int]
    active: list[int]
    kind: SplitKind
    note: str


class PointResult(BaseModel):
    """Coupling measures at one configuration; det only for a square block, condition
    None where sigma_min is zero."""

    q: list[float]
    det: float | None
    sigma_min: float
    condition: float | None


class SingularPoint(BaseModel):
    """A configuration where M_pa loses rank (refined sign change of det) or sigma_min has
    a local minimum below the threshold."""

    q: list[float]
    det: float | None
    sigma_min: float
    source: Literal["det-sign-change", "sigma-minimum"]


class MinSigma(BaseModel):
    """Smallest sigma_min met [kg m^2] and where."""

    q: list[float]
    sigma_min: float


class CouplingReport(BaseModel):
    """Coupling measures at every configuration, the singular points and the minimum.

    For grids larger than MAX_RESULTS points `results` is empty and `results_omitted`
    counts the points left out (the singular points and the minimum are still complete).
    Grid results are listed in row-major order (the last joint varies fastest).
    """

    split: Split
    results: list[PointResult]
    results_omitted: int = 0
    singular_points: list[SingularPoint]
    singular_points_omitted: int = 0
    min_sigma: MinSigma


def split_of(robot: Robot) -> Split:
    """Classify M_pa: square, fewer active than passive joints, or more."""
    passive, active = robot.passive, robot.active
    if len(active) == len(passive):
        kind: SplitKind = "square"
        note = (f"M_pa is {len(passive)} x {len(active)}: the active accelerations follow "
                "uniquely from the passive motion where det M_pa != 0")
    elif len(active) < len(passive):
        kind = "fewer-active"
        note = (f"only {len(active)} active joints for {len(passive)} passive: M_pa cannot "
                "have full row rank, so the passive motion cannot be prescribed in full "
                "(sigma_min is 0 everywhere)")
    else:
        kind = "more-active"
        note = (f"{len(active)} active joints for {len(passive)} passive: the inverse "
                "dynamics uses the minimum-norm active accelerations; singular where "
                "M_pa loses row rank (sigma_min = 0)")
    return Split(passive=passive, active=active, kind=kind, note=note)


# --------------------------------------------------------------------------- singular points


def _edges(shape: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pairs of flat indices of neighbouring grid points, one pair of arrays per axis."""
    index = np.arange(math.prod(shape)).reshape(shape)
    pairs = []
    for axis, length in enumerate(shape):
        if length < 2:
            continue
        lo = np.take(index, np.arange(length - 1), axis=axis).ravel()
        hi = np.take(index, np.arange(1, length), axis=axis).ravel()
        pairs.append((lo, hi))
    return pairs


def _sign_changes(robot: Robot, s: Structure, Q: np.ndarray, det: np.ndarray,
                  pairs, deadline: float | None = None) -> tuple[list[SingularPoint], int]:
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
    m = along(robot, points, s)
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


def _local_minima(smin: np.ndarray, pairs, threshold: float, exclude: np.ndarray) -> np.ndarray:
    """Indices whose sigma_min is below threshold and not above any neighbour's."""
    is_min = smin < threshold
    for lo, hi in pairs:
        is_min[lo] &= smin[lo] <= smin[hi]
        is_min[hi] &= smin[hi] <= smin[lo]
    is_min &= ~exclude
    return np.flatnonzero(is_min)


def _near_sign_change(det: np.ndarray | None, pairs, size: int) -> np.ndarray:
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
                    q0: np.ndarray) -> np.ndarray:
    """Local minimum of sigma_min in the box [lower, upper] around q0 (free axes only)."""
    free = upper > lower
    if not free.any():
        return q0

    def objective(x: np.ndarray | float) -> float:
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


def _minima_points(robot: Robot, s: Structure, Q: np.ndarray, idx: np.ndarray,
                   boxes, deadline: float | None = None) -> list[SingularPoint]:
    found: list[SingularPoint] = []
    for k in idx:
        budget.check(deadline, _REFINING.format(len(found), len(idx)))
        lower, upper = boxes(k)
        q = _refine_minimum(robot, s, lower, upper, Q[k])
        found.append(_singular(robot, s, q, "sigma-minimum"))
    return found


# --------------------------------------------------------------------------- analysis


def _points(request: CouplingRequest):
    """Configurations (K, n), neighbour pairs, and the local box of each point."""
    if request.configurations is not None:
        Q = np.asarray(request.configurations, dtype=float)
        K = len(Q)
        pairs = [(np.arange(K - 1), np.arange(1, K))] if K > 1 else []

        def path_box(k: int) -> tuple[np.ndarray, np.ndarray]:
            lo, hi = Q[max(k - 1, 0)], Q[min(k + 1, K - 1)]
            return np.minimum(lo, hi), np.maximum(lo, hi)
        return Q, pairs, path_box, True

    grid = request.grid
    if grid is None:
        raise ValueError("configurations: give exactly one of configurations and grid")
    axes = grid.axes()
    shape = tuple(len(axis) for axis in axes)
    mesh = np.meshgrid(*axes, indexing="ij")
    Q = np.stack([m.ravel() for m in mesh], axis=1)
    steps = np.array([axis[1] - axis[0] if len(axis) > 1 else 0.0 for axis in axes])
    lower_all, upper_all = np.array(grid.lower), np.array(grid.upper)

    def grid_box(k: int) -> tuple[np.ndarray, np.ndarray]:
        return (np.maximum(Q[k] - steps, lower_all), np.minimum(Q[k] + steps, upper_all))
    return Q, _edges(shape), grid_box, False


def analyse(request: CouplingRequest, *, deadline: float | None = None) -> CouplingReport:
    """det, sigma_min and condition of M_pa at the requested configurations, the singular
    points between them, and the smallest sigma_min met (BudgetExceeded past `deadline`,
    a `time.monotonic()` value)."""
    with budget.part_of("the coupling analysis"):
        return _analyse(request, deadline)


def _analyse(request: CouplingRequest, deadline: float | None) -> CouplingReport:
    robot = request.robot
    s = Structure.of(robot)
    split = split_of(robot)
    Q, pairs, boxes, is_path = _points(request)
    m = along(robot, Q, s, deadline)
    det, smin = m.det, m.sigma_min

    singular: list[SingularPoint] = []
    omitted = 0
    if split.kind != "fewer-active":
        if det is not None:
            singular, omitted = _sign_changes(robot, s, Q, det, pairs, deadline)
        near = _near_sign_change(det, pairs, len(Q))
        idx = _local_minima(smin.copy(), pairs, request.threshold, near)
        room = MAX_SINGULAR - len(singular)
        omitted += max(len(idx) - room, 0)
        if is_path:
            singular += _path_minima(robot, s, Q, idx[:room], deadline)
        else:
            singular += _minima_points(robot, s, Q, idx[:room], boxes, deadline)

    k = int(np.argmin(smin))
    best = MinSigma(q=Q[k].tolist(), sigma_min=float(smin[k]))
    for point in singular:
        if point.sigma_min < best.sigma_min:
            best = MinSigma(q=point.q, sigma_min=point.sigma_min)

    listed = len(Q) if len(Q) <= MAX_RESULTS else 0
    cond = condition(smin[:listed], m.sigma_max[:listed])
    results = [PointResult(q=Q[i].tolist(), det=None if det is None else float(det[i]),
                           sigma_min=float(smin[i]), condition=cond[i]) for i in range(listed)]
    return CouplingReport(split=split, results=results, results_omitted=len(Q) - listed,
                          singular_points=singular, singular_points_omitted=omitted,
                          min_sigma=best)


def _path_minima(robot: Robot, s: Structure, Q: np.ndarray, idx: np.ndarray,
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
