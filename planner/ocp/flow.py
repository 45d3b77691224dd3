"""The flow of the dynamics across the intervals of a plan, by CVODES, all intervals at
once.

On interval k, in normalised time s = (t - t_k) / h_k in [0, 1], the arm follows M ddq +
h = B sat(tau_k(s) + u), tau_k the plan's torque polynomial, u a constant torque offset
[N m] (0 for the plan itself, a feedback correction otherwise) and sat the actuators'
saturation at the task's torque limit L, min(max(., -L), L) (L = inf: none). The
intervals of one call are stacked into one ODE of 2n B states (B intervals), each started
from its own state: one CVODES run re-integrates them all, and each of its steps
evaluates the dynamics of every interval in one call. What CVODES costs per call of the
right-hand side (CasADi times each call by reading the process's CPU clock, a system
call) and per run is then paid once for B intervals. The tolerance of B stacked
intervals is TOL / sqrt(B): CVODES tests the root mean square of the weighted local errors
over all its states, so a step that passes holds every interval's own weighted error
within what it would meet integrated alone. CVODES integrates by Adams-Moulton with
functional iteration, as `planner.simulate` does by default: the arms are not stiff, and
on plans of the seed arm the interval check and the replays take a quarter to a half of
BDF's time (`python -m bench verification`). Where Adams fails, BDF with Newton
iteration takes over.
"""

from __future__ import annotations

import os
import sys
import threading
import weakref
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from planner.captured import captured
from planner.compiled import library, source_digest
from planner.dynamics import functions
from planner.model import Robot, Structure, parameters
from planner.ocp.transcription import Interpolant
from planner.simulate import METHODS, Method

TOL = 1e-10  # CVODES rtol = atol of the states
_SOURCES = [Path(__file__).resolve().parents[1] / name
            for name in ("dynamics.py", "model.py", "ocp/flow.py")]


def _dae(s: Structure, degree: int) -> ca.Function:
    """The right-hand side in normalised time: (t, x, z, p, u) -> (ode, alg, quad, zero)."""
    f = functions(s)["ode_ldl"]
    na = len(s.active_idx)
    x, u = ca.SX.sym("x", 2 * s.n), ca.SX.sym("u", na)
    sn, h = ca.SX.sym("s"), ca.SX.sym("h")
    coeffs = ca.SX.sym("c", (degree + 1) * na)
    p = ca.SX.sym("p", s.n_params)
    limit = ca.SX.sym("limit", na)
    wanted = sum(coeffs[j * na:(j + 1) * na] * sn**j for j in range(degree + 1)) + u
    tau = ca.fmin(ca.fmax(wanted, -limit), limit)
    none = ca.SX(0, 1)
    return ca.Function("flow_ode", [sn, x, none, ca.vertcat(p, coeffs, h, limit), u],
                       [h * f(x, tau, p), none, none, none], ca.dyn_in(), ca.dyn_out())


@lru_cache(maxsize=64)
def _dae_functions(s: Structure, degree: int) -> tuple[ca.Function, ...]:
    """`_dae` and the derivatives CVODES' setup asks for."""
    dae = _dae(s, degree)
    return dae, dae.forward(1), dae.reverse(1), dae.jacobian()


@lru_cache(maxsize=64)
def _library_name(s: Structure, degree: int) -> str:
    return f"flow_{source_digest(repr(s), str(degree), sources=_SOURCES)}"


def _compiled_dae(s: Structure, degree: int) -> ca.Function | None:
    """`_dae` compiled (`planner.compiled`); None while it is built in the background."""
    loaded = library(_library_name(s, degree), _dae_functions(s, degree), background=True)
    return None if loaded is None else loaded["flow_ode"]


@dataclass(frozen=True)
class Flow:
    """CVODES over B intervals, by Adams and by BDF: each a Function (x0 (2n x B), p, u) ->
    xf (2n x outputs B) (see `flow`): the B intervals stacked into one ODE (`_stacked`);
    for one interval the integrator itself."""

    adams: ca.Function
    bdf: ca.Function

    def __call__(self, x0: np.ndarray, p: np.ndarray, u: np.ndarray) -> np.ndarray:
        """xf (2n x outputs B), interval b from x0[:, b] (2n x B) with p[:, b] and
        u[:, b outputs:(b + 1) outputs]: by Adams, by BDF where Adams fails. Raises
        RuntimeError when both fail."""
        try:
            return quiet(self.adams, x0=x0, p=p, u=u)
        except RuntimeError:
            return quiet(self.bdf, x0=x0, p=p, u=u)


