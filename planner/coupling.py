"""Inertial coupling analysis: det, sigma_min and condition of M_pa over many configurations.

M_pa(q) is the block of the mass matrix with the passive joints' rows and the active
joints' columns [kg m^2]. Prescribing the passive motion needs M_pa of full row rank;
configurations where it loses rank are inertial coupling singularities.

A request (`planner.coupling_request`) names the configurations: a path or a grid box.
The block and its measures are evaluated in batches by `planner.coupling_block`; the
singular points between neighbouring configurations are found and refined by
`planner.coupling_singularities`; the report is `planner.coupling_report`.
"""

from __future__ import annotations

import math

import numpy as np

from planner import budget
from planner.coupling_block import along, condition
from planner.coupling_report import (
    CouplingReport,
    MinSigma,
    PointResult,
    SingularPoint,
    split_of,
)
from planner.coupling_request import CouplingRequest
from planner.coupling_singularities import (
    MAX_SINGULAR,
    Box,
    Pairs,
    local_minima,
    minima_points,
    near_sign_change,
    path_minima,
    sign_changes,
)
from planner.model import Structure

__all__ = ["MAX_RESULTS", "CouplingReport", "CouplingRequest", "analyse"]

MAX_RESULTS = 20_000
"""Largest number of per-configuration results a report lists (the rest are counted)."""


def _edges(shape: tuple[int, ...]) -> Pairs:
    """Pairs of flat indices of neighbouring grid points, one pair of arrays per axis."""
    index = np.arange(math.prod(shape)).reshape(shape)
    pairs: Pairs = []
    for axis, length in enumerate(shape):
        if length < 2:
            continue
        lo = np.take(index, np.arange(length - 1), axis=axis).ravel()
        hi = np.take(index, np.arange(1, length), axis=axis).ravel()
        pairs.append((lo, hi))
    return pairs


def _points(request: CouplingRequest) -> tuple[np.ndarray, Pairs, Box, bool]:
    """Configurations (K, n), neighbour pairs, the local box of each point, and whether
    the configurations are a path."""
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
            singular, omitted = sign_changes(robot, s, Q, det, pairs, deadline)
        near = near_sign_change(det, pairs, len(Q))
        idx = local_minima(smin.copy(), pairs, request.threshold, near)
        room = MAX_SINGULAR - len(singular)
        omitted += max(len(idx) - room, 0)
        if is_path:
            singular += path_minima(robot, s, Q, idx[:room], deadline)
        else:
            singular += minima_points(robot, s, Q, idx[:room], boxes, deadline)

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
