"""Peer comparison in one run: the planner, the Opti baseline and opty (direct collocation in
SymPy, solved by Ipopt through cyipopt).

Two parts in one file, run by two interpreters:

- the driver (the project's .venv): installs opty into its own virtualenv `.venv-opty` if
  it is not there (Debian's Ipopt development packages, then `pip install opty cyipopt
  sympy numpy scipy`, cyipopt built from source), defines the scenes (bench/common.py),
  solves them with the planner, sends each opty point to the worker, verifies opty's plan
  with the planner's own simulator and writes the report;
- the worker (`.venv-opty/bin/python bench/peer_opty.py --worker IN OUT`, JSON in and out):
  derives the equations of motion M(q) u' + h(q, u) = B tau by SymPy from the Lagrangian of
  the planar chain (docs/model.md: absolute angles, wave r = l + a sin(n q + eps), point
  masses at the tips, rotational term by the robot's convention), checks M and h at the
  driver's random state, builds the opty problem (compilation included in the build time)
  and solves it from the given initial guess.

For each scene ("arm-2", "under-2", optionally "seed-4"), each opty method (backward Euler,
midpoint) and each node count (20, 40, 80 nodes, i.e. 19, 39, 79 intervals; a method
stops once a solve exceeds 120 s):
build time, median wall time of the solves (3; 1 when the first took over 30 s),
iterations, status, objective; re-simulation of opty's torques by CVODES
(`planner.simulate.run`), error against the reference. The planner is measured on the same
scenes with Legendre 5 and Legendre 3 at N = 40 (fresh process each: cold build, then 3
solves with the NLP cached), and so is the Opti baseline of bench/peers/opti.py (explicit
forward dynamics, same collocation and guess; fresh process, built once, 3 solves). The reference is the planner's plan at Legendre 5, N = 80,
from its default guess.

Torque interpolation consistent with each opty method:
- backward Euler: (x_i - x_{i-1}) / h = f(x_i, u_i), so u_i acts on [t_{i-1}, t_i]:
  zero-order hold of the right-hand sample;
- midpoint: (x_{i+1} - x_i) / h = f((x_i + x_{i+1}) / 2, (u_i + u_{i+1}) / 2): linear
  interpolation of the samples (whose mean over the interval is that average).
The effort objective of the opty NLP is the exact integral of |tau|^2 of that interpolant
(backward Euler: h sum_i |u_i|^2 over all nodes; u_0 acts on no interval and goes to 0).

Initial guess, both solvers: the planner's default (`planner.ocp.guess.hermite_guess`: cubic
Hermite motion between the boundary states, the torques the active rows of the dynamics ask
for along it), sampled at opty's nodes.

    .venv/bin/python bench/peer_opty.py [--scenes arm-2 under-2] [--nodes 20 40 80]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VENV = ROOT / ".venv-opty"
VENV_PYTHON = VENV / "bin" / "python"
DEBIAN = ["coinor-libipopt-dev", "pkg-config", "liblapack-dev", "libblas-dev"]
PIP = ["opty", "cyipopt", "sympy", "numpy", "scipy"]
METHODS = ("backward euler", "midpoint")
NODES = (20, 40, 80)
SOLVE_CAP = 120.0  # [s] a solve stops here (intermediate callback), and its method goes no finer
ONE_SOLVE_ABOVE = 30.0  # [s] a first solve this long is not repeated
WORKER_TIMEOUT = 900.0  # [s] one worker process (derivation, compilation, solves)
REFERENCE = {"degree": 5, "N": 80}
PLANNER_POINTS = ((5, 40), (3, 40))  # (Legendre degree, N)
CHECK_TOL = 1e-10
SECTION = "Peer comparison: Opti baseline and opty"
IPOPT_STATUS = {0: "Solve_Succeeded", 1: "Solved_To_Acceptable_Level",
                2: "Infeasible_Problem_Detected", 3: "Search_Direction_Becomes_Too_Small",
                4: "Diverging_Iterates", 5: "User_Requested_Stop", 6: "Feasible_Point_Found",
                -1: "Maximum_Iterations_Exceeded", -2: "Restoration_Failed",
                -3: "Error_In_Step_Computation", -4: "Maximum_CpuTime_Exceeded",
                -10: "Not_Enough_Degrees_Of_Freedom", -11: "Invalid_Problem_Definition",
                -12: "Invalid_Option", -13: "Invalid_Number_Detected",
                -100: "Unrecoverable_Exception", -101: "NonIpopt_Exception_Thrown",
                -102: "Insufficient_Memory", -199: "Internal_Error"}

if importlib.util.find_spec("casadi") is not None:  # the driver's side (project venv)
    sys.path.insert(0, str(ROOT))
    from scipy.interpolate import CubicSpline

    from bench.peers import opti as baseline_opti
    from bench.common import (
        DOCS,
        RESULTS,
        build_instrumented,
        dense_error,
        isolated,
        load,
        machine_note,
        make_scene,
        median,
        table,
        write_csv,
        write_section,
    )
    from planner.dynamics import Dynamics
    from planner.ocp import Plan, plan
    from planner.ocp.guess import hermite_guess
    from planner.simulate import SimulationRequest, run


# ----------------------------------------------------------------------------- worker side

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
            r = r + sp.Float(a) * sp.sin(sp.Float(wave["frequency"]) * q[i] + sp.Float(wave["phase"]))
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
                 "h_error": float(np.abs(np.array(h_num, float).ravel() - np.array(check["h"])).max())}

    t = me.dynamicsymbols._t
    q = me.dynamicsymbols(" ".join(f"q{i}" for i in range(n)), seq=True)
    u = me.dynamicsymbols(" ".join(f"u{i}" for i in range(n)), seq=True)
    tau = me.dynamicsymbols(" ".join(f"tau{j}" for j in range(len(active))), seq=True)
    to_time = {**dict(zip(qs, q)), **dict(zip(dqs, u))}
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
    """Build and solve one opty point; the plan, timings and the check of M and h."""
    import cyipopt
    import opty
    import sympy

    prob, out = opty_problem(spec)
    N, n = spec["nodes"], len(spec["robot"]["links"])
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
        prob.deadline = wall + SOLVE_CAP
        free, info = prob.solve(free0.copy())
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        status = IPOPT_STATUS.get(int(info["status"]), str(info["status"]))
        if prob.capped:
            status = f"stopped at {SOLVE_CAP:g} s"
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


# ----------------------------------------------------------------------------- driver side

def run_logged(command: list[str], log: list[str]) -> subprocess.CompletedProcess:
    log.append("$ " + " ".join(command))
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False,
                          env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
    log.append(f"exit {done.returncode}")
    return done


def last_error_line(done: subprocess.CompletedProcess) -> str:
    lines = [line for line in (done.stderr + "\n" + done.stdout).splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or ["no output"])[-1].strip()[:300]


def opty_ready() -> bool:
    if not VENV_PYTHON.exists():
        return False
    done = subprocess.run([str(VENV_PYTHON), "-c", "import opty, cyipopt, sympy, scipy"],
                          capture_output=True, check=False)
    return done.returncode == 0


def install_opty() -> dict:
    """Make `.venv-opty` with opty; {"seconds", "steps"} or {"failure": (command, error line)}."""
    started, log = time.perf_counter(), []
    if opty_ready():
        return {"seconds": 0.0, "steps": "already installed"}
    missing = [p for p in DEBIAN if subprocess.run(["dpkg", "-s", p], capture_output=True,
                                                   check=False).returncode != 0]
    if missing:
        for command in (["apt-get", "update", "-q"], ["apt-get", "install", "-y", "-q", *missing]):
            done = run_logged(command, log)
            if done.returncode:
                return {"failure": (" ".join(command), last_error_line(done))}
    for command in (["python3", "-m", "venv", str(VENV)],
                    [str(VENV_PYTHON), "-m", "pip", "install", "-q", *PIP]):
        done = run_logged(command, log)
        if done.returncode:
            return {"failure": (" ".join(command), last_error_line(done))}
    if not opty_ready():
        done = subprocess.run([str(VENV_PYTHON), "-c", "import opty, cyipopt"],
                              capture_output=True, text=True, check=False)
        return {"failure": (f"{VENV_PYTHON} -c 'import opty, cyipopt'", last_error_line(done))}
    return {"seconds": time.perf_counter() - started,
            "steps": f"apt-get install {' '.join(missing) or '(none missing)'}; "
                     f"python3 -m venv .venv-opty; pip install {' '.join(PIP)}"}


def call_worker(spec: dict) -> dict:
    """Run `worker(spec)` in the opty venv; its dict or {"failure": ...}."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.json", Path(tmp) / "out.json"
        src.write_text(json.dumps(spec))
        try:
            done = subprocess.run([str(VENV_PYTHON), str(Path(__file__).resolve()), "--worker",
                                   str(src), str(dst)], cwd=ROOT, capture_output=True,
                                  text=True, check=False, timeout=WORKER_TIMEOUT)
        except subprocess.TimeoutExpired:
            return {"failure": f"timeout after {WORKER_TIMEOUT:g} s"}
        if dst.exists():
            return json.loads(dst.read_text())
        return {"failure": f"exit {done.returncode}: {last_error_line(done)}"}


