"""opty (direct collocation in SymPy, solved by Ipopt through cyipopt) on a planning scene:
the peer side of `python -m bench peer_opty`, run by the interpreter of its own virtualenv
`.venv-opty` (no CasADi there), JSON in and out:

    .venv-opty/bin/python -c "from bench.peers.opty import main; main()" IN OUT

It derives the equations of motion M(q) u' + h(q, u) = B tau by SymPy from the Lagrangian
of the planar chain (docs/model.md: absolute angles, wave r = l + a sin(n q + eps), point
masses at the tips, rotational term by the robot's convention), checks M and h at the
driver's random state, builds the opty problem (compilation included in the build time)
and solves it from the given initial guess.

The effort objective of the opty NLP is the exact integral of |tau|^2 of the torque
interpolant its method implies (backward Euler: h sum_i |u_i|^2 over all nodes, u_0
acting on no interval; midpoint: the linear interpolation of the samples).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

SOLVE_CAP = 120.0  # [s] a solve stops here (intermediate callback), and its method goes no finer
ONE_SOLVE_ABOVE = 30.0  # [s] a first solve this long is not repeated
IPOPT_STATUS = {0: "Solve_Succeeded", 1: "Solved_To_Acceptable_Level",
                2: "Infeasible_Problem_Detected", 3: "Search_Direction_Becomes_Too_Small",
                4: "Diverging_Iterates", 5: "User_Requested_Stop", 6: "Feasible_Point_Found",
                -1: "Maximum_Iterations_Exceeded", -2: "Restoration_Failed",
                -3: "Error_In_Step_Computation", -4: "Maximum_CpuTime_Exceeded",
                -10: "Not_Enough_Degrees_Of_Freedom", -11: "Invalid_Problem_Definition",
                -12: "Invalid_Option", -13: "Invalid_Number_Detected",
                -100: "Unrecoverable_Exception", -101: "NonIpopt_Exception_Thrown",
                -102: "Insufficient_Memory", -199: "Internal_Error"}


def lagrangian_dynamics(robot: dict):
    """SymPy M(q) and h(q, dq) of the planar chain (plain symbols, numbers substituted)."""
    import sympy as sp

    links = robot["links"]
    n = len(links)
    q, dq = sp.symbols(f"q:{n}"), sp.symbols(f"dq:{n}")
    g = sp.Float(robot.get("gravity", 0.0))
    radius = []
    for i, link in enumerate(links):
        wave = link.get("wave") or {}
        a = float(wave.get("amplitude", 0.0))
        r = sp.Float(link["length"])
        if a != 0.0:
            angle = sp.Float(wave["frequency"]) * q[i] + sp.Float(wave["phase"])
            r = r + sp.Float(a) * sp.sin(angle)
        radius.append(r)
    tips, x, y = [], sp.Integer(0), sp.Integer(0)
    for i in range(n):
        x, y = x + radius[i] * sp.cos(q[i]), y + radius[i] * sp.sin(q[i])
        tips.append((x, y))
    T = sp.Integer(0)
    for k, (xk, yk) in enumerate(tips):
        vx = sum(sp.diff(xk, q[i]) * dq[i] for i in range(k + 1))
        vy = sum(sp.diff(yk, q[i]) * dq[i] for i in range(k + 1))
        T += sp.Float(links[k]["mass"]) * (vx**2 + vy**2) / 2
    cumulative = robot.get("rotational_inertia", "cumulative") == "cumulative"
    for k in range(n):
        rate = sum(dq[: k + 1]) if cumulative else dq[k]
        T += sp.Float(links[k].get("inertia", 0.0)) * rate**2 / 2
    V = -g * sum(sp.Float(links[k]["mass"]) * tips[k][0] for k in range(n))
    momentum = [sp.diff(T, v) for v in dq]
    M = sp.Matrix(n, n, lambda i, j: sp.diff(momentum[i], dq[j]))
    h = sp.Matrix([sum(sp.diff(momentum[i], q[j]) * dq[j] for j in range(n))
                   - sp.diff(T, q[i]) + sp.diff(V, q[i]) for i in range(n)])
    return q, dq, M, h


def counting_intermediate(self, *args) -> bool:
    """Ipopt's per-iteration callback for opty's Problem: records the objective as opty
    does, counts iterations, and stops the solve at its deadline."""
    self.obj_value.append(args[2])
    self.iterations = int(args[1])
    if time.perf_counter() > self.deadline:
        self.capped = True
        return False
    return True


def opty_problem(spec: dict):
    """Equations of motion in dynamicsymbols, the check of M and h, and the opty Problem."""
    import sympy as sp
    import sympy.physics.mechanics as me
    from opty import Problem

    started = time.perf_counter()
    robot, task = spec["robot"], spec["task"]
    links = robot["links"]
    n = len(links)
    active = [i for i, link in enumerate(links) if link["joint"] == "active"]
    qs, dqs, M, h = lagrangian_dynamics(robot)
    check = spec["check"]
    M_num, h_num = sp.lambdify([qs, dqs], [M, h], "numpy")(check["q"], check["dq"])
    check_out = {"M_error": float(np.abs(np.array(M_num, float) - np.array(check["M"])).max()),
                 "h_error": float(np.abs(np.array(h_num, float).ravel()
                                         - np.array(check["h"])).max())}

    t = me.dynamicsymbols._t
    q = me.dynamicsymbols(" ".join(f"q{i}" for i in range(n)), seq=True)
    u = me.dynamicsymbols(" ".join(f"u{i}" for i in range(n)), seq=True)
    tau = me.dynamicsymbols(" ".join(f"tau{j}" for j in range(len(active))), seq=True)
    to_time = {**dict(zip(qs, q, strict=True)), **dict(zip(dqs, u, strict=True))}
    M_t, h_t = M.xreplace(to_time), h.xreplace(to_time)
    Btau = sp.Matrix([tau[active.index(i)] if i in active else 0 for i in range(n)])
    udot = sp.Matrix([v.diff(t) for v in u])
    eom = sp.Matrix([q[i].diff(t) - u[i] for i in range(n)]).col_join(M_t * udot + h_t - Btau)
    derive_time = time.perf_counter() - started

    N, duration = spec["nodes"], float(task["duration"])
    step = duration / (N - 1)
    instance = tuple(
        [q[i].func(0.0) - task["initial"]["q"][i] for i in range(n)]
        + [u[i].func(0.0) - task["initial"]["dq"][i] for i in range(n)]
        + [q[i].func(duration) - task["final"]["q"][i] for i in range(n)]
        + [u[i].func(duration) - task["final"]["dq"][i] for i in range(n)])
    states = tuple(q) + tuple(u)
    na, ns = len(active), 2 * n
    midpoint = spec["method"] == "midpoint"

    def objective(free):
        U = free[ns * N:ns * N + na * N].reshape(na, N)
        if midpoint:
            a, b = U[:, :-1], U[:, 1:]
            return float(step * np.sum(a * a + a * b + b * b) / 3)
        return float(step * np.sum(U * U))

    def gradient(free):
        grad = np.zeros_like(free)
        U = free[ns * N:ns * N + na * N].reshape(na, N)
        if midpoint:
            G = np.zeros_like(U)
            a, b = U[:, :-1], U[:, 1:]
            G[:, :-1] += step * (2 * a + b) / 3
            G[:, 1:] += step * (a + 2 * b) / 3
        else:
            G = 2 * step * U
        grad[ns * N:ns * N + na * N] = G.ravel()
        return grad

    started = time.perf_counter()
    Problem.intermediate = counting_intermediate  # (opty's Problem cannot be subclassed)
    prob = Problem(objective, gradient, eom, states, N, step, instance_constraints=instance,
                   time_symbol=t, integration_method=spec["method"])
    build_time = time.perf_counter() - started
    order = [str(s.func) for s in prob.collocator.unknown_input_trajectories]
    assert order == [str(s.func) for s in tau], order
    prob.add_option("print_level", 0)
    prob.add_option("tol", float(spec["tol"]))
    return prob, {**check_out, "derive_time": derive_time, "build_time": build_time,
                  "free": prob.num_free, "constraints": prob.num_constraints}


def worker(spec: dict) -> dict:
    """Build and solve one opty point; the plan, timings and the check of M and h.

    Optional spec keys: "solve_cap" [s], a solve's own cap (default SOLVE_CAP), and
    "wall_time" [s], a cap on everything from here (derivation, compilation, solves)."""
    import cyipopt
    import opty
    import sympy

    started = time.perf_counter()
    prob, out = opty_problem(spec)
    N, n = spec["nodes"], len(spec["robot"]["links"])
    cap = float(spec.get("solve_cap", SOLVE_CAP))
    end = started + float(spec.get("wall_time", math.inf))
    guess = spec["guess"]
    free0 = np.concatenate([np.asarray(guess["q"], float).T.ravel(),
                            np.asarray(guess["dq"], float).T.ravel(),
                            np.asarray(guess["tau"], float).T.ravel()])
    assert free0.size == prob.num_free, (free0.size, prob.num_free)
    solves = []
    for k in range(spec["repeats"]):
        prob.obj_value.clear()
        prob.iterations, prob.capped = 0, False
        wall, cpu = time.perf_counter(), time.process_time()
        prob.deadline = min(wall + cap, end)
        free, info = prob.solve(free0.copy())
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        status = IPOPT_STATUS.get(int(info["status"]), str(info["status"]))
        if prob.capped:
            status = f"stopped at {min(cap, end - started):g} s"
        solves.append({"wall": wall, "cpu": cpu, "iterations": prob.iterations,
                       "status": status, "success": int(info["status"]) in (0, 1),
                       "nlp_objective": float(info["obj_val"])})
        if k == 0 and (wall > ONE_SOLVE_ABOVE or prob.capped):
            break
    states, inputs, _ = prob.parse_free(free)
    states, inputs = np.atleast_2d(states), np.atleast_2d(inputs)
    step = float(spec["task"]["duration"]) / (N - 1)
    return {**out, "solves": solves, "t": (step * np.arange(N)).tolist(),
            "q": states[:n].T.tolist(), "dq": states[n:].T.tolist(), "tau": inputs.T.tolist(),
            "versions": {"opty": opty.__version__, "cyipopt": cyipopt.__version__,
                         "sympy": sympy.__version__, "numpy": np.__version__}}


def main() -> None:
    """`worker` on the spec in the JSON file sys.argv[1], its result to sys.argv[2]."""
    result = worker(json.loads(Path(sys.argv[1]).read_text()))
    Path(sys.argv[2]).write_text(json.dumps(result))
