"""The baseline: a plain CasADi Opti script for a planning scene, written as a user would.

State x = (q, dq), explicit forward dynamics x' = (dq, solve(M, B tau - h)) with M and h
the library's CasADi Functions called on MX; Legendre collocation of degree d on N equal
intervals, laid out as in CasADi's direct-collocation example (nodes, d collocation states
per interval, continuity by the end-point weights D), with the torque as a variable at each
collocation point (degree d - 1 per interval, the planner's own torque space), so that both
solve the same continuous problem with the same discretization error.

Same as the planner: objective effort * int |tau|^2 dt by the collocation quadrature;
boundary states; the torque limit at the collocation points; the coupling margin
sigma_min(M_pa) >= delta at the nodes and the collocation points, written as the leading
principal minors of G / delta^2 - I >= 0, G = M_pa M_pa^T, and for a square M_pa also
sign * det(M_pa) / delta^p - 1 >= 0 with the sign det M_pa has at the start, alone for a
1 x 1 block (the form of planner/ocp/problem.py `_margin_function`: the minors bound
sigma_min, the kept sign stops a path from jumping through det = 0 between knots); the
initial guess of `planner.ocp.guess.hermite_guess`. Different on purpose: Ipopt with its default
options (monotone barrier update, tol 1e-8), no `expand`, boundary conditions as equality
constraints, one Opti variable block per quantity indexed interval by interval.

Supports fixed-duration, state-to-state scenes with an effort objective, an optional torque
limit and an optional coupling margin. Its plans are checked by the planner's own code:
every interval re-integrated from the plan's state (`planner.ocp.accuracy`), the
whole-horizon replay (`planner.ocp.verify.open_loop`), the dynamics defect.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from bench.scenes import fixed_duration
from planner.dynamics import functions, selection
from planner.model import Structure, parameters
from planner.ocp.accuracy import interval_errors
from planner.ocp.guess import hermite_guess
from planner.ocp.methods import Collocation
from planner.ocp.methods.collocation import collocation_interpolant
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import defect, open_loop
from planner.scene import Scene

WALL_CAP = 600.0  # [s] Ipopt max_wall_time, a safety cap (not an Ipopt default)


def collocation_coefficients(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Roots [0, tau_1..tau_d] and C (derivatives), D (end values), B (integrals) of the
    Lagrange basis on them, as in CasADi's direct_collocation example."""
    root = np.append(0.0, ca.collocation_points(d, "legendre"))
    C, D, B = np.zeros((d + 1, d + 1)), np.zeros(d + 1), np.zeros(d + 1)
    for j in range(d + 1):
        basis = np.poly1d([1.0])
        for r in range(d + 1):
            if r != j:
                basis *= np.poly1d([1.0, -root[r]]) / (root[j] - root[r])
        D[j] = basis(1.0)
        derivative = np.polyder(basis)
        C[j] = [derivative(root[r]) for r in range(d + 1)]
        B[j] = np.polyint(basis)(1.0)
    return root, C, D, B


@dataclass
class Baseline:
    """A built Opti problem and the handles to read its solution."""

    opti: ca.Opti
    X: ca.MX
    Xc: list[ca.MX]
    U: list[ca.MX]
    cost: ca.MX
    build_time: float
    solved: bool = False
    value: Callable | None = None  # the last solve's value function (solution or last iterate)


def build(scene: Scene, wall_time: float = WALL_CAP) -> Baseline:
    """The Opti problem of a scene (fixed duration; effort objective; optional margin);
    wall_time [s]: Ipopt's max_wall_time."""
    start = time.perf_counter()
    robot, task = scene.robot, scene.task
    N, d = scene.transcription.intervals, scene.transcription.degree
    s = Structure.of(robot)
    n, na = s.n, len(s.active_idx)
    p = ca.DM(parameters(robot, s))
    f = functions(s)
    Bsel = ca.DM(selection(s))
    T = fixed_duration(scene)
    h = T / N
    root, C, D, Bq = collocation_coefficients(d)

    def xdot(x: ca.MX, u: ca.MX) -> ca.MX:
        q, dq = x[:n], x[n:]
        ddq = ca.solve(f["M"](q, p), ca.mtimes(Bsel, u) - f["h"](q, dq, p))
        return ca.vertcat(dq, ddq)

    margin = task.coupling_margin
    square = len(s.passive_idx) == na
    start_block = np.array(f["M"](task.initial.q, p))[np.ix_(s.passive_idx, s.active_idx)]
    sign = float(np.sign(np.linalg.det(start_block))) if square else 0.0

    def keep_margin(q: ca.MX, margin: float) -> None:
        mpa = f["M"](q, p)[s.passive_idx, s.active_idx]
        gram = ca.mtimes(mpa, mpa.T) if mpa.size1() <= mpa.size2() else ca.mtimes(mpa.T, mpa)
        shifted = gram / margin**2 - ca.MX.eye(gram.size1())
        orders = [] if square and na == 1 else range(1, gram.size1() + 1)
        for k in orders:
            opti.subject_to(ca.det(shifted[:k, :k]) >= 0)
        if square:
            opti.subject_to(sign * ca.det(mpa) / margin**na - 1 >= 0)

    opti = ca.Opti()
    X = opti.variable(2 * n, N + 1)
    Xc = [opti.variable(2 * n, d) for _ in range(N)]
    U = [opti.variable(na, d) for _ in range(N)]
    cost = ca.MX(0)
    for k in range(N):
        end = D[0] * X[:, k]
        for j in range(1, d + 1):
            slope = C[0, j] * X[:, k]
            for r in range(d):
                slope = slope + C[r + 1, j] * Xc[k][:, r]
            opti.subject_to(h * xdot(Xc[k][:, j - 1], U[k][:, j - 1]) == slope)
            cost = cost + task.objective.effort * Bq[j] * ca.sumsqr(U[k][:, j - 1]) * h
            end = end + D[j] * Xc[k][:, j - 1]
            if margin is not None:
                keep_margin(Xc[k][:n, j - 1], margin)
        opti.subject_to(X[:, k + 1] == end)
    if margin is not None:
        for k in range(N + 1):
            keep_margin(X[:n, k], margin)
    if task.torque_limit is not None:
        limit = np.broadcast_to(np.asarray(task.torque_limit, float), (na,))[:, None]
        for k in range(N):
            opti.subject_to(opti.bounded(-limit, U[k], limit))
    opti.subject_to(X[:, 0] == np.concatenate([task.initial.q, task.initial.dq]))
    opti.subject_to(X[:, N] == np.concatenate([task.final.q, task.final.dq]))
    opti.minimize(cost)
    opti.solver("ipopt", {"print_time": False, "record_time": True},
                {"print_level": 0, "sb": "yes", "max_wall_time": wall_time})
    set_guess(opti, scene, X, Xc, U, root)
    return Baseline(opti, X, Xc, U, cost, time.perf_counter() - start)


