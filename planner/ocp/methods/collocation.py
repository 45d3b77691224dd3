"""Orthogonal collocation of degree d at Legendre or Radau points, condensed to the motion.

On an interval of width h the states are polynomials of degree d through the interval
start and the d collocation points, the torques of degree d - 1 through the collocation
points, and the dynamics hold at the collocation points: with the Lagrange basis of
`casadi.collocation_coeff` (C, D, B), the collocation equations read

    [q0, q_c] C = h dq_c,    [dq0, dq_c] C = h ddq_c,

linear in the collocation states. They are solved inside the stage instead of being rows
of the NLP: with A = C_c^-1 (C_c the rows of C of the collocation points; C_0 + 1ᵀ C_c = 0
since the basis reproduces constants),

    dq_c = dq0 1ᵀ + h ddq_c A,    q_c = q0 1ᵀ + h dq_c A,

so that a stage's variables are its node state, the accelerations and the torques at the
collocation points: the same NLP solutions in about half the variables and rows, and a KKT
system whose size per stage is that of the state, the accelerations and the torques. The
dynamics M ddq_c + h - B tau_c = 0 (implicit form) or ddq_c - fd(q_c, dq_c, tau_c) = 0
(explicit form) are the stage's rows, the gaps to the next node its first rows.
"""

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
    collocation points, whose states are condensed into the stage (module docstring)."""

    terminal_knots = 0
    link = ("q", "dq")
    knot_blocks: tuple[str, ...] = ()
    """No angle is a variable at the knots: exact tracking holds by rows
    (`planner.ocp.terms.ExactTracking`)."""
    symbolic = ca.SX

    def __init__(self, intervals: int, degree: int, scheme: str, implicit: bool = True):
        self.intervals, self.degree, self.name, self.implicit = intervals, degree, scheme, implicit
        self.order = degree + 1
        self.knot_positions = tuple(float(t) for t in ca.collocation_points(degree, scheme))
        C, D, B = ca.collocation_coeff(list(self.knot_positions))
        self.D, self.B = np.array(D).ravel(), np.array(B).ravel()
        self.A = np.linalg.inv(np.array(C)[1:, :])
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
        return (*nodes(n), Part("ddq", "ddq", n, at), Part("tau", "tau", na, at)), nodes(n)

    def lifted_parts(self, n: int) -> tuple[Part, ...]:
        """The condensed collocation states (`planner.ocp.transcription.Lifted`)."""
        at = self.knot_positions
        return Part("q_col", "q", n, at), Part("dq_col", "dq", n, at)

    def lift(self, w: dict[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
        """The angles and rates at the collocation points (n x d) of a stage whose node
        state is w["q"], w["dq"] (n x 1), whose accelerations at the collocation points are
        w["ddq"] (n x d), and whose width is h [s]."""
        A, ones = ca.DM(self.A), ca.DM.ones(1, self.degree)
        dq_c = ca.mtimes(w["dq"], ones) + h * ca.mtimes(w["ddq"], A)
        return {"q_col": ca.mtimes(w["q"], ones) + h * ca.mtimes(dq_c, A), "dq_col": dq_c}

    def stage(self, w: dict[str, ca.SX], nxt: dict[str, ca.SX], h: ca.SX,
              model: Model[ca.SX]) -> StagePiece[ca.SX]:
        """w: the stage's variables and its lifted parts (symbols, or `lift`'s values)."""
        ddq, tau, qc, dqc = w["ddq"], w["tau"], w["q_col"], w["dq_col"]
        Q, DQ = ca.horzcat(w["q"], qc), ca.horzcat(w["dq"], dqc)
        D = ca.DM(self.D)
        gaps = ca.vertcat(nxt["q"] - ca.mtimes(Q, D), nxt["dq"] - ca.mtimes(DQ, D))
        defects = ca.SX(0, 1) if model.implicit else \
            ca.vec(ddq - model.fd.map(self.degree)(qc, dqc, tau, model.p))
        values = {"q": Q, "dq": DQ, "tau": tau}
        rows = {"q": self.state_hull, "dq": self.state_hull, "tau": self.tau_hull}
        hulls = {kind: ca.mtimes(values[kind], ca.DM(rows[kind].T)) for kind in self.hulls}
        return StagePiece(defects, qc, dqc, ddq, tau, Q, tau, self.knot_positions, gaps, hulls)

    def terminal(self, w: dict[str, ca.SX], model: Model[ca.SX]) -> StagePiece[ca.SX]:
        empty, none = ca.SX(model.n, 0), ca.SX(model.na, 0)
        return StagePiece(ca.SX(0, 1), empty, empty, empty, none, w["q"], none, ())

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        return mesh.widths[:, None] * self.B[None, :], np.zeros(0)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations | None) -> Interpolant:
        """(fd unused: the accelerations are variables in either form.)"""
        N, d = self.intervals, self.degree
        h = np.diff(breaks)[:, None, None]
        q, dq = sol["q"].T, sol["dq"].T
        ddq = sol["ddq"].T.reshape(N, d, -1)
        dqc = dq[:-1, None, :] + h * np.einsum("kjn,jl->kln", ddq, self.A)
        qc = q[:-1, None, :] + h * np.einsum("kjn,jl->kln", dqc, self.A)
        return collocation_interpolant(self.knot_positions, breaks, q, dq, qc, dqc,
                                       sol["tau"].T.reshape(N, d, -1))


def collocation_interpolant(points: tuple[float, ...], breaks: np.ndarray, q: np.ndarray,
                            dq: np.ndarray, qc: np.ndarray, dqc: np.ndarray,
                            tau: np.ndarray) -> Interpolant:
    """States of degree d through the node values q, dq (N + 1, n) and the collocation
    values qc, dqc (N, d, n), torques of degree d - 1 through tau (N, d, na), on the
    breakpoints [s] (N + 1,)."""
    at = np.array(points)
    nodes_at = np.concatenate([[0.0], at])

    def state(node: np.ndarray, col: np.ndarray) -> np.ndarray:
        return monomial(nodes_at, np.concatenate([node[:-1, None, :], col], axis=1))

    return Interpolant(PiecewisePolynomial(breaks, state(q, qc)),
                       PiecewisePolynomial(breaks, state(dq, dqc)),
                       PiecewisePolynomial(breaks, monomial(at, tau)))
