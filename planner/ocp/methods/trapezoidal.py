"""Trapezoidal collocation: states quadratic, accelerations and torques linear per interval."""

from __future__ import annotations

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial, integrate
from planner.ocp.layout import Part
from planner.ocp.mesh import Mesh
from planner.ocp.transcription import (
    Accelerations,
    Interpolant,
    Model,
    StagePiece,
    knot_accelerations,
    nodes,
)


def linear(v: np.ndarray) -> np.ndarray:
    """Coefficients (N, 2, dim) of the lines through consecutive rows of v (N + 1, dim)."""
    return np.stack([v[:-1], v[1:] - v[:-1]], axis=1)


def node_weights(mesh: Mesh, end: float, mid: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature weights (fractions of T) of rules with weight `end` x width at both ends of
    every interval (summed where intervals meet) and `mid` x width at its midpoint: per
    stage [node, (midpoint)], and at the final node."""
    widths = mesh.widths
    before = np.concatenate([[0.0], widths[:-1]])
    node = end * (before + widths)
    stage = np.stack([node, mid * widths], axis=1) if mid else node[:, None]
    return stage, np.array([end * widths[-1]])


class Trapezoidal:
    """Dynamics at the N + 1 nodes, trapezoidal quadrature of rates and accelerations."""

    name = "trapezoidal"
    order = 3
    knot_positions = (0.0,)
    terminal_knots = 1
    symbolic = ca.SX
    knot_blocks = ("q",)
    hulls: tuple[str, ...] = ("q", "dq")  # the torque is linear between its node values

    def __init__(self, intervals: int, implicit: bool = True):
        self.intervals, self.implicit = intervals, implicit
        self.link = ("q", "dq", "ddq" if implicit else "tau")

    def node_count(self) -> int:
        return self.intervals + 1

    def knot_count(self) -> int:
        return self.intervals + 1

    def parts(self, n: int, na: int) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
        accel = Part("ddq", "ddq", n, (0.0,))
        tau = Part("tau", "tau", na, (0.0,))
        stage = (*nodes(n), accel, tau) if self.implicit else (*nodes(n), tau)
        return stage, stage

    @staticmethod
    def _knot(w: dict[str, ca.SX], model: Model[ca.SX]) -> tuple[ca.SX, ca.SX, ca.SX]:
        """A knot's angles, rates and accelerations (the next stage's linked parts hold
        its torques only in the explicit form, which needs them)."""
        q, dq = w["q"], w["dq"]
        return q, dq, model.accelerations(w, "ddq", q, dq, w.get("tau"))

    def stage(self, w: dict[str, ca.SX], nxt: dict[str, ca.SX], h: ca.SX,
              model: Model[ca.SX]) -> StagePiece[ca.SX]:
        q0, dq0, a0 = self._knot(w, model)
        q1, dq1, a1 = self._knot(nxt, model)
        tau = w["tau"]
        defects = ca.vertcat(q1 - q0 - h / 2 * (dq0 + dq1), dq1 - dq0 - h / 2 * (a0 + a1))
        # the quadratic states' middle Bernstein coefficients (their ends are the nodes)
        hull = {"q": q0 + h / 2 * dq0, "dq": dq0 + h / 2 * a0}
        return StagePiece(defects, q0, dq0, a0, tau, q0, tau, (0.0,), hull=hull)

    def terminal(self, w: dict[str, ca.SX], model: Model[ca.SX]) -> StagePiece[ca.SX]:
        q, dq, a = self._knot(w, model)
        tau = w["tau"]
        return StagePiece(ca.SX(0, 1), q, dq, a, tau, q, tau, (0.0,))

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        return node_weights(mesh, 0.5)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations) -> Interpolant:
        h = np.diff(breaks)
        ddq = knot_accelerations(sol, "ddq", "q", "dq", "tau", fd)
        q, dq, ddq, tau = sol["q"].T, sol["dq"].T, ddq.T, sol["tau"].T
        return Interpolant(PiecewisePolynomial(breaks, integrate(linear(dq), q[:-1], h)),
                           PiecewisePolynomial(breaks, integrate(linear(ddq), dq[:-1], h)),
                           PiecewisePolynomial(breaks, linear(tau)))
