"""Orthogonal collocation of degree d at Legendre or Radau points."""

from __future__ import annotations

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial, hull, monomial
from planner.ocp.layout import Part
from planner.ocp.mesh import Mesh
from planner.ocp.transcription import (
    Accelerations,
    Interpolant,
    Model,
    StagePiece,
    nodes,
)


class Collocation:
    """States of degree d through the interval start and d collocation points, torques of
    degree d - 1 through the collocation points, per interval; the dynamics hold at the
    collocation points. C, D, B of the Lagrange basis come from `casadi.collocation_coeff`."""

    terminal_knots = 0
    link = ("q", "dq")
    knot_blocks = ("q_col",)
    symbolic = ca.SX

    def __init__(self, intervals: int, degree: int, scheme: str, implicit: bool = True):
        self.intervals, self.degree, self.name, self.implicit = intervals, degree, scheme, implicit
        self.order = degree + 1
        self.knot_positions = tuple(float(t) for t in ca.collocation_points(degree, scheme))
        C, D, B = ca.collocation_coeff(list(self.knot_positions))
        self.C, self.D, self.B = C, D, np.array(B).ravel()
        # Bernstein coefficients beyond the variables: of the states through the node and the
        # collocation points (the end value is the next node's by the gap rows), and of the
        # torques through the collocation points (none for a constant, degree 1)
        self.state_hull = hull((0.0, *self.knot_positions), end_known=True)
        self.tau_hull = hull(self.knot_positions)
        self.hulls = tuple(kind for kind, rows in (("q", self.state_hull),
                                                   ("dq", self.state_hull),
                                                   ("tau", self.tau_hull)) if rows.size)

    def node_count(self) -> int:
        return self.intervals * (self.degree + 1)

    def knot_count(self) -> int:
        return self.intervals * self.degree

    def parts(self, n: int, na: int) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
        at = self.knot_positions
        inner = (Part("q_col", "q", n, at), Part("dq_col", "dq", n, at))
        accel = (Part("ddq", "ddq", n, at),) if self.implicit else ()
        return (*nodes(n), *inner, *accel, Part("tau", "tau", na, at)), nodes(n)

    def stage(self, w: dict[str, ca.SX], nxt: dict[str, ca.SX], h: ca.SX,
              model: Model[ca.SX]) -> StagePiece[ca.SX]:
        qc, dqc, tau = w["q_col"], w["dq_col"], w["tau"]
        ddqc = model.accelerations(w, "ddq", qc, dqc, tau)
        Q, DQ = ca.horzcat(w["q"], qc), ca.horzcat(w["dq"], dqc)
        defects = ca.vertcat(ca.vec(ca.mtimes(Q, self.C) - h * dqc),
                             ca.vec(ca.mtimes(DQ, self.C) - h * ddqc))
        gaps = ca.vertcat(nxt["q"] - ca.mtimes(Q, self.D), nxt["dq"] - ca.mtimes(DQ, self.D))
        values = {"q": Q, "dq": DQ, "tau": tau}
        rows = {"q": self.state_hull, "dq": self.state_hull, "tau": self.tau_hull}
        hulls = {kind: ca.mtimes(values[kind], ca.DM(rows[kind].T)) for kind in self.hulls}
        return StagePiece(defects, qc, dqc, ddqc, tau, ca.horzcat(w["q"], qc), tau,
                          self.knot_positions, gaps, hulls)

    def terminal(self, w: dict[str, ca.SX], model: Model[ca.SX]) -> StagePiece[ca.SX]:
        empty, none = ca.SX(model.n, 0), ca.SX(model.na, 0)
        return StagePiece(ca.SX(0, 1), empty, empty, empty, none, w["q"], none, ())

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        return mesh.widths[:, None] * self.B[None, :], np.zeros(0)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations | None) -> Interpolant:
        """(fd unused: the collocation states carry the accelerations.)"""
        N, d = self.intervals, self.degree
        points = np.array(self.knot_positions)
        nodes_at = np.concatenate([[0.0], points])

        def state(node: np.ndarray, col: np.ndarray) -> np.ndarray:
            values = np.concatenate([node[:-1, None, :], col.reshape(N, d, -1)], axis=1)
            return monomial(nodes_at, values)

        q, dq = sol["q"].T, sol["dq"].T
        qc, dqc, tau = sol["q_col"].T, sol["dq_col"].T, sol["tau"].T
        return Interpolant(PiecewisePolynomial(breaks, state(q, qc)),
                           PiecewisePolynomial(breaks, state(dq, dqc)),
                           PiecewisePolynomial(breaks, monomial(points, tau.reshape(N, d, -1))))

