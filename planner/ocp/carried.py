"""The multipliers of a solve carried to a refinement of its mesh, so that the refined
solve starts near the optimum in its dual as well as its primal values.

A refined mesh cuts the intervals of the one before (`planner.ocp.mesh.Mesh.split`), and
the rows and variables of every stage are the same quantities on either mesh. The
multipliers of the rows that read the next stage's variables (the continuity rows, and a
defect written between an interval's two nodes) approximate the costate at the node that
ends the stage, a function of time: they are interpolated linearly over the coarse nodes'
times. A stage's other rows (collocation and dynamics equations at its points, path
constraints) and the bounds of its variables carry a share of the interval's integral:
the multipliers of a coarse interval's are scaled by the width of each fine interval
inside it over its own. The rows that keep the globals' copies equal link a stage to the
next too, and are interpolated likewise. The terminal's rows and variables and the first
copy of the globals (the one with bounds) are the same on both meshes: their multipliers
are copied (docs/planner.md, "Meshes and refinement").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.ocp.instance import Instance
from planner.ocp.row_kinds import row_kinds
from planner.ocp.solve import Solution


@dataclass(frozen=True)
class Point:
    """A starting point of a solve: variables x (n_x,), bound multipliers lam_x (n_x,) and
    row multipliers lam_g (n_g,)."""

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


def carried(coarse: Instance, solution: Solution, fine: Instance,
            x0: np.ndarray) -> Point | None:
    """The start of a solve on `fine`, a refinement of `coarse`'s mesh with the same
    stages: the variables x0 (the coarse plan interpolated) and the multipliers of
    `solution` (the solve on `coarse`) carried over; None where the solution has no
    multipliers, a stage's rows or their kinds differ, or the fine mesh does not refine
    the coarse one."""
    if solution.lam_x is None or solution.lam_g is None:
        return None
    kinds, per_stage = row_kinds(coarse.problem)
    fine_kinds, fine_per_stage = row_kinds(fine.problem)
    layout, fine_layout = coarse.problem.layout, fine.problem.layout
    if per_stage == 0 or per_stage != fine_per_stage \
            or layout.stage_size != fine_layout.stage_size \
            or not np.array_equal(kinds[:per_stage], fine_kinds[:per_stage]):
        return None
    within = _enclosing(coarse.mesh.breaks, fine.mesh.breaks)
    if within is None:
        return None
    ratio = fine.mesh.widths / coarse.mesh.widths[within]  # (N_fine,)
    lam_g = _rows(solution.lam_g, coarse, fine, within, ratio, _linking(coarse, per_stage),
                  per_stage)
    lam_x = _bounds(solution.lam_x, coarse, fine.mesh.intervals, within, ratio)
    return Point(np.asarray(x0, float), lam_x, lam_g)


def _enclosing(coarse: np.ndarray, fine: np.ndarray) -> np.ndarray | None:
    """The coarse interval (N_fine,) that holds each fine interval; None unless every
    coarse break is a fine one."""
    if not np.all(np.isin(coarse, fine)):
        return None
    middles = (fine[:-1] + fine[1:]) / 2
    return np.searchsorted(coarse, middles) - 1


def _linking(inst: Instance, per_stage: int) -> np.ndarray:
    """Which rows of a stage (per_stage,) read the next stage's variables (the continuity
    rows, and a collocation defect written between the interval's two nodes)."""
    jacobian = inst.problem.solver.get_function("nlp_jac_g").sparsity_out(1)
    nw = inst.problem.layout.stage_size
    rows, cols = (np.asarray(a) for a in jacobian.get_triplet())
    beyond = (rows < per_stage) & (cols >= nw) & (cols < 2 * nw)
    out = np.zeros(per_stage, bool)
    out[rows[beyond]] = True
    return out


def _rows(lam: np.ndarray, coarse: Instance, fine: Instance, within: np.ndarray,
          ratio: np.ndarray, linking: np.ndarray, per_stage: int) -> np.ndarray:
    """The fine solve's row multipliers (n_g_fine,): rows that link a stage to the next
    (and the globals' copy rows) interpolated over the times of the nodes that end their
    stages, the other stage rows scaled by `ratio`, the terminal's copied."""
    N, layout = coarse.mesh.intervals, coarse.problem.layout
    terminal = lam.size - N * per_stage - layout.copy_rows
    stages = lam[:N * per_stage].reshape(N, per_stage)
    copies = lam[lam.size - layout.copy_rows:].reshape(N, layout.globals_size)
    out = stages[within] * ratio[:, None]
    ends, fine_ends = coarse.mesh.breaks[1:], fine.mesh.breaks[1:]
    for row in np.flatnonzero(linking):
        out[:, row] = np.interp(fine_ends, ends, stages[:, row])
    fine_copies = np.array([np.interp(fine_ends, ends, column) for column in copies.T]).T
    return np.concatenate([out.ravel(), lam[N * per_stage:N * per_stage + terminal],
                           fine_copies.reshape(-1)])


def _bounds(lam: np.ndarray, coarse: Instance, fine_intervals: int, within: np.ndarray,
            ratio: np.ndarray) -> np.ndarray:
    """The fine solve's bound multipliers (n_x_fine,): a stage's variables' scaled by
    `ratio`, the terminal's and the first copy of the globals' copied (the other copies
    have no bounds)."""
    layout = coarse.problem.layout
    N, nw, ng = coarse.mesh.intervals, layout.stage_size, layout.globals_size
    stages = lam[:N * nw].reshape(N, nw)
    copies = np.zeros((fine_intervals + 1) * ng)
    copies[:ng] = lam[layout.globals_start:layout.globals_start + ng]
    return np.concatenate([(stages[within] * ratio[:, None]).ravel(),
                           lam[N * nw:layout.globals_start], copies])