def planner_point(scene_name: str, degree: int, N: int, reference_path: str,
                  repeats: int = 3) -> dict:
    """The planner on a scene in a fresh process: cold build, then `repeats` solves with the
    NLP cached (run by `isolated`)."""
    scene = make_scene(scene_name, "legendre", N, degree)
    build_time, _ = build_instrumented(scene)
    plans = [plan(scene) for _ in range(repeats)]
    ref = Plan.model_validate_json(Path(reference_path).read_text())
    first = plans[0]
    return {"build": build_time, "solve": median(p.solver.solve_time for p in plans),
            "runs": repeats, "iterations": first.solver.iterations,
            "status": first.solver.status, "objective": first.objective,
            "resim_error": first.verification.resimulation_error,
            "ref_error": dense_error(first, ref)}


def baseline_point(scene_name: str, degree: int, N: int, reference_path: str,
                   repeats: int = 3) -> dict:
    """The Opti baseline (bench/peers/opti.py) on a scene in a fresh process: built once,
    solved `repeats` times from the planner's guess; the error of its first solution's
    interpolant against the reference (run by `isolated`)."""
    scene = make_scene(scene_name, "legendre", N, degree)
    built = baseline_opti.build(scene)
    first = baseline_opti.solve(scene, built)
    interp = baseline_opti.interpolant(scene, built, built.value)
    runs = [first] + [baseline_opti.solve(scene, built) for _ in range(repeats - 1)]
    ref = Plan.model_validate_json(Path(reference_path).read_text())
    t = np.asarray(ref.dense.t)
    ref_error = (math.nan if interp is None
                 else float(np.abs(interp.q(t) - np.asarray(ref.dense.q)).max()))
    return {"build": first["build_time"], "solve": median(r["solve_time"] for r in runs),
            "runs": repeats, "iterations": first["iterations"], "status": first["status"],
            "objective": first["objective"], "resim_error": first["resimulation_error"],
            "ref_error": ref_error}


