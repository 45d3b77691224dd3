"""Direct transcriptions of M(q) ddq + h(q, dq) = B tau over N intervals of width h = T / N.

Each transcription lays out its variables, states its defect constraints and quadrature,
and gives the interpolant it assumes (states and torques between the knots), which the
verification feeds to an independent simulation. Times are fractions of T in [0, 1].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial, integrate, monomial
from planner.ocp.layout import Layout

# dyn(name, q, dq, tau) -> ddq at those knots; registers variables/constraints as the form needs.
Dyn = Callable[[str, ca.MX, ca.MX, ca.MX], ca.MX]


@dataclass
class Discrete:
    """The symbolic transcription: nodes, dynamics knots, defects, quadrature."""

    q: ca.MX  # n x (N + 1) node angles
    dq: ca.MX  # n x (N + 1) node rates
    knot_q: ca.MX  # n x K angles where the dynamics (and path constraints) hold
    knot_tau: ca.MX  # na x K torques there
    knot_times: np.ndarray  # (K,) fractions of T
    weights: np.ndarray  # (K,) quadrature weights, sum 1: int f dt ~ T sum w_j f_j
    tau_steps: ca.MX  # na x S consecutive torque differences in time order
    step_times: np.ndarray  # (S,) the time fractions between those torques
    path_q: ca.MX  # n x P angles where path constraints hold: the knots and the nodes
    knot_blocks: tuple[str, ...]  # the angle blocks at the knots (where tracking holds exactly)
    defects: list[ca.MX] = field(default_factory=list)
    block_times: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class Interpolant:
    """Numeric interpolant of a solved transcription: q, dq and tau as piecewise polynomials."""

    q: PiecewisePolynomial
    dq: PiecewisePolynomial
    tau: PiecewisePolynomial


def _nodes(N: int) -> np.ndarray:
    return np.linspace(0.0, 1.0, N + 1)


def _node_states(lay: Layout, n: int, N: int) -> tuple[ca.MX, ca.MX, dict]:
    q, dq = lay.add("q", n, N + 1), lay.add("dq", n, N + 1)
    t = _nodes(N)
    return q, dq, {"q": ("q", t), "dq": ("dq", t)}


class Trapezoidal:
    """Trapezoidal collocation: states quadratic, accelerations and torques linear per interval."""

    name = "trapezoidal"

    def __init__(self, intervals: int):
        self.N = intervals

    def build(self, lay: Layout, n: int, na: int, h: ca.MX, dyn: Dyn) -> Discrete:
        N, t = self.N, _nodes(self.N)
        q, dq, times = _node_states(lay, n, N)
        tau = lay.add("tau", na, N + 1)
        ddq = dyn("ddq", q, dq, tau)
        defects = [q[:, 1:] - q[:, :-1] - h / 2 * (dq[:, 1:] + dq[:, :-1]),
                   dq[:, 1:] - dq[:, :-1] - h / 2 * (ddq[:, 1:] + ddq[:, :-1])]
        w = np.full(N + 1, 1.0 / N)
        w[[0, -1]] /= 2
        times.update(tau=("tau", t), ddq=("ddq", t))
        return Discrete(q, dq, q, tau, t, w, tau[:, 1:] - tau[:, :-1], np.diff(t), q, ("q",),
                        defects, times)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray) -> Interpolant:
        h = np.diff(breaks)
        q, dq, ddq, tau = (sol[k].T for k in ("q", "dq", "ddq", "tau"))
        lin = lambda v: np.stack([v[:-1], v[1:] - v[:-1]], axis=1)
        return Interpolant(PiecewisePolynomial(breaks, integrate(lin(dq), q[:-1], h)),
                           PiecewisePolynomial(breaks, integrate(lin(ddq), dq[:-1], h)),
                           PiecewisePolynomial(breaks, lin(tau)))


class HermiteSimpson:
    """Separated Hermite-Simpson: states cubic, accelerations and torques quadratic per interval."""

    name = "hermite-simpson"

    def __init__(self, intervals: int):
        self.N = intervals

    def build(self, lay: Layout, n: int, na: int, h: ca.MX, dyn: Dyn) -> Discrete:
        N, t = self.N, _nodes(self.N)
        tm = (t[:-1] + t[1:]) / 2
        q, dq, times = _node_states(lay, n, N)
        qm, dqm = lay.add("q_mid", n, N), lay.add("dq_mid", n, N)
        tau, taum = lay.add("tau", na, N + 1), lay.add("tau_mid", na, N)
        ddq, ddqm = dyn("ddq", q, dq, tau), dyn("ddq_mid", qm, dqm, taum)
        a, b = slice(0, N), slice(1, N + 1)
        defects = [
            qm - (q[:, a] + q[:, b]) / 2 - h / 8 * (dq[:, a] - dq[:, b]),
            dqm - (dq[:, a] + dq[:, b]) / 2 - h / 8 * (ddq[:, a] - ddq[:, b]),
            q[:, b] - q[:, a] - h / 6 * (dq[:, a] + 4 * dqm + dq[:, b]),
            dq[:, b] - dq[:, a] - h / 6 * (ddq[:, a] + 4 * ddqm + ddq[:, b]),
        ]
        w = np.concatenate([np.full(N + 1, 2.0), np.full(N, 4.0)]) / (6 * N)
        w[[0, N]] /= 2
        times.update(q_mid=("q", tm), dq_mid=("dq", tm), tau=("tau", t), tau_mid=("tau", tm),
                     ddq=("ddq", t), ddq_mid=("ddq", tm))
        steps = ca.horzcat(taum - tau[:, a], tau[:, b] - taum)
        knots = ca.horzcat(q, qm)
        return Discrete(q, dq, knots, ca.horzcat(tau, taum), np.concatenate([t, tm]),
                        w, steps, np.full(2 * N, 0.5 / N), knots, ("q", "q_mid"), defects, times)

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray) -> Interpolant:
        h = np.diff(breaks)
        pts = np.array([0.0, 0.5, 1.0])

        def quad(node: np.ndarray, mid: np.ndarray) -> np.ndarray:
            return monomial(pts, np.stack([node[:-1], mid, node[1:]], axis=1))

        q, dq, ddq, tau = (sol[k].T for k in ("q", "dq", "ddq", "tau"))
        dqm, ddqm, taum = (sol[k].T for k in ("dq_mid", "ddq_mid", "tau_mid"))
        return Interpolant(PiecewisePolynomial(breaks, integrate(quad(dq, dqm), q[:-1], h)),
                           PiecewisePolynomial(breaks, integrate(quad(ddq, ddqm), dq[:-1], h)),
                           PiecewisePolynomial(breaks, quad(tau, taum)))


class Collocation:
    """Orthogonal collocation of degree d at Legendre or Radau points: states of degree d,
    torques of degree d - 1 through the collocation points, per interval."""

    def __init__(self, intervals: int, degree: int, scheme: str):
        self.N, self.d, self.name = intervals, degree, scheme
        self.tau_pts = np.array(ca.collocation_points(degree, scheme))
        pts = np.concatenate([[0.0], self.tau_pts])
        basis = np.linalg.inv(np.vander(pts, increasing=True))  # columns: Lagrange coefficients
        powers = np.arange(degree + 1)
        dbasis = basis[1:] * powers[1:, None]  # derivative coefficients
        # C[r, j] = L_r'(tau_j), D[r] = L_r(1), B[j] = int_0^1 L_j(s) ds over the torque points.
        self.C = np.array([[sum(dbasis[m - 1, r] * tj ** (m - 1) for m in range(1, degree + 1))
                            for tj in self.tau_pts] for r in range(degree + 1)])
        self.D = basis.sum(axis=0)
        vander_tau = np.vander(self.tau_pts, increasing=True)
        self.B = np.linalg.solve(vander_tau.T, 1.0 / np.arange(1, degree + 1))

    def build(self, lay: Layout, n: int, na: int, h: ca.MX, dyn: Dyn) -> Discrete:
        N, d = self.N, self.d
        tc = ((np.arange(N)[:, None] + self.tau_pts[None, :]) / N).ravel()
        q, dq, times = _node_states(lay, n, N)
        qc, dqc = lay.add("q_col", n, N * d), lay.add("dq_col", n, N * d)
        tau = lay.add("tau", na, N * d)
        ddqc = dyn("ddq", qc, dqc, tau)
        interval = self._interval_function(n)
        coll_q, coll_dq, end_q, end_dq = interval.map(N)(q[:, :-1], dq[:, :-1], qc, dqc, ddqc, h)
        defects = [coll_q, coll_dq, q[:, 1:] - end_q, dq[:, 1:] - end_dq]
        times.update(q_col=("q", tc), dq_col=("dq", tc), tau=("tau", tc), ddq=("ddq", tc))
        w = np.tile(self.B, N) / N
        steps = tau[:, 1:] - tau[:, :-1] if N * d > 1 else ca.MX(na, 0)
        return Discrete(q, dq, qc, tau, tc, w, steps, np.diff(tc), ca.horzcat(q, qc),
                        ("q_col",), defects, times)

    def _interval_function(self, n: int) -> ca.Function:
        """Collocation equations and end state of one interval (SX, mapped over intervals)."""
        d = self.d
        q0, dq0 = ca.SX.sym("q0", n), ca.SX.sym("dq0", n)
        qc, dqc, ddqc = ca.SX.sym("qc", n, d), ca.SX.sym("dqc", n, d), ca.SX.sym("ddqc", n, d)
        h = ca.SX.sym("h")
        Q, DQ = ca.horzcat(q0, qc), ca.horzcat(dq0, dqc)
        C, D = ca.DM(self.C), ca.DM(self.D)
        coll_q = ca.mtimes(Q, C) - h * dqc
        coll_dq = ca.mtimes(DQ, C) - h * ddqc
        return ca.Function("interval", [q0, dq0, qc, dqc, ddqc, h],
                           [coll_q, coll_dq, ca.mtimes(Q, D), ca.mtimes(DQ, D)])

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray) -> Interpolant:
        N, d = self.N, self.d
        pts = np.concatenate([[0.0], self.tau_pts])

        def state(node: np.ndarray, col: np.ndarray) -> np.ndarray:
            vals = np.concatenate([node[:-1, None, :], col.reshape(N, d, -1)], axis=1)
            return monomial(pts, vals)

        q, dq = sol["q"].T, sol["dq"].T
        qc, dqc, tau = sol["q_col"].T, sol["dq_col"].T, sol["tau"].T
        return Interpolant(PiecewisePolynomial(breaks, state(q, qc)),
                           PiecewisePolynomial(breaks, state(dq, dqc)),
                           PiecewisePolynomial(breaks, monomial(self.tau_pts, tau.reshape(N, d, -1))))


class MultipleShooting:
    """Multiple shooting: torques held constant per interval, the explicit dynamics integrated
    by fixed-step RK4 or CVODES; the interpolant between nodes is the integrator's own."""

    name = "multiple-shooting"

    def __init__(self, intervals: int, integrator: str, steps: int, ode: ca.Function,
                 p: ca.MX):
        self.N, self.integrator, self.steps, self.ode, self.p = intervals, integrator, steps, ode, p

    def build(self, lay: Layout, n: int, na: int, h: ca.MX, dyn: Dyn) -> Discrete:
        N, t = self.N, _nodes(self.N)
        q, dq, times = _node_states(lay, n, N)
        tau = lay.add("tau", na, N)
        x = ca.vertcat(q, dq)
        end = self._step(n, na).map(N)(x[:, :-1], tau, h, self.p)
        times.update(tau=("tau", t[:-1]))
        return Discrete(q, dq, q[:, :-1], tau, t[:-1], np.full(N, 1.0 / N),
                        tau[:, 1:] - tau[:, :-1] if N > 1 else ca.MX(na, 0), np.diff(t[:-1]),
                        q, ("q",), [x[:, 1:] - end], times)

    def _step(self, n: int, na: int) -> ca.Function:
        x, u = ca.MX.sym("x", 2 * n), ca.MX.sym("u", na)
        h, p = ca.MX.sym("h"), ca.MX.sym("p", self.p.numel())
        if self.integrator == "cvodes":
            xs, us, ps, hs = ca.SX.sym("x", 2 * n), ca.SX.sym("u", na), ca.SX.sym("p", p.numel()), ca.SX.sym("h")
            dae = {"x": xs, "p": ca.vertcat(us, ps, hs), "ode": hs * self.ode(xs, us, ps)}
            sim = ca.integrator("shoot", "cvodes", dae, 0.0, 1.0,
                                {"abstol": 1e-10, "reltol": 1e-10})
            xf = sim(x0=x, p=ca.vertcat(u, p, h))["xf"]
        else:
            xf, dt = x, h / self.steps
            for _ in range(self.steps):
                k1 = self.ode(xf, u, p)
                k2 = self.ode(xf + dt / 2 * k1, u, p)
                k3 = self.ode(xf + dt / 2 * k2, u, p)
                k4 = self.ode(xf + dt * k3, u, p)
                xf = xf + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return ca.Function("shoot", [x, u, h, p], [xf])

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray) -> Interpolant:
        """Cubic Hermite states through the nodes (rates and accelerations there)."""
        h = np.diff(breaks)[:, None]
        pts_basis = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-3, -2, 3, -1], [2, 1, -2, 1]], float)

        def hermite(v: np.ndarray, dv: np.ndarray) -> np.ndarray:
            data = np.stack([v[:-1], dv[:-1] * h, v[1:], dv[1:] * h], axis=1)
            return np.einsum("mj,kjd->kmd", pts_basis, data)

        q, dq, ddq, tau = sol["q"].T, sol["dq"].T, sol["ddq"].T, sol["tau"].T
        return Interpolant(PiecewisePolynomial(breaks, hermite(q, dq)),
                           PiecewisePolynomial(breaks, hermite(dq, ddq)),
                           PiecewisePolynomial(breaks, tau[:, None, :]))
