"""Wavy Lagrangian dynamics of a planar chain, derived by CasADi automatic differentiation.

From the Lagrangian L = T - V of `planner.model`, with q the absolute joint angles:
    M(q) = d2T/ddq2,    h(q, dq) = d/dq(dT/ddq) dq - dT/dq + dV/dq,
so that M(q) ddq + h(q, dq) = B tau. Only the terms a structure needs are built:
no wave terms for a waveless joint, no gravity for g = 0, no rotational terms for a
zero inertia. Functions are cached per `Structure`, the numbers enter as parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from planner.errors import InputError
from planner.model import Robot, Structure, parameters


@dataclass(frozen=True)
class Symbols:
    """Symbolic quantities of one structure, shared by every function built from it."""

    q: ca.SX
    dq: ca.SX
    p: ca.SX
    radius: list[ca.SX]
    tips: ca.SX
    kinetic: ca.SX
    potential: ca.SX
    momentum: ca.SX
    mass: ca.SX
    bias: ca.SX
    gravity: ca.SX


def _unpack(s: Structure, p: ca.SX) -> dict[str, list]:
    """Split the symbolic parameter vector (layout of `planner.model.parameters`)."""
    n, k = s.n, 2 * s.n
    out: dict[str, list] = {"l": [p[i] for i in range(n)], "m": [p[n + i] for i in range(n)]}
    out["I"] = []
    for on in s.inertial:
        out["I"].append(p[k] if on else None)
        k += int(on)
    out["wave"] = []
    for on in s.wavy:
        out["wave"].append((p[k], p[k + 1], p[k + 2]) if on else None)
        k += 3 * int(on)
    out["g"] = [p[k]] if s.gravity else []
    return out


def derive(s: Structure) -> Symbols:
    """Derive tips, energies, M, h and the gravity term for a structure."""
    q, dq = ca.SX.sym("q", s.n), ca.SX.sym("dq", s.n)
    p = ca.SX.sym("p", s.n_params)
    par = _unpack(s, p)

    radius = []
    for i in range(s.n):
        wave = par["wave"][i]
        r = par["l"][i]
        if wave is not None:
            r = r + wave[0] * ca.sin(wave[1] * q[i] + wave[2])
        radius.append(r)

    tip, tips = ca.SX.zeros(2), []
    for i in range(s.n):
        tip = tip + radius[i] * ca.vertcat(ca.cos(q[i]), ca.sin(q[i]))
        tips.append(tip)

    kinetic = ca.SX(0)
    for k in range(s.n):
        velocity = ca.jtimes(tips[k], q, dq)
        kinetic += 0.5 * par["m"][k] * ca.sumsqr(velocity)
    for k, inertia in enumerate(par["I"]):
        if inertia is None:
            continue
        rate = ca.sum1(dq[: k + 1]) if s.rotational == "cumulative" else dq[k]
        kinetic += 0.5 * inertia * rate**2

    potential = ca.SX(0)
    if s.gravity:
        g = par["g"][0]
        potential = -g * sum(par["m"][k] * tips[k][0] for k in range(s.n))

    momentum = ca.gradient(kinetic, dq)
    mass = ca.jacobian(momentum, dq)
    gravity = ca.gradient(potential, q) if s.gravity else ca.SX.zeros(s.n)
    bias = ca.jtimes(momentum, q, dq) - ca.gradient(kinetic, q) + gravity
    return Symbols(q, dq, p, radius, ca.horzcat(*tips), kinetic, potential, momentum,
                   ca.simplify(mass), bias, gravity)


def generalized_forces(sym: Symbols, ddq: ca.SX) -> ca.SX:
    """M ddq + h as d/dt(dT/ddq) - dT/dq + dV/dq along (dq, ddq), without forming M.

    One directional derivative of the momentum gives a smaller expression (and cheaper
    second derivatives in the planner's NLP) than the product M ddq.
    """
    state, rate = ca.vertcat(sym.q, sym.dq), ca.vertcat(sym.dq, ddq)
    return ca.jtimes(sym.momentum, state, rate) - ca.gradient(sym.kinetic, sym.q) + sym.gravity


def selection(s: Structure) -> np.ndarray:
    """B (n x n_active): maps the active joints' torques to generalized forces."""
    B = np.zeros((s.n, len(s.active_idx)))
    for col, joint in enumerate(s.active_idx):
        B[joint, col] = 1.0
    return B


@lru_cache(maxsize=128)
def functions(s: Structure) -> dict[str, ca.Function]:
    """Compiled dynamics functions of a structure (cached: built once per structure).

    Keys and signatures (p is the parameter vector of `planner.model.parameters`):
      M(q, p), h(q, dq, p), gravity(q, p), energy(q, dq, p) -> [T, V], tips(q, p) -> 2 x n,
      fd(q, dq, tau, p) -> ddq, id(q, dq, ddq, p) -> Q = M ddq + h (see generalized_forces),
      residual(q, dq, ddq, tau, p) -> M ddq + h - B tau, ode(x, tau, p) -> dx,
      ode_ldl(x, tau, p) -> dx: the same rates with M (symmetric positive definite) solved
      by its LDL^T factors instead of a QR, a fifth fewer operations on four links (what
      a plan's checks integrate and linearise, `planner.ocp.flow`, `planner.ocp.feedback`).
    The coupling block M_pa and its measures are `planner.coupling_block`'s.
    """
    sym = derive(s)
    q, dq, p = sym.q, sym.dq, sym.p
    ddq = ca.SX.sym("ddq", s.n)
    tau = ca.SX.sym("tau", len(s.active_idx))
    B = ca.DM(selection(s))
    generalized = generalized_forces(sym, ddq)
    accel = ca.solve(sym.mass, ca.mtimes(B, tau) - sym.bias)
    factored = ca.ldl_solve(ca.mtimes(B, tau) - sym.bias, *ca.ldl(sym.mass))
    x = ca.vertcat(q, dq)
    return {
        "M": ca.Function("M", [q, p], [sym.mass], ["q", "p"], ["M"]),
        "h": ca.Function("h", [q, dq, p], [sym.bias], ["q", "dq", "p"], ["h"]),
        "gravity": ca.Function("gravity", [q, p], [sym.gravity], ["q", "p"], ["G"]),
        "energy": ca.Function("energy", [q, dq, p], [sym.kinetic, sym.potential],
                              ["q", "dq", "p"], ["T", "V"]),
        "tips": ca.Function("tips", [q, p], [sym.tips], ["q", "p"], ["tips"]),
        "fd": ca.Function("fd", [q, dq, tau, p], [accel], ["q", "dq", "tau", "p"], ["ddq"]),
        "id": ca.Function("id", [q, dq, ddq, p], [generalized], ["q", "dq", "ddq", "p"], ["Q"]),
        "residual": ca.Function("residual", [q, dq, ddq, tau, p],
                                [generalized - ca.mtimes(B, tau)],
                                ["q", "dq", "ddq", "tau", "p"], ["r"]),
        "ode": ca.Function("ode", [x, tau, p], [ca.vertcat(dq, accel)], ["x", "tau", "p"], ["dx"]),
        "ode_ldl": ca.Function("ode_ldl", [x, tau, p], [ca.vertcat(dq, factored)],
                               ["x", "tau", "p"], ["dx"]),
    }


def vector(name: str, value, size: int, per: str) -> np.ndarray:
    """`value` as a float vector of `size` finite entries; InputError naming `name` if not
    ("q: needs 2 entries, one per joint (got 1)")."""
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name}: must be a list of numbers") from None
    if v.ndim > 1:
        raise InputError(f"{name}: must be a flat list of numbers (got shape {v.shape})")
    if v.size != size:
        entries = "entry" if size == 1 else "entries"
        raise InputError(f"{name}: needs {size} {entries}, one per {per} (got {v.size})")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name}: every entry must be a finite number (got {v.tolist()})")
    return v.reshape(size)