def check_state(robot, rng: np.random.Generator) -> dict:
    """A random state and the planner's M and h there (the worker must reproduce them)."""
    n = robot.n
    q, dq = rng.uniform(-math.pi, math.pi, n), rng.uniform(-2.0, 2.0, n)
    dyn = Dynamics(robot)
    return {"q": q.tolist(), "dq": dq.tolist(), "M": dyn.mass_matrix(q).tolist(),
            "h": dyn.bias(q, dq).tolist()}


def verify_opty(scene, method: str, out: dict, ref: Plan) -> dict:
    """Re-simulate opty's torques with CVODES (the interpolation its method implies) and
    compare with the reference; the exact effort of that torque interpolant."""
    t, q, tau = np.asarray(out["t"]), np.asarray(out["q"]), np.asarray(out["tau"])
    h = t[1] - t[0]
    if method == "backward euler":  # u_i on [t_{i-1}, t_i]: hold the right-hand sample
        samples, kind = np.vstack([tau[1:], tau[-1:]]), "zoh"
        effort = float(h * np.sum(tau[1:] ** 2))
    else:
        samples, kind = tau, "linear"
        a, b = tau[:-1], tau[1:]
        effort = float(h * np.sum(a * a + a * b + b * b) / 3)
    if not np.all(np.isfinite(q)) or not np.all(np.isfinite(tau)):
        return {"objective": effort, "resim_error": math.nan, "ref_error": math.nan,
                "ref_error_nodes": math.nan, "interpolation": kind}
    request = SimulationRequest.model_validate({
        "robot": scene.robot.model_dump(), "t": t.tolist(), "tau": samples.tolist(),
        "interpolation": kind, "initial": {"q": q[0].tolist(), "dq": out["dq"][0]}})
    sim = run(request)
    resim = (float(np.abs(np.asarray(sim.q) - q).max()) if sim.status == "completed"
             else math.nan)
    ref_q = CubicSpline(np.asarray(ref.dense.t), np.asarray(ref.dense.q))
    dense_t = np.asarray(ref.dense.t)
    ours = CubicSpline(t, q)(dense_t)
    return {"objective": effort, "resim_error": resim,
            "ref_error": float(np.abs(ours - ref_q(dense_t)).max()),
            "ref_error_nodes": float(np.abs(q - ref_q(t)).max()), "interpolation": kind,
            "resim_status": sim.status}