_LOCKS: weakref.WeakKeyDictionary[ca.Function, threading.Lock] = weakref.WeakKeyDictionary()
_LOCKING = threading.Lock()  # guards _LOCKS


def lock_of(integrator: ca.Function) -> threading.Lock:
    """The lock held by every call that runs `integrator`: an integrator keeps the state
    of a call in itself (`planner.exclusive`), and the cached ones are shared by the
    process's threads (a server's replanning sessions, a plan's checks), directly or
    inside the Functions that map them."""
    with _LOCKING:
        return _LOCKS.setdefault(integrator, threading.Lock())


def _forked() -> None:
    """In a forked child, which has only the thread that forked: every integrator's lock
    anew, as one another thread held at the fork would stay held there."""
    global _LOCKING
    _LOCKING = threading.Lock()
    _LOCKS.clear()


os.register_at_fork(after_in_child=_forked)


def quiet(function: ca.Function, *, runs: ca.Function | None = None,
          **args: np.ndarray) -> np.ndarray:
    """xf of one call of `function`, which runs the integrator `runs` (by default it is
    one). A CasADi Function whose call fails prints its name and every input ("Function
    flow (0x...) Input 0 (x0): [...]") to Python's stdout or stderr before it raises: a
    diverging replay would fill a worker's log or a command line's output with them. What
    the call prints is captured (`planner.captured`: other threads print on meanwhile); a
    failed call's becomes a note of its RuntimeError, anything a successful call printed
    is passed on unchanged. Calls that run one integrator run one at a time (`lock_of`);
    calls of different integrators run at once, in threads of their own."""
    try:
        with lock_of(function if runs is None else runs), captured() as (out, err):
            xf = function(**args)["xf"]
    except RuntimeError as exc:
        exc.add_note(out.getvalue() + err.getvalue())
        raise
    sys.stdout.write(out.getvalue())
    sys.stderr.write(err.getvalue())
    return np.array(xf)


def flow(s: Structure, degree: int, outputs: int, batch: int, tol: float = TOL,
         compiled: bool = False) -> Flow:
    """The flow of `batch` intervals at once, stacked into one ODE (see above). Per
    interval: x0 (2n) -> xf (2n x outputs) at s = 1/outputs, 2/outputs, ..., 1 with
    p = [robot parameters, torque coefficients (degree + 1 by na, power-major), h, torque
    limits (na; inf: none)] and u the torque offset, na x outputs (one per output
    interval). compiled: the right-hand side compiled to C (about twice as fast) once it
    is on disk, interpreted while it is built in the background."""
    return _flow(s, degree, outputs, batch, tol, ready(s, degree, compiled))


def ready(s: Structure, degree: int, compiled: bool) -> bool:
    """Whether the right-hand side runs compiled: asked for, and its library loaded (it is
    built in the background meanwhile)."""
    return compiled and _compiled_dae(s, degree) is not None


def stepper(s: Structure, degree: int, outputs: int, batch: int, tol: float, compiled: bool,
            method: Method) -> ca.Function:
    """CVODES by `method` over `batch` intervals at once, (x0 (2n x B), p (n_p x B),
    u (na x outputs B)) -> xf (2n x outputs B) as in `flow`: the integrator itself for one,
    the intervals stacked into one ODE for more (compiled only once `ready`)."""
    flows = _flow(s, degree, outputs, batch, tol, compiled)
    return flows.adams if method == "adams" else flows.bdf


@lru_cache(maxsize=64)
def _flow(s: Structure, degree: int, outputs: int, batch: int, tol: float,
          compiled: bool) -> Flow:
    if batch == 1:
        return Flow(*(integrator(s, degree, outputs, tol, compiled, method)
                      for method in ("adams", "bdf")))
    return Flow(*(_stacked(s, degree, outputs, batch, tol, compiled, method)
                  for method in ("adams", "bdf")))


