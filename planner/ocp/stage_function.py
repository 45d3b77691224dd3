"""One stage of the NLP (or its final node) as a function: its constraint rows and cost.

A stage function maps the stage's variables, the next stage's `link` entries, the global
variables and the common and local parameters to the rows of the transcription (defects,
implicit dynamics, gaps) and of every wanted term, and to their cost; it is written in the
transcription's symbolic type (SX, or MX where a stage calls an integrator).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, cast, overload

import casadi as ca
import numpy as np

from planner.dynamics import functions
from planner.model import wave_slots
from planner.ocp.assembly import Lifting
from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout, split
from planner.ocp.parameters import Parameters, slices
from planner.ocp.terms import Stage, Term
from planner.ocp.transcription import Lifted, Model, StagePiece, Transcription
from planner.symbolic import Sym

RowGroups = list[tuple[float, float, int]]
"""Constraint rows in groups: lower bound, upper bound, count."""

ROW_KINDS = {"tip": "tip target", "margin": "coupling margin", "torque_limit": "torque limit",
             "position_bounds": "position bound", "velocity_bounds": "velocity bound",
             "exact_tracking": "prescribed passive motion"}
"""What a term's constraint rows are, by its name; the transcription's own rows are
"dynamics" (collocation defects and M ddq + h - B tau) and "continuity" (the gaps between
stages). The task's initial and final states are bounds of variables, not rows."""


class _Symbols(Generic[Sym]):
    """The symbolic inputs of a stage function (in the transcription's Sym) and what terms
    read from them."""

    def __init__(self, key: ProblemKey, tr: Transcription[Sym], layout: Layout, params: Parameters,
                 width: int, terminal: bool):
        sym, s = tr.symbolic, key.structure
        self.w: Sym = sym.sym("w", width)
        self.nxt: Sym = sym.sym("nxt", 0 if terminal else sum(
            p.size for p in layout.stage if p.name in tr.link))
        self.glob: Sym = sym.sym("glob", layout.globals_size)
        self.common: Sym = sym.sym("common", params.n_common)
        self.local: Sym = sym.sym("local", params.n_local)
        globs = slices(dict(layout.globals))
        self.T: Sym = self.glob[globs["T"]] if key.free_time else self.common[params.common["T"]]
        entries = ca.vertsplit(self.common[params.common["robot"]])
        if key.codesign:
            waves = self.glob[globs["wave"]]
            for col, joint in enumerate(s.active_idx):
                entries[wave_slots(s)[joint]] = waves[2 * col]
                entries[wave_slots(s)[joint] + 2] = waves[2 * col + 1]
        self.p: Sym = ca.vertcat(*entries)
        self.params = params

    def inputs(self, terminal: bool) -> list[Sym]:
        return [self.w, self.glob, self.common, self.local] if terminal else \
            [self.w, self.nxt, self.glob, self.common, self.local]

    def common_of(self, name: str) -> Sym:
        return self.common[self.params.common[name]]

    def local_of(self, name: str) -> Sym:
        return self.local[self.params.local[name]]


@dataclass(frozen=True)
class StageFunction:
    """A stage's (or the terminal's) function (w, nxt, glob, common, local) -> (rows,
    cost), the bounds of its row groups, what each group is (`ROW_KINDS`, for the evidence
    of an infeasible task), and, for a lifted transcription's stage, the same function on
    its lifted quantities (`Lifting`)."""

    function: ca.Function
    bounds: RowGroups
    kinds: tuple[str, ...]
    lifting: Lifting | None = None


@overload
def stage_function(key: ProblemKey, tr: Transcription[ca.SX], layout: Layout,
                   params: Parameters, terms: list[Term], terminal: bool) -> StageFunction: ...


@overload
def stage_function(key: ProblemKey, tr: Transcription[ca.MX], layout: Layout,
                   params: Parameters, terms: list[Term], terminal: bool) -> StageFunction: ...