def scene_rows(name: str, nodes: list[int], methods: list[str], rng, log) -> list[dict]:
    rows = []
    ref_scene = make_scene(name, "legendre", REFERENCE["N"], REFERENCE["degree"])
    ref = plan(ref_scene)
    log(f"{name}: reference {ref.solver.status}, objective {ref.objective:.6g}, "
        f"re-sim. error {ref.verification.resimulation_error:.2e}")
    with tempfile.TemporaryDirectory() as tmp:
        ref_path = Path(tmp) / "reference.json"
        ref_path.write_text(ref.model_dump_json())
        for function, solver, timeout in (("planner_point", "undertow", 600.0),
                                          ("baseline_point", "Opti baseline", 900.0)):
            for degree, N in PLANNER_POINTS:
                out = isolated("peer_opty", function,
                               {"scene_name": name, "degree": degree, "N": N,
                                "reference_path": str(ref_path)}, timeout)
                rows.append({"scene": name, "solver": solver, "method": f"Legendre {degree}",
                             "N": N, "load": load(), **out})
                log(f"{name}: {solver} Legendre {degree} N={N}: {out}")

    scene = make_scene(name)
    check = check_state(scene.robot, rng)
    guess_of = hermite_guess(scene, scene.robot, float(scene.task.duration))
    for method in methods:
        stop = ""
        for N in nodes:
            row = {"scene": name, "solver": "opty", "method": method, "N": N, "load": load()}
            if stop:
                rows.append({**row, "status": "skipped", "note": stop})
                continue
            g = guess_of(np.linspace(0.0, 1.0, N))
            spec = {"robot": scene.robot.model_dump(), "task": scene.task.model_dump(),
                    "method": method, "nodes": N, "tol": scene.solver.tol, "repeats": 3,
                    "check": check, "guess": {k: g[k].tolist() for k in ("q", "dq", "tau")}}
            started = time.perf_counter()
            out = call_worker(spec)
            row["wall"] = time.perf_counter() - started
            if "failure" in out:
                rows.append({**row, "status": "failed", "note": out["failure"]})
                log(f"{name}: opty {method} N={N}: {out['failure']}")
                stop = f"skipped: N = {N} failed"
                continue
            M_scale = max(1.0, float(np.abs(check["M"]).max()))
            h_scale = max(1.0, float(np.abs(check["h"]).max()))
            assert out["M_error"] <= CHECK_TOL * M_scale, ("M", out["M_error"])
            assert out["h_error"] <= CHECK_TOL * h_scale, ("h", out["h_error"])
            solves = out["solves"]
            first = solves[0]
            row.update({"build": out["build_time"], "derive": out["derive_time"],
                        "solve": median(s["wall"] for s in solves),
                        "solve_cpu": median(s["cpu"] for s in solves), "runs": len(solves),
                        "iterations": first["iterations"], "status": first["status"],
                        "nlp_objective": first["nlp_objective"], "M_error": out["M_error"],
                        "h_error": out["h_error"], "variables": out["free"],
                        "constraints": out["constraints"]})
            row.update(verify_opty(scene, method, out, ref))
            row["versions"] = out["versions"]
            log(f"{name}: opty {method} N={N}: build {row['build']:.1f} s, solve "
                f"{row['solve']:.3g} s, {row['iterations']} it, {row['status']}, "
                f"J {row['objective']:.4g}, resim {row['resim_error']:.2e}, "
                f"ref {row['ref_error']:.2e}")
            rows.append(row)
            if any(s["wall"] > SOLVE_CAP or s["status"].startswith("stopped") for s in solves):
                stop = f"skipped: a solve at N = {N} exceeded {SOLVE_CAP:g} s"
    return rows, ref


