"""Decision variables of an NLP, laid out stage by stage.

The variables of interval k (a stage, the same parts for every k) come first, interval
after interval, then those of the final node (the terminal), then the global variables
(a free duration, co-designed waves, the idle variable of `ProblemKey.idle`), one copy
g_k for each stage and one for the terminal:

    x = [w_0, w_1, ..., w_{N-1}, w_N (terminal), g_0, g_1, ..., g_N]

Stage k reads its own copy and rows g_k = g_{k+1} (`planner.ocp.assembly`) keep the copies
equal, so that no variable is read by every stage: the KKT matrix stays banded over the
stages, where one shared copy would border it with dense rows and columns that make the
sparse factorization costlier (docs/planner.md, "Global variables"). Only the first copy
carries a global's bounds (`first`).

A part is a named matrix of `rows` x len(positions) variables holding one quantity (q, dq,
ddq or tau) at fixed fractions of the interval. A named block gathers the part of that name
across all stages (and the terminal), in time order: e.g. "q" is the node angles, n x (N + 1);
a global's block is its copies, size x (N + 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from planner.ocp.mesh import Mesh
from planner.symbolic import Sym


@dataclass(frozen=True)
class Part:
    """rows x len(positions) variables of quantity `kind` at those fractions of an interval
    (stored column-major)."""

    name: str
    kind: str
    rows: int
    positions: tuple[float, ...]

    @property
    def size(self) -> int:
        return self.rows * len(self.positions)


def _offsets(parts: tuple[Part, ...]) -> dict[str, int]:
    out, k = {}, 0
    for part in parts:
        out[part.name] = k
        k += part.size
    return out


@dataclass(frozen=True)
class Layout:
    """The variables of N stages, a terminal and N + 1 copies of the globals (name, size)."""

    stage: tuple[Part, ...]
    terminal: tuple[Part, ...]
    globals: tuple[tuple[str, int], ...]
    intervals: int

    @property
    def stage_size(self) -> int:
        return sum(p.size for p in self.stage)

    @property
    def terminal_size(self) -> int:
        return sum(p.size for p in self.terminal)

    @property
    def globals_size(self) -> int:
        """The variables of one copy of the globals."""
        return sum(size for _, size in self.globals)

    @property
    def globals_start(self) -> int:
        """Where the globals' copies start in x."""
        return self.intervals * self.stage_size + self.terminal_size

    @property
    def size(self) -> int:
        return self.globals_start + (self.intervals + 1) * self.globals_size

    @property
    def copy_rows(self) -> int:
        """The rows g_k - g_{k+1} that keep the globals' copies equal, one per global
        variable and stage (after the stages' and the terminal's rows)."""
        return self.intervals * self.globals_size

    def first(self, name: str) -> np.ndarray:
        """The indices into x of the first copy of global `name` (size,): the copy that
        carries its bounds and that stands for its value."""
        return self.blocks[name][1][:, 0]

    @cached_property
    def blocks(self) -> dict[str, tuple[str, np.ndarray]]:
        """Per block name: its quantity and the indices into x of its entries, rows x columns
        in time order."""
        N, nw = self.intervals, self.stage_size
        out: dict[str, tuple[str, list[np.ndarray]]] = {}
        for part, start in zip(self.stage, _offsets(self.stage).values(), strict=True):
            local = start + np.arange(part.size).reshape(len(part.positions), part.rows).T
            cols = [local + k * nw for k in range(N)]
            out[part.name] = (part.kind, cols)
        base = N * nw
        for part, start in zip(self.terminal, _offsets(self.terminal).values(), strict=True):
            local = base + start + np.arange(part.size).reshape(len(part.positions), part.rows).T
            out.setdefault(part.name, (part.kind, []))[1].append(local)
        base, copies = self.globals_start, (N + 1) * self.globals_size
        for name, size in self.globals:
            out[name] = ("global", [base + np.arange(size)[:, None]
                                    + np.arange(0, copies, self.globals_size)[None, :]])
            base += size
        return {name: (kind, np.hstack(cols)) for name, (kind, cols) in out.items()}

    def __contains__(self, name: str) -> bool:
        return name in self.blocks

    def view(self, x: np.ndarray, name: str) -> np.ndarray:
        """The block `name` of a numeric vector (a copy, rows x columns)."""
        return np.asarray(x)[self.blocks[name][1]]

    def put(self, x: np.ndarray, name: str, values) -> None:
        """Write values (broadcast to rows x columns) into block `name` of x."""
        idx = self.blocks[name][1]
        x[idx] = np.broadcast_to(values, idx.shape)

    def times(self, name: str, mesh: Mesh) -> np.ndarray:
        """The time fractions of the columns of block `name` on a mesh."""
        cols: list[np.ndarray] = []
        for part in self.stage:
            if part.name == name:
                cols.append(mesh.points(np.asarray(part.positions)))
        for part in self.terminal:
            if part.name == name:
                cols.append(np.ones(len(part.positions)))
        return np.concatenate(cols)

    def zeros(self) -> np.ndarray:
        return np.zeros(self.size)


def split(parts: tuple[Part, ...], w: Sym) -> dict[str, Sym]:
    """The named parts of one stage's (or the terminal's) variable vector, rows x columns."""
    out = {}
    for part, start in zip(parts, _offsets(parts).values(), strict=True):
        out[part.name] = ca.reshape(w[start:start + part.size], part.rows, len(part.positions))
    return out


def torques(layout: Layout) -> tuple[list[np.ndarray], list[float], list[np.ndarray], list[float]]:
    """The torque columns of a stage and of the terminal in time order, with their positions
    (local indices into the stage's / the terminal's variables)."""
    def columns(parts: tuple[Part, ...]) -> tuple[list[np.ndarray], list[float]]:
        found, start = [], 0
        for part in parts:
            if part.kind == "tau":
                for j, at in enumerate(part.positions):
                    found.append((at, start + j * part.rows + np.arange(part.rows)))
            start += part.size
        found.sort(key=lambda item: item[0])
        return [idx for _, idx in found], [at for at, _ in found]

    stage, stage_at = columns(layout.stage)
    terminal, terminal_at = columns(layout.terminal)
    return stage, stage_at, terminal, terminal_at
