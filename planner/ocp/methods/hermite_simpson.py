"""Separated Hermite-Simpson: states cubic, accelerations and torques quadratic per interval."""

from __future__ import annotations

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial, integrate, monomial
from planner.ocp.layout import Part
from planner.ocp.mesh import Mesh
from planner.ocp.methods.trapezoidal import node_weights
from planner.ocp.transcription import (
    Accelerations,
    Interpolant,
    Model,
    StagePiece,
    knot_accelerations,
)

_POINTS = np.array([0.0, 0.5, 1.0])


class HermiteSimpson:
    """Dynamics at the nodes and the interval midpoints; Simpson quadrature, Hermite midpoints."""

    name = "hermite-simpson"
    order = 4
    knot_positions = (0.0, 0.5)
    terminal_knots = 1
    symbolic = ca.SX
    knot_blocks = ("q", "q_mid")
    hulls: tuple[str, ...] = ("q", "dq", "tau")

    def __init__(self, intervals: int, implicit: bool = True):
        self.intervals, self.implicit = intervals, implicit
        # the next node's torque too: the torque quadratic ends there
        self.link = ("q", "dq", "ddq", "tau") if implicit else ("q", "dq", "tau")

    def node_count(self) -> int:
        return 2 * self.intervals + 1

    def knot_count(self) -> int:
        return 2 * self.intervals + 1

    def parts(self, n: int, na: int) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
        def knot(suffix: str, at: float) -> tuple[Part, ...]:
            q, dq = (Part(f"{k}{suffix}", k, n, (at,)) for k in ("q", "dq"))
            accel = Part(f"ddq{suffix}", "ddq", n, (at,))
            tau = Part(f"tau{suffix}", "tau", na, (at,))
            return (q, dq, accel, tau) if self.implicit else (q, dq, tau)

        node = knot("", 0.0)
        return (*node, *knot("_mid", 0.5)), node

    @staticmethod
    def _knot(w: dict[str, ca.SX], model: Model[ca.SX],
              suffix: str = "") -> tuple[ca.SX, ca.SX, ca.SX]:
        """A knot's angles, rates and accelerations (the next stage's linked parts hold
        its torques only in the explicit form, which needs them)."""
        q, dq = w[f"q{suffix}"], w[f"dq{suffix}"]
        return q, dq, model.accelerations(w, f"ddq{suffix}", q, dq, w.get(f"tau{suffix}"))

    def stage(self, w: dict[str, ca.SX], nxt: dict[str, ca.SX], h: ca.SX,
              model: Model[ca.SX]) -> StagePiece[ca.SX]:
        q0, dq0, a0 = self._knot(w, model)
        qm, dqm, am = self._knot(w, model, "_mid")
        q1, dq1, a1 = self._knot(nxt, model)
        tau0, taum = w["tau"], w["tau_mid"]
        defects = ca.vertcat(qm - (q0 + q1) / 2 - h / 8 * (dq0 - dq1),
                             dqm - (dq0 + dq1) / 2 - h / 8 * (a0 - a1),
                             q1 - q0 - h / 6 * (dq0 + 4 * dqm + dq1),
                             dq1 - dq0 - h / 6 * (a0 + 4 * am + a1))
        knots = ca.horzcat(q0, qm)
        taus = ca.horzcat(tau0, taum)
        return StagePiece(defects, knots, ca.horzcat(dq0, dqm), ca.horzcat(a0, am), taus,
                          knots, taus, (0.0, 0.5),
                          hull={"q": _cubic_hull(q0, dq0, dqm, dq1, h),
                                "dq": _cubic_hull(dq0, a0, am, a1, h),
                                "tau": 2 * taum - (tau0 + nxt["tau"]) / 2})

    def terminal(self, w: dict[str, ca.SX], model: Model[ca.SX]) -> StagePiece[ca.SX]:
        q, dq, a = self._knot(w, model)
        tau = w["tau"]
        return StagePiece(ca.SX(0, 1), q, dq, a, tau, q, tau, (0.0,))

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        return node_weights(mesh, 1 / 6, 4 / 6)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations) -> Interpolant:
        h = np.diff(breaks)

        def quadratic(node: np.ndarray, mid: np.ndarray) -> np.ndarray:
            return monomial(_POINTS, np.stack([node[:-1], mid, node[1:]], axis=1))

        ddq = knot_accelerations(sol, "ddq", "q", "dq", "tau", fd).T
        ddqm = knot_accelerations(sol, "ddq_mid", "q_mid", "dq_mid", "tau_mid", fd).T
        q, dq, tau = (sol[k].T for k in ("q", "dq", "tau"))
        dqm, taum = sol["dq_mid"].T, sol["tau_mid"].T
        return Interpolant(
            PiecewisePolynomial(breaks, integrate(quadratic(dq, dqm), q[:-1], h)),
            PiecewisePolynomial(breaks, integrate(quadratic(ddq, ddqm), dq[:-1], h)),
            PiecewisePolynomial(breaks, quadratic(tau, taum)))


def _cubic_hull(v0: ca.SX, r0: ca.SX, rm: ca.SX, r1: ca.SX, h: ca.SX) -> ca.SX:
    """The two middle Bernstein coefficients of v0 + h int_0^s r, r the quadratic through r0,
    rm, r1 at s = 0, 1/2, 1 (Bernstein coefficients r0, 2 rm - (r0 + r1) / 2, r1): each
    coefficient of the integral is the one before plus h / 3 times one of r's. (The last is
    the end value, which the Simpson defect makes the next node's.)"""
    first = v0 + h / 3 * r0
    return ca.horzcat(first, first + h / 3 * (2 * rm - (r0 + r1) / 2))