COLUMNS = [("solver", "solver"), ("method", "method"), ("N", "N"), ("build", "build [s]"),
           ("solve", "solve [s]"), ("iterations", "iterations"), ("status", "status"),
           ("objective", "objective"), ("resim_error", "re-sim. error [rad]"),
           ("ref_error", "error vs reference [rad]")]
CSV_KEYS = ["scene", "solver", "method", "N", "status", "runs", "build", "derive", "solve",
            "solve_cpu", "iterations", "objective", "nlp_objective", "resim_error",
            "ref_error", "ref_error_nodes", "interpolation", "variables", "constraints",
            "M_error", "h_error", "wall", "load", "note"]


def report(rows, refs, install, versions, note, command, minutes, nodes) -> str:
    ipopt = subprocess.run(["pkg-config", "--modversion", "ipopt"], capture_output=True,
                           text=True, check=False).stdout.strip() or "?"
    v = versions or {}
    parts = [
        f"Generated by `{command}` in {minutes:.0f} min. opty {v.get('opty', '?')} and cyipopt "
        f"{v.get('cyipopt', '?')} (built from source against Debian's Ipopt {ipopt} with "
        f"MUMPS) live in their own virtualenv `.venv-opty`, which the script makes on first "
        f"use ({install}); SymPy {v.get('sympy', '?')}, NumPy {v.get('numpy', '?')} there. "
        "The script's project-venv side defines the scenes, runs the planner and verifies; "
        "for each opty point it starts `.venv-opty/bin/python bench/peer_opty.py --worker` "
        "and exchanges JSON (nodes, t, q, dq, tau, timings, status). The Opti baseline "
        "(`bench/peers/opti.py`: the script a CasADi user would write, explicit forward "
        "dynamics solve(M, Bτ − h), the planner's Legendre collocation and guess, Ipopt's "
        "default options) runs at the planner's points, each in a fresh process: built once, "
        "3 solves; its errors are those of its collocation interpolant.",
        "Same continuous problem for both: the scene's robot, boundary states and duration, "
        "objective ∫|τ|² dt, Ipopt tolerance 1e-8. opty gets the equations of motion "
        "M(q) u̇ + h(q, u) = B τ (with q̇ = u) derived in the worker by SymPy from the "
        "Lagrangian of the chain, waves and the cumulative rotational term included; before "
        f"any timing the worker's M and h are checked against `planner.dynamics` at a random "
        f"state (largest difference {max(r.get('M_error', 0) for r in rows if r['solver'] == 'opty'):.1e} "
        f"in M, {max(r.get('h_error', 0) for r in rows if r['solver'] == 'opty'):.1e} in h; "
        f"the script asserts {CHECK_TOL:g}). Initial guess for both: the planner's default "
        "(cubic Hermite motion between the boundary states and the torques the active rows of "
        "the dynamics ask for along it), sampled at opty's nodes.",
        "Caveats. opty transcribes by backward Euler (first order) or the implicit midpoint "
        "rule (second order) only, against the planner's Legendre collocation of degree 3 and "
        "5 (order 6 and 10 at the nodes); to reach a given error it needs far more nodes. "
        "opty passes Ipopt no Hessian, so Ipopt runs limited-memory BFGS (the planner gives "
        "the exact Hessian of the Lagrangian). Each new opty problem (new N or method) is "
        "generated and compiled to C by Cython: that is its build time. Node counts N for "
        f"opty ({', '.join(map(str, nodes))} nodes, i.e. N − 1 intervals), interval counts "
        "for the planner. opty's torque is re-simulated by CVODES (`planner.simulate.run`, "
        "rtol = atol = 1e-10) with the interpolation its method implies: backward Euler "
        "holds each interval's right-hand sample (zero-order hold), midpoint interpolates "
        "linearly; its objective column is ∫|τ|² dt of that interpolant (the NLP's own "
        "objective). Re-simulation error: max |q_sim − q_plan| at opty's nodes; for the "
        "planner over its dense output (its own verification). Error vs reference: "
        f"max |q − q_ref| over the reference's dense grid, the reference being the planner at "
        f"Legendre {REFERENCE['degree']}, N = {REFERENCE['N']} from its default guess; "
        "opty's nodes are joined by a not-a-knot cubic spline (the CSV also has the error at "
        "the nodes alone). Solve time: wall time of `Problem.solve` (opty, Python callbacks "
        "included) and of Ipopt (planner), median of 3 solves (1 when the first took over "
        f"{ONE_SOLVE_ABOVE:g} s); a solve is stopped at {SOLVE_CAP:g} s and its method then "
        "goes no finer. Planner build: cold, in a fresh process. Ipopt's iteration limit is "
        "its default 3000 for opty, the planner's 500.",
    ]
    for name, ref in refs.items():
        scene_rows_ = [r for r in rows if r["scene"] == name]
        parts.append(f"### {name}\n\nReference: objective {ref.objective:.6g}, "
                     f"{ref.solver.iterations} iterations, re-simulation error "
                     f"{ref.verification.resimulation_error:.1e} rad.\n\n"
                     + table(scene_rows_, COLUMNS))
    parts.append(note)
    parts.append(f"Command: `{command}`")
    return "\n\n".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["arm-2", "under-2"])
    parser.add_argument("--nodes", nargs="+", type=int, default=list(NODES))
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    args = parser.parse_args()
    command = " ".join([".venv/bin/python bench/peer_opty.py", *sys.argv[1:]])
    started = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - started:7.1f} s] {message}", flush=True)

    install = install_opty()
    if "failure" in install:
        what, error = install["failure"]
        write_section(DOCS / "benchmarks.md", SECTION,
                      f"Not run: installing opty failed. `{what}` ended with\n\n    {error}\n\n"
                      f"Command: `{command}`")
        log(f"install failed: {what}: {error}")
        raise SystemExit(1)
    install_note = (f"{install['seconds']:.0f} s: {install['steps']}" if install["seconds"]
                    else "it was already there for this run")
    log(f"opty ready ({install_note})")
    note = machine_note()
    rng = np.random.default_rng(6)
    rows, refs = [], {}
    for name in args.scenes:
        scene_out, refs[name] = scene_rows(name, args.nodes, args.methods, rng, log)
        rows += scene_out
    versions = next((r["versions"] for r in rows if "versions" in r), None)
    write_csv(RESULTS / "peer_opty.csv", [{k: r.get(k) for k in CSV_KEYS} for r in rows])
    text = report(rows, refs, install_note, versions, note, command,
                  (time.perf_counter() - started) / 60, args.nodes)
    write_section(DOCS / "benchmarks.md", SECTION, text)
    log("done")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--worker":
        result = worker(json.loads(Path(sys.argv[2]).read_text()))
        Path(sys.argv[3]).write_text(json.dumps(result))
    else:
        main()