def _stacked(s: Structure, degree: int, outputs: int, batch: int, tol: float,
             compiled: bool, method: Method) -> ca.Function:
    """CVODES by `method` over `batch` intervals stacked into one ODE, at the tolerance
    tol / sqrt(batch), as a Function of the shapes `flow` gives: (x0 (2n x B),
    p (n_p x B), u (na x outputs B)) -> xf (2n x outputs B)."""
    dae = _dynamics(s, degree, compiled)
    n2, n_p, na = 2 * s.n, dae.size1_in(3), dae.size1_in(4)
    t, x = ca.MX.sym("s"), ca.MX.sym("x", n2 * batch)
    p, u = ca.MX.sym("p", n_p * batch), ca.MX.sym("u", na * batch)
    rates = dae.map(batch)(t, ca.reshape(x, n2, batch), ca.MX(0, 1),
                           ca.reshape(p, n_p, batch), ca.reshape(u, na, batch))[0]
    none = ca.MX(0, 1)
    stack = ca.Function("flow_stack", [t, x, none, p, u],
                        [ca.reshape(rates, n2 * batch, 1), none, none, none],
                        ca.dyn_in(), ca.dyn_out())
    grid = list(np.linspace(0.0, 1.0, outputs + 1)[1:])
    whole = ca.integrator("flow", "cvodes", stack, 0.0, grid,
                          {"abstol": tol / np.sqrt(batch), "reltol": tol / np.sqrt(batch),
                           "show_eval_warnings": False, "disable_internal_warnings": True,
                           **METHODS[method]})
    # column b outputs + j (interval b, output j) <-> column j batch + b of the stack's
    by_output = [b * outputs + j for j in range(outputs) for b in range(batch)]
    by_interval = [j * batch + b for b in range(batch) for j in range(outputs)]
    x0, ps = ca.MX.sym("x0", n2, batch), ca.MX.sym("p", n_p, batch)
    us = ca.MX.sym("u", na, outputs * batch)
    xf = whole(x0=ca.reshape(x0, n2 * batch, 1), p=ca.reshape(ps, n_p * batch, 1),
               u=ca.reshape(us[:, by_output], na * batch, outputs))["xf"]
    return ca.Function("flow", [x0, ps, us], [ca.reshape(xf, n2, outputs * batch)[:, by_interval]],
                       ["x0", "p", "u"], ["xf"])


def _dynamics(s: Structure, degree: int, compiled: bool) -> ca.Function:
    """`_dae`, compiled where asked (which `flow` does only once it is `ready`)."""
    dae = _compiled_dae(s, degree) if compiled else _dae(s, degree)
    if dae is None:
        raise RuntimeError("the compiled flow is not loaded yet")
    return dae


@lru_cache(maxsize=64)
def integrator(s: Structure, degree: int, outputs: int, tol: float,
               compiled: bool, method: Method) -> ca.Function:
    """CVODES by `method` over one interval, unmapped (see `flow`; compiled only once
    `ready`)."""
    grid = list(np.linspace(0.0, 1.0, outputs + 1)[1:])
    return ca.integrator("flow", "cvodes", _dynamics(s, degree, compiled), 0.0, grid,
                         {"abstol": tol, "reltol": tol, "show_eval_warnings": False,
                          "disable_internal_warnings": True, **METHODS[method]})


def inputs(robot: Robot, interp: Interpolant,
           limit: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The plan's state at the start of every interval (2n x N) and the integrator's p of
    every interval (columns), the torque saturated at `limit` (na,) [N m] (None: not)."""
    breaks = interp.q.breaks
    starts = np.hstack([interp.q(breaks[:-1]), interp.dq(breaks[:-1])]).T
    coeffs = interp.tau.coeffs  # (N, m, na)
    N = coeffs.shape[0]
    p = parameters(robot, Structure.of(robot))
    na = coeffs.shape[2]
    sat = np.full(na, np.inf) if limit is None else np.broadcast_to(limit, (na,))
    params = np.vstack([np.repeat(p[:, None], N, axis=1), coeffs.reshape(N, -1).T,
                        np.diff(breaks)[None, :], np.repeat(sat[:, None], N, axis=1)])
    return starts, params
