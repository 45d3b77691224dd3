"""Multiple shooting: torques held per interval, the explicit dynamics integrated across it."""

from __future__ import annotations

from typing import Generic

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial, hermite
from planner.ocp.layout import Part
from planner.ocp.mesh import Mesh
from planner.ocp.transcription import (
    Accelerations,
    Interpolant,
    Model,
    StagePiece,
    nodes,
)
from planner.rk4 import rk4_step
from planner.symbolic import Sym

CVODES_TOL = 1e-10  # CVODES' relative and absolute tolerance across a shooting interval


def multiple_shooting(intervals: int, integrator: str,
                      steps: int) -> MultipleShooting[ca.SX] | MultipleShooting[ca.MX]:
    """Multiple shooting across an interval by `integrator` ("rk4": `steps` fixed steps,
    written out in SX; "cvodes": called from MX, which SX cannot hold)."""
    if integrator == "cvodes":
        return MultipleShooting(intervals, integrator, steps, ca.MX)
    return MultipleShooting(intervals, integrator, steps, ca.SX)


class MultipleShooting(Generic[Sym]):
    """Torques constant per interval; the end state by fixed-step RK4 or CVODES; the
    interpolant between nodes is the cubic Hermite through the node states and their
    rates, each interval's accelerations at both ends under its own torque. Its stages are
    written in `symbolic` (`multiple_shooting` picks the one its integrator needs)."""

    name = "multiple-shooting"
    order = 4
    knot_positions = (0.0,)
    terminal_knots = 0
    link = ("q", "dq")
    knot_blocks = ("q",)
    hulls: tuple[str, ...] = ("q", "dq")  # the torque is constant per interval

    def __init__(self, intervals: int, integrator: str, steps: int, symbolic: type[Sym]):
        self.intervals, self.integrator, self.steps = intervals, integrator, steps
        self.implicit = False
        self.symbolic: type[Sym] = symbolic

    def node_count(self) -> int:
        return self.intervals * self.steps

    def knot_count(self) -> int:
        return self.intervals

    def parts(self, n: int, na: int) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
        return (*nodes(n), Part("tau", "tau", na, (0.5,))), nodes(n)

    def stage(self, w: dict[str, Sym], nxt: dict[str, Sym], h: Sym,
              model: Model[Sym]) -> StagePiece[Sym]:
        q, dq, tau = w["q"], w["dq"], w["tau"]
        end = self._end(ca.vertcat(q, dq), tau, h, model)
        ddq = model.fd(q, dq, tau, model.p)
        # the cubic Hermite states' middle Bernstein coefficients, v0 + h v0' / 3 and
        # v1 - h v1' / 3, the end from the interval's own integration (the next node by the
        # gap rows), so that they read the stage's variables alone
        q1, dq1 = end[:model.n], end[model.n:]
        ddq1 = model.fd(q1, dq1, tau, model.p)
        hull = {"q": ca.horzcat(q + h / 3 * dq, q1 - h / 3 * dq1),
                "dq": ca.horzcat(dq + h / 3 * ddq, dq1 - h / 3 * ddq1)}
        return StagePiece(self.symbolic(0, 1), q, dq, ddq, tau, q, tau, (0.5,),
                          ca.vertcat(nxt["q"], nxt["dq"]) - end, hull)

    def _end(self, x: Sym, tau: Sym, h: Sym, model: Model[Sym]) -> Sym:
        """The state one interval of width h later under the constant torque."""
        if self.integrator == "cvodes":
            xs, us, ps, hs = (ca.SX.sym(k, size) for k, size in
                              (("x", x.numel()), ("u", model.na), ("p", model.p.numel()), ("h", 1)))
            dae = {"x": xs, "p": ca.vertcat(us, ps, hs), "ode": hs * model.ode(xs, us, ps)}
            sim = ca.integrator("shoot", "cvodes", dae, 0.0, 1.0,
                                {"abstol": CVODES_TOL, "reltol": CVODES_TOL})
            return sim(x0=x, p=ca.vertcat(tau, model.p, h))["xf"]
        dt = h / self.steps
        for _ in range(self.steps):
            x = rk4_step(lambda state, _c: model.ode(state, tau, model.p), x, dt)
        return x

    def terminal(self, w: dict[str, Sym], model: Model[Sym]) -> StagePiece[Sym]:
        empty, none = self.symbolic(model.n, 0), self.symbolic(model.na, 0)
        return StagePiece(self.symbolic(0, 1), empty, empty, empty, none, w["q"], none, ())

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        return mesh.widths[:, None], np.zeros(0)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations) -> Interpolant:
        h = np.diff(breaks)
        q, dq, tau = sol["q"].T, sol["dq"].T, sol["tau"].T
        ddq = fd(q[:-1], dq[:-1], tau)
        ddq_end = fd(q[1:], dq[1:], tau)
        starts = np.vstack([ddq, ddq_end[-1:]])
        return Interpolant(PiecewisePolynomial(breaks, hermite(q, dq, h)),
                           PiecewisePolynomial(breaks, hermite(dq, starts, h, ddq_end)),
                           PiecewisePolynomial(breaks, tau[:, None, :]))