class Dynamics:
    """Numpy-facing dynamics of one robot (vectors in, arrays out; SI units).

    q [rad], dq [rad/s] and ddq [rad/s^2] need one finite entry per joint, tau [N m] one
    per active joint (a plain sequence or a 1-D array); anything else raises InputError
    naming the argument, e.g. "q: needs 2 entries, one per joint (got 1)".
    """

    def __init__(self, robot: Robot, structure: Structure | None = None):
        self.robot = robot
        self.structure = structure or Structure.of(robot)
        self.p = parameters(robot, self.structure)
        self.f = functions(self.structure)
        self.B = selection(self.structure)

    def _joints(self, name: str, value) -> np.ndarray:
        return vector(name, value, self.structure.n, "joint")

    def mass_matrix(self, q) -> np.ndarray:
        """M(q) [kg m^2], n x n."""
        return np.array(self.f["M"](self._joints("q", q), self.p))

    def bias(self, q, dq) -> np.ndarray:
        """h(q, dq) [N m]: Coriolis, centrifugal and gravity terms."""
        return np.array(self.f["h"](self._joints("q", q), self._joints("dq", dq), self.p)).ravel()

    def gravity(self, q) -> np.ndarray:
        """Gravity term dV/dq [N m]."""
        return np.array(self.f["gravity"](self._joints("q", q), self.p)).ravel()

    def energy(self, q, dq) -> tuple[float, float]:
        """Kinetic and potential energy [J]."""
        T, V = self.f["energy"](self._joints("q", q), self._joints("dq", dq), self.p)
        return float(T), float(V)

    def tips(self, q) -> np.ndarray:
        """Tip position of every link, n x 2 [m]."""
        return np.array(self.f["tips"](self._joints("q", q), self.p)).T

    def forward(self, q, dq, tau) -> np.ndarray:
        """Joint accelerations [rad/s^2] for the active torques tau [N m].

        Raises InputError where they are not finite: M(q) numerically singular (masses,
        lengths and inertias spanning too many orders of magnitude) or values too large.
        """
        tau = vector("tau", tau, len(self.structure.active_idx), "active joint")
        ddq = np.array(self.f["fd"](self._joints("q", q), self._joints("dq", dq), tau,
                                    self.p)).ravel()
        if not np.all(np.isfinite(ddq)):
            raise InputError("the accelerations are not finite at this state: M(q) is "
                             "numerically singular or the values are too large")
        return ddq

    def forward_many(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Accelerations [rad/s^2] at K states: q, dq (K, n), tau (K, n_active) -> (K, n);
        entries are NaN where M(q) is numerically singular."""
        K = len(q)
        return np.array(self.f["fd"].map(K)(np.asarray(q, float).T, np.asarray(dq, float).T,
                                            np.asarray(tau, float).T, self.p)).T.reshape(K, -1)

    def inverse(self, q, dq, ddq) -> np.ndarray:
        """Generalized forces M ddq + h [N m]."""
        return np.array(self.f["id"](self._joints("q", q), self._joints("dq", dq),
                                     self._joints("ddq", ddq), self.p)).ravel()

