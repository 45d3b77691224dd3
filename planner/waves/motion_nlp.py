"""The collocation NLP of the motion problem (`planner.waves.motion`), and its build.

The NLP maximises s over the waves' amplitudes and phases and the active states at the
nodes of K collocation intervals, with the passive rows of the equations of motion at the
nodes and the bound lambda_min(M_pa M_pa^T) >= s^2 (`planner.waves.nlp.bound`) there. It
is expanded to SX, which evaluates about ten times faster and costs a build that grows
with K: 1.8 s at 40 intervals to 18 s at 320 on an 8-link arm, one CasADi call that no
deadline can interrupt. So `solver` keeps the builds (16 at most) and refuses to start one
that the pace of the arm's last build says would end past the deadline.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from functools import lru_cache

import casadi as ca

from planner import budget
from planner.dynamics import derive
from planner.exclusive import Exclusive
from planner.model import Structure
from planner.waves.nlp import IPOPT, bound, decision, with_waves

CACHED = 16
"""Motion NLPs kept built (structures x interval counts)."""

_built: OrderedDict[tuple[Structure, int], tuple[Exclusive, int]] = OrderedDict()
_pace: dict[Structure, float] = {}  # seconds per interval of the structure's last build
_lock = threading.Lock()  # guards both


def solver(s: Structure, K: int, deadline: float | None = None,
           what: str = "the motion NLP") -> tuple[Exclusive, int]:
    """The NLP of K intervals and its node size nz, built on first use. Raises
    BudgetExceeded, building nothing, past `deadline` or when the build would end past it
    at the pace of this structure's last build."""
    key = (s, K)
    with _lock:
        found = _built.get(key)
        if found is not None:
            _built.move_to_end(key)
            return found
    budget.check(deadline, what)
    pace = _pace.get(s)
    if deadline is not None and pace is not None and time.monotonic() + pace * K > deadline:
        raise budget.BudgetExceeded(
            f"{what}: building it for {K} collocation intervals would take about "
            f"{pace * K:.2g} s (at the pace of this arm's last build) and end past its deadline")
    start = time.monotonic()
    built = _build(s, K)
    with _lock:
        _pace[s] = (time.monotonic() - start) / K
        _built[key] = built
        while len(_built) > CACHED:
            _built.popitem(last=False)
    return built


def n_bound(s: Structure) -> int:
    """Bound constraints per node: one for up to two passive joints, else one per minor."""
    r = len(s.passive_idx)
    return 1 if r <= 2 else r


@lru_cache(maxsize=16)
def _node(s: Structure) -> ca.Function:
    """Passive-row residual and bound at one collocation node."""
    sym = derive(s)
    P, A = s.passive_idx, s.active_idx
    na, npas = len(A), len(P)
    z = ca.SX.sym("z", 3 * na + (npas if na > npas else 0))
    qp, dqp, ddqp = ca.SX.sym("qp", npas), ca.SX.sym("dqp", npas), ca.SX.sym("ddqp", npas)
    s2, c = ca.SX.sym("s2"), ca.SX.sym("c", npas)
    q, dq = ca.SX.zeros(s.n), ca.SX.zeros(s.n)
    q[P], q[A], dq[P], dq[A] = qp, z[:na], dqp, z[na:2 * na]
    mass = ca.Function("Mh", [sym.q, sym.dq, sym.p], [sym.mass, sym.bias])
    M, h = mass(q, dq, sym.p)
    mpa = M[P, A]
    ddqa = z[2 * na:3 * na]
    residual = [ca.mtimes(M[P, P], ddqp) + ca.mtimes(mpa, ddqa) + h[P]]
    if na > npas:  # minimum norm: ddq_a in the row space of M_pa
        residual.append(ddqa - ca.mtimes(mpa.T, z[3 * na:]))
    return ca.Function("node", [z, qp, dqp, ddqp, sym.p, s2, c],
                       [ca.vertcat(*residual), bound(ca.mtimes(mpa, mpa.T), s2, c)])


def _interval(na: int, nz: int) -> ca.Function:
    """Continuity of (q_a, dq_a) over one interval with ddq_a linear in time."""
    z0, z1, h = ca.SX.sym("z0", nz), ca.SX.sym("z1", nz), ca.SX.sym("h")
    q0, v0, a0 = z0[:na], z0[na:2 * na], z0[2 * na:3 * na]
    q1, v1, a1 = z1[:na], z1[na:2 * na], z1[2 * na:3 * na]
    return ca.Function("interval", [z0, z1, h], [ca.vertcat(
        q1 - q0 - h * v0 - h**2 / 6 * (2 * a0 + a1), v1 - v0 - h / 2 * (a0 + a1))])


def _build(s: Structure, K: int) -> tuple[Exclusive, int]:
    """maximise s over (a, eps, s, node states) along K intervals; returns (solver, nz)."""
    na, npas = len(s.active_idx), len(s.passive_idx)
    nz = 3 * na + (npas if na > npas else 0)
    a, eps, sig = decision(na)
    Z = ca.MX.sym("Z", nz, K + 1)
    base, freq = ca.MX.sym("p", s.n_params), ca.MX.sym("n", na)
    QP, DQP, DDQP = (ca.MX.sym(name, npas, K + 1) for name in ("qp", "dqp", "ddqp"))
    H, X0 = ca.MX.sym("h", 1, K), ca.MX.sym("x0", 2 * na)
    C = ca.MX.sym("C", npas, K + 1)
    p = with_waves(s, base, a, freq, eps)
    residual, bound = _node(s).map(K + 1)(Z, QP, DQP, DDQP, p, sig**2, C)
    continuity = _interval(na, nz).map(K)(Z[:, :-1], Z[:, 1:], H)
    g = ca.vertcat(Z[:2 * na, 0] - X0, ca.vec(residual), ca.vec(continuity), ca.vec(bound))
    nlp = {"x": ca.vertcat(a, eps, sig, ca.vec(Z)), "f": -sig, "g": g,
           "p": ca.vertcat(base, freq, ca.vec(QP), ca.vec(DQP), ca.vec(DDQP), H.T, X0,
                           ca.vec(C))}
    options = {**IPOPT, "expand": True, **budget.ipopt_stop(nlp)}
    return Exclusive(ca.nlpsol("waves_motion", "ipopt", nlp, options)), nz