def stage_function(key: ProblemKey, tr: Transcription[Sym], layout: Layout, params: Parameters,
                   terms: list[Term], terminal: bool) -> StageFunction:
    """A stage's (or the terminal's) function, written in the transcription's symbolic type
    (one overload each, so that a transcription of either type can be passed)."""
    s = key.structure
    parts = layout.terminal if terminal else layout.stage
    sym = _Symbols(key, tr, layout, params, sum(p.size for p in parts), terminal)
    f = functions(s)
    model = Model(s.n, key.torque_count(), key.form == "implicit", f["fd"], f["ode"], sym.p)
    w = split(parts, sym.w)
    width = sym.local_of("width")
    h = sym.T * width
    lifted = _lifted(tr, s.n, cast(Any, w), cast(Any, h)) \
        if isinstance(tr, Lifted) and not terminal else None
    if lifted is not None:  # the stage is written on symbols of its lifted quantities
        w = {**w, **cast(Any, lifted[2])}
    if terminal:
        piece = tr.terminal(w, model)
    else:
        link = tuple(p for p in layout.stage if p.name in tr.link)
        piece = tr.stage(w, split(link, sym.nxt), h, model)
    m = piece.knot_q.size2()
    weights = sym.T * sym.local_of("weights")[:m].T if m else tr.symbolic(1, 0)
    rows: list[tuple] = [(piece.defects, 0.0, 0.0)] if piece.defects.numel() else []
    kinds = ["dynamics"] * len(rows)
    if model.implicit and m:
        rows.append((ca.vec(_residual(key, f["residual"].map(m), piece, sym.p)), 0.0, 0.0))
        kinds.append("dynamics")
    context = Stage(key, s, piece, weights, h, sym.T, sym.p, sym.common_of, sym.local_of, terminal)
    cost = tr.symbolic(0)
    for term in terms:
        piece_cost, term_rows = term.cost(context), term.rows(context)
        if piece_cost is not None:
            cost += piece_cost
        if term_rows is not None:
            rows.append(term_rows)
            kinds.append(ROW_KINDS.get(term.name, term.name))
    if piece.gaps is not None and piece.gaps.numel():
        rows.insert(0, (piece.gaps, 0.0, 0.0))
        kinds.insert(0, "continuity")
    g = ca.vertcat(*(r for r, _, _ in rows)) if rows else tr.symbolic(0, 1)
    bounds = [(lo, hi, r.numel()) for r, lo, hi in rows]
    name = "terminal" if terminal else "stage"
    inputs = sym.inputs(terminal)
    if lifted is None:
        return StageFunction(ca.Function(name, inputs, [g, cost]), bounds, tuple(kinds))
    plain, lifting = _lifted_functions(name, cast(Any, inputs), lifted[0], lifted[1],
                                       cast(Any, g), cast(Any, cost))
    return StageFunction(plain, bounds, tuple(kinds), lifting)


def _lifted(tr: Lifted, n: int, w: dict[str, ca.SX],
            h: ca.SX) -> tuple[ca.SX, ca.SX, dict[str, ca.SX]]:
    """A lifted transcription's stage quantities: their symbols z, their values lift(w, h)
    as one vector, and the symbols by part."""
    parts = tr.lifted_parts(n)
    z = ca.SX.sym("z", sum(p.size for p in parts))
    values = tr.lift(w, h)
    return z, ca.vertcat(*(ca.vec(values[p.name]) for p in parts)), split(parts, z)


def _lifted_functions(name: str, inputs: list[ca.SX], z: ca.SX, values: ca.SX, g: ca.SX,
                      cost: ca.SX) -> tuple[ca.Function, Lifting]:
    """The stage function of rows g and cost written on the lifted quantities z, whose
    values are `values` (in the inputs), and its `Lifting`."""
    plain = ca.Function(name, inputs, ca.substitute([g, cost], [z], [values]))
    on_z = ca.Function(f"{name}_lifted", [inputs[0], z, *inputs[1:]], [g, cost])
    return plain, Lifting(on_z, ca.Function(f"{name}_lift", inputs, [values]))


def _residual(key: ProblemKey, residual: ca.Function, piece: StagePiece[Sym], p: Sym) -> Sym:
    """M ddq + h - B tau at a stage's knots (n x m); relaxed, less the passive joints'
    virtual torques (the rows of the torque vector after the active ones)."""
    s = key.structure
    tau = piece.knot_tau
    if not key.relaxed:
        return residual(piece.knot_q, piece.knot_dq, piece.knot_ddq, tau, p)
    na = len(s.active_idx)
    scatter = np.zeros((s.n, len(s.passive_idx)))
    scatter[s.passive_idx, range(len(s.passive_idx))] = 1.0
    return residual(piece.knot_q, piece.knot_dq, piece.knot_ddq, tau[:na, :], p) \
        - ca.mtimes(ca.DM(scatter), tau[na:, :])