def set_guess(opti: ca.Opti, scene: Scene, X: ca.MX, Xc: list[ca.MX], U: list[ca.MX],
              root: np.ndarray) -> None:
    """The planner's own initial guess (cubic Hermite motion and its torques)."""
    N = scene.transcription.intervals
    guess = hermite_guess(scene, scene.robot, fixed_duration(scene))
    nodes = guess(np.linspace(0.0, 1.0, N + 1))
    opti.set_initial(X, np.vstack([nodes["q"].T, nodes["dq"].T]))
    for k in range(N):
        g = guess((k + root[1:]) / N)
        opti.set_initial(Xc[k], np.vstack([g["q"].T, g["dq"].T]))
        opti.set_initial(U[k], g["tau"].T)


def solve(scene: Scene, built: Baseline | None = None, wall_time: float = WALL_CAP) -> dict:
    """Solve a built problem again from the initial guess, or build it first (with Ipopt's
    max_wall_time wall_time [s]).

    Returns build_time (Opti construction plus the nlpsol setup that Opti does inside its
    first solve; 0 for a problem solved before), solve_time and cpu_time (Ipopt's wall and
    CPU time from its statistics), iterations, status, objective, and the planner's own
    checks: re-simulation error and dynamics defect of the collocation interpolant.
    """
    first = built is None or not built.solved
    built = built or build(scene, wall_time)
    if built.solved:
        root = collocation_coefficients(scene.transcription.degree)[0]
        set_guess(built.opti, scene, built.X, built.Xc, built.U, root)
    started = time.perf_counter()
    try:
        sol = built.opti.solve()
        stats, value = sol.stats(), sol.value
    except RuntimeError:  # Ipopt did not succeed: read the last iterate
        stats, value = built.opti.stats(), built.opti.debug.value
    total = time.perf_counter() - started
    built.solved, built.value = True, value
    solve_time = float(stats.get("t_wall_total", total))
    result = {"build_time": built.build_time + total - solve_time if first else 0.0,
              "solve_time": solve_time, "cpu_time": float(stats.get("t_proc_total", math.nan)),
              "iterations": int(stats.get("iter_count", 0)),
              "status": stats.get("return_status", "?"), "success": bool(stats.get("success")),
              "objective": float(value(built.cost))}
    result.update(verification(scene, built, value))
    result["stats"] = {k: v for k, v in stats.items()
                       if k.startswith(("t_wall_", "t_proc_", "n_call_"))}
    return result


def interpolant(scene: Scene, built: Baseline, value) -> Interpolant | None:
    """The collocation interpolant of a solution (the planner's own for Legendre
    collocation), None when the solution has non-finite entries."""
    N, d = scene.transcription.intervals, scene.transcription.degree
    n = scene.robot.n
    X = np.array(value(built.X))
    Xc = np.hstack([np.array(value(x)).reshape(2 * n, d) for x in built.Xc])
    U = np.hstack([np.array(value(u)).reshape(-1, d) for u in built.U])
    if not all(np.all(np.isfinite(b)) for b in (X, Xc, U)):
        return None
    breaks = np.linspace(0.0, fixed_duration(scene), N + 1)

    def per_interval(values: np.ndarray) -> np.ndarray:  # rows x (N d) -> (N, d, rows)
        return values.T.reshape(N, d, -1)

    return collocation_interpolant(Collocation(N, d, "legendre").knot_positions, breaks,
                                   X[:n].T, X[n:].T, per_interval(Xc[:n]),
                                   per_interval(Xc[n:]), per_interval(U))


def verification(scene: Scene, built: Baseline, value) -> dict:
    """The planner's checks of the solution's interpolant: the largest interval error
    [rad] (what `verification.local_error` is for a plan), the whole-horizon replay error
    [rad] and the defect [N m s]."""
    interp = interpolant(scene, built, value)
    if interp is None:
        return {"local_error": math.nan, "resimulation_error": math.nan, "defect": math.nan}
    errors, _ = interval_errors(scene.robot, interp)
    error, _ = open_loop(scene.robot, interp)
    local = float(errors.max())
    return {"local_error": local if math.isfinite(local) else math.nan,
            "resimulation_error": math.nan if error is None else error,
            "defect": defect(scene.robot, interp)}
