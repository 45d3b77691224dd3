"""One stage of the NLP (or its final node) as a function: its constraint rows and cost.

A stage function maps the stage's variables, the next stage's `link` entries, the global
variables and the common and local parameters to the rows of the transcription (defects,
implicit dynamics, gaps) and of every wanted term, and to their cost; it is written in the
transcription's symbolic type (SX, or MX where a stage calls an integrator).
"""

from __future__ import annotations

from typing import Generic, overload

import casadi as ca
import numpy as np

from planner.dynamics import functions
from planner.model import wave_slots
from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout, split
from planner.ocp.parameters import Parameters, slices
from planner.ocp.terms import Stage, Term
from planner.ocp.transcription import Model, StagePiece, Transcription
from planner.symbolic import Sym

RowGroups = list[tuple[float, float, int]]
"""Constraint rows in groups: lower bound, upper bound, count."""

ROW_KINDS = {"tip": "tip target", "margin": "coupling margin", "torque_limit": "torque limit",
             "position_bounds": "position bound", "velocity_bounds": "velocity bound"}
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


@overload
def stage_function(key: ProblemKey, tr: Transcription[ca.SX], layout: Layout,
                   params: Parameters, terms: list[Term],
                   terminal: bool) -> tuple[ca.Function, RowGroups, tuple[str, ...]]: ...


@overload
def stage_function(key: ProblemKey, tr: Transcription[ca.MX], layout: Layout,
                   params: Parameters, terms: list[Term],
                   terminal: bool) -> tuple[ca.Function, RowGroups, tuple[str, ...]]: ...


def stage_function(key: ProblemKey, tr: Transcription[Sym], layout: Layout, params: Parameters,
                   terms: list[Term], terminal: bool
                   ) -> tuple[ca.Function, RowGroups, tuple[str, ...]]:
    """A stage's (or the terminal's) rows and cost, the bounds of its row groups and what
    each group is (`ROW_KINDS`, for the evidence of an infeasible task), written in the
    transcription's symbolic type (one overload each, so that a transcription of either
    type can be passed)."""
    s = key.structure
    parts = layout.terminal if terminal else layout.stage
    sym = _Symbols(key, tr, layout, params, sum(p.size for p in parts), terminal)
    f = functions(s)
    model = Model(s.n, key.torque_count(), key.form == "implicit", f["fd"], f["ode"], sym.p)
    w = split(parts, sym.w)
    width = sym.local_of("width")
    h = sym.T * width
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
    return ca.Function(name, sym.inputs(terminal), [g, cost]), bounds, tuple(kinds)


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
