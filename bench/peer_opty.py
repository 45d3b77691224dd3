"""Peer comparison in one run: the planner, the Opti baseline and opty (direct collocation in
SymPy, solved by Ipopt through cyipopt; bench/peers/opty.py).

This side (the project's .venv) installs opty into its own virtualenv `.venv-opty` if it is
not there (Debian's Ipopt development packages, then `pip install opty cyipopt sympy numpy
scipy`, cyipopt built from source), defines the scenes (bench/scenes.py), solves them
with the planner, sends each opty point to bench/peers/opty.py run by `.venv-opty`'s
interpreter (JSON in and out), verifies opty's plan with the planner's own simulator and
writes the report.

For each scene ("arm-2", "under-2", optionally "seed-4"), each opty method (backward Euler,
midpoint) and each node count (20, 40, 80 nodes, i.e. 19, 39, 79 intervals; a method
stops once a solve exceeds 120 s):
build time, median wall time of the solves (3; 1 when the first took over 30 s),
iterations, status, objective; re-simulation of opty's torques by CVODES
(`planner.simulate.run`), error against the reference. The planner is measured on the same
scenes with Legendre 5 and Legendre 3 at N = 40, one solve per plan (refinement and
retries off; fresh process each: cold build, then 3 solves with the NLP cached), and so is
the Opti baseline of bench/peers/opti.py (explicit forward dynamics, same collocation and
guess; fresh process, built once, 3 solves). The reference is the planner's plan at
Legendre 5, N = 80, one solve from its default guess.

Torque interpolation consistent with each opty method:
- backward Euler: (x_i - x_{i-1}) / h = f(x_i, u_i), so u_i acts on [t_{i-1}, t_i]:
  zero-order hold of the right-hand sample;
- midpoint: (x_{i+1} - x_i) / h = f((x_i + x_{i+1}) / 2, (u_i + u_{i+1}) / 2): linear
  interpolation of the samples (whose mean over the interval is that average).

Initial guess, both solvers: the planner's default (`planner.ocp.guess.hermite_guess`: cubic
Hermite motion between the boundary states, the torques the active rows of the dynamics ask
for along it), sampled at opty's nodes.

    python -m bench peer_opty [--scenes arm-2 under-2] [--nodes 20 40 80]
        [--methods "backward euler" midpoint]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from bench import harness
from bench.peers import opti as baseline_opti
from bench.peers.opty import ONE_SOLVE_ABOVE, SOLVE_CAP
from bench.plans import dense_error
from bench.scenes import fixed_duration, make_scene
from planner.dynamics import Dynamics
from planner.model import Robot
from planner.ocp import Plan, plan
from planner.ocp.guess import hermite_guess
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.transcription import Interpolant
from planner.scene import Scene
from planner.simulate import SimulationRequest, run

VENV = harness.ROOT / ".venv-opty"
VENV_PYTHON = VENV / "bin" / "python"
DEBIAN = ["coinor-libipopt-dev", "pkg-config", "liblapack-dev", "libblas-dev"]
PIP = ["opty", "cyipopt", "sympy", "numpy", "scipy"]
METHODS = ("backward euler", "midpoint")
NODES = (20, 40, 80)
WORKER_TIMEOUT = 900.0  # [s] one worker process (derivation, compilation, solves)
REFERENCE = {"degree": 5, "N": 80}
PLANNER_POINTS = ((5, 40), (3, 40))  # (Legendre degree, N)
CHECK_TOL = 1e-10
DOC = harness.DOCS / "benchmarks.md"
SECTION = "Peer comparison: Opti baseline and opty"


def run_quietly(command: list[str]) -> subprocess.CompletedProcess:
    """A command's completed process, its output captured."""
    return subprocess.run(command, cwd=harness.ROOT, capture_output=True, text=True,
                          check=False, env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})


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
    started = time.perf_counter()
    if opty_ready():
        return {"seconds": 0.0, "steps": "already installed"}
    missing = [p for p in DEBIAN if subprocess.run(["dpkg", "-s", p], capture_output=True,
                                                   check=False).returncode != 0]
    if missing:
        for command in (["apt-get", "update", "-q"], ["apt-get", "install", "-y", "-q", *missing]):
            done = run_quietly(command)
            if done.returncode:
                return {"failure": (" ".join(command), last_error_line(done))}
    for command in (["python3", "-m", "venv", str(VENV)],
                    [str(VENV_PYTHON), "-m", "pip", "install", "-q", *PIP]):
        done = run_quietly(command)
        if done.returncode:
            return {"failure": (" ".join(command), last_error_line(done))}
    if not opty_ready():
        done = subprocess.run([str(VENV_PYTHON), "-c", "import opty, cyipopt"],
                              capture_output=True, text=True, check=False)
        return {"failure": (f"{VENV_PYTHON} -c 'import opty, cyipopt'", last_error_line(done))}
    return {"seconds": time.perf_counter() - started,
            "steps": f"apt-get install {' '.join(missing) or '(none missing)'}; "
                     f"python3 -m venv .venv-opty; pip install {' '.join(PIP)}"}


def call_worker(spec: dict, timeout: float = WORKER_TIMEOUT) -> dict:
    """Run bench.peers.opty's `worker(spec)` in the opty venv; its dict or {"failure": ...}
    (the process is stopped after `timeout` [s])."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.json", Path(tmp) / "out.json"
        src.write_text(json.dumps(spec))
        try:
            done = subprocess.run([str(VENV_PYTHON), "-c",
                                   "from bench.peers.opty import main; main()", str(src),
                                   str(dst)], cwd=harness.ROOT, capture_output=True,
                                  text=True, check=False, timeout=timeout)
        except subprocess.TimeoutExpired:
            return harness.timed_out(timeout)
        if dst.exists():
            return json.loads(dst.read_text())
        return {"failure": f"exit {done.returncode}: {last_error_line(done)}"}


def planner_point(scene_name: str, degree: int, N: int, reference_path: str,
                  repeats: int = 3) -> dict:
    """The planner on a scene in a fresh process: cold build, then `repeats` solves with the
    NLP cached, one solve per plan (run by `isolated`)."""
    scene = make_scene(scene_name, "legendre", N, degree, one_solve=True)
    build_time, _ = harness.build_instrumented(scene)
    plans = [plan(scene) for _ in range(repeats)]
    ref = Plan.model_validate_json(Path(reference_path).read_text())
    first = plans[0]
    return {"build": build_time, "solve": harness.median(p.solver.solve_time for p in plans),
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
    return {"build": first["build_time"],
            "solve": harness.median(r["solve_time"] for r in runs),
            "runs": repeats, "iterations": first["iterations"], "status": first["status"],
            "objective": first["objective"], "resim_error": first["resimulation_error"],
            "ref_error": ref_error}


def check_state(robot: Robot, rng: np.random.Generator) -> dict:
    """A random state and the planner's M and h there (the worker must reproduce them)."""
    n = robot.n
    q, dq = rng.uniform(-math.pi, math.pi, n), rng.uniform(-2.0, 2.0, n)
    dyn = Dynamics(robot)
    return {"q": q.tolist(), "dq": dq.tolist(), "M": dyn.mass_matrix(q).tolist(),
            "h": dyn.bias(q, dq).tolist()}


def interpolant(scene: Scene, method: str, out: dict) -> Interpolant | None:
    """opty's plan as the planner's interpolant, None when it has non-finite entries: the
    torque its method implies (backward Euler: the right-hand sample held; midpoint:
    linear between the samples), q cubic Hermite from q and dq at both nodes, dq cubic
    Hermite from dq and the accelerations fd(q, dq, tau) at both nodes."""
    t, q, dq = np.asarray(out["t"]), np.asarray(out["q"]), np.asarray(out["dq"])
    tau = np.asarray(out["tau"])
    if not all(np.all(np.isfinite(a)) for a in (t, q, dq, tau)):
        return None
    h = np.diff(t)[:, None, None]
    if method == "backward euler":
        torque = tau[1:, None, :]
    else:
        torque = np.stack([tau[:-1], tau[1:] - tau[:-1]], axis=1)
    ddq = Dynamics(scene.robot).forward_many(q, dq, tau)
    if not np.all(np.isfinite(ddq)):
        return None
    hermite = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                        [-3.0, -2.0, 3.0, -1.0], [2.0, 1.0, -2.0, 1.0]])

    def cubic(y: np.ndarray, dy: np.ndarray) -> PiecewisePolynomial:
        ends = np.stack([y[:-1], h[:, 0] * dy[:-1], y[1:], h[:, 0] * dy[1:]], axis=1)
        return PiecewisePolynomial(t, np.einsum("mj,kjd->kmd", hermite, ends))

    return Interpolant(cubic(q, dq), cubic(dq, ddq), PiecewisePolynomial(t, torque))


def verify_opty(scene: Scene, method: str, out: dict, ref: Plan) -> dict:
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


def scene_rows(name: str, nodes: list[int], methods: list[str], rng: np.random.Generator,
               log: Callable[[str], None]) -> tuple[list[dict], Plan]:
    """The planner's, the baseline's and opty's rows of one scene, and its reference plan."""
    rows = []
    ref_scene = make_scene(name, "legendre", REFERENCE["N"], REFERENCE["degree"],
                           one_solve=True)
    ref = plan(ref_scene)
    log(f"{name}: reference {ref.solver.status}, objective {ref.objective:.6g}, "
        f"open-loop replay {ref.verification.resimulation_error:.2e}")
    with tempfile.TemporaryDirectory() as tmp:
        ref_path = Path(tmp) / "reference.json"
        ref_path.write_text(ref.model_dump_json())
        for function, solver, timeout in ((planner_point, "undertow", 600.0),
                                          (baseline_point, "Opti baseline", 900.0)):
            for degree, N in PLANNER_POINTS:
                out = harness.isolated("peer_opty", function.__name__,
                               {"scene_name": name, "degree": degree, "N": N,
                                "reference_path": str(ref_path)}, timeout)
                rows.append({"scene": name, "solver": solver, "method": f"Legendre {degree}",
                             "N": N, "load": harness.load(), **out})
                log(f"{name}: {solver} Legendre {degree} N={N}: {out}")

    scene = make_scene(name)
    check = check_state(scene.robot, rng)
    guess_of = hermite_guess(scene, scene.robot, fixed_duration(scene))
    for method in methods:
        stop = ""
        for N in nodes:
            row = {"scene": name, "solver": "opty", "method": method, "N": N,
                   "load": harness.load()}
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
                        "solve": harness.median(s["wall"] for s in solves),
                        "solve_cpu": harness.median(s["cpu"] for s in solves),
                        "runs": len(solves),
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
           ("objective", "objective"), ("resim_error", "open-loop replay [rad]"),
           ("ref_error", "error vs reference [rad]")]
CSV_KEYS = ["scene", "solver", "method", "N", "status", "runs", "build", "derive", "solve",
            "solve_cpu", "iterations", "objective", "nlp_objective", "resim_error",
            "ref_error", "ref_error_nodes", "interpolation", "variables", "constraints",
            "M_error", "h_error", "wall", "load", "note"]


def report(rows: list[dict], refs: dict[str, Plan], install: str, versions: dict | None,
           nodes: list[int]) -> str:
    ipopt = subprocess.run(["pkg-config", "--modversion", "ipopt"], capture_output=True,
                           text=True, check=False).stdout.strip() or "?"
    v = versions or {}
    opty_rows = [r for r in rows if r["solver"] == "opty"]
    parts = [
        f"opty {v.get('opty', '?')} and cyipopt {v.get('cyipopt', '?')} (built from source "
        f"against Debian's Ipopt {ipopt} with MUMPS) live in their own virtualenv "
        f"`.venv-opty`, which the benchmark makes on first use ({install}); SymPy "
        f"{v.get('sympy', '?')}, NumPy {v.get('numpy', '?')} there. The project-venv side "
        "(bench/peer_opty.py) defines the scenes, runs the planner and verifies; for each opty "
        "point it runs bench/peers/opty.py with `.venv-opty`'s interpreter and exchanges JSON "
        "(nodes, t, q, dq, tau, timings, status). The Opti baseline (`bench/peers/opti.py`: "
        "the script a CasADi user would write, explicit forward dynamics solve(M, Bτ − h), "
        "the planner's Legendre collocation and guess, Ipopt's default options) runs at the "
        "planner's points, each in a fresh process: built once, 3 solves; its errors are "
        "those of its collocation interpolant.",
        "Same continuous problem for both: the scene's robot, boundary states and duration, "
        "objective ∫|τ|² dt, Ipopt tolerance 1e-8. opty gets the equations of motion "
        "M(q) u̇ + h(q, u) = B τ (with q̇ = u) derived in the worker by SymPy from the "
        "Lagrangian of the chain, waves and the cumulative rotational term included; before "
        "any timing the worker's M and h are checked against `planner.dynamics` at a random "
        f"state (largest difference {max((r.get('M_error', 0) for r in opty_rows), default=0):.1e} "
        f"in M, {max((r.get('h_error', 0) for r in opty_rows), default=0):.1e} in h; "
        f"the benchmark asserts {CHECK_TOL:g}). Initial guess for both: the planner's default "
        "(cubic Hermite motion between the boundary states and the torques the active rows of "
        "the dynamics ask for along it), sampled at opty's nodes.",
        "Caveats. opty transcribes by backward Euler (first order) or the implicit midpoint "
        "rule (second order) only, against the planner's Legendre collocation of degree 3 and "
        "5 (order 6 and 10 at the nodes); to reach a given error it needs far more nodes. "
        "opty passes Ipopt no Hessian, so Ipopt runs limited-memory BFGS (the planner gives "
        "the exact Hessian of the Lagrangian). Each new opty problem (new N or method) is "
        "generated and compiled to C by Cython: that is its build time. Node counts N for "
        f"opty ({', '.join(map(str, nodes))} nodes, i.e. N − 1 intervals), interval counts "
        "for the planner, which makes one solve per plan (mesh refinement and retries off). "
        "opty's torque is re-simulated by CVODES (`planner.simulate.run`, "
        "rtol = atol = 1e-10) with the interpolation its method implies: backward Euler "
        "holds each interval's right-hand sample (zero-order hold), midpoint interpolates "
        "linearly; its objective column is ∫|τ|² dt of that interpolant (the NLP's own "
        "objective). Open-loop replay: max |q_sim − q_plan| over the whole horizon from the "
        "planned start, at opty's nodes; for the planner and the baseline at the breakpoints "
        "and three points between each two (the planner's own verification). Error vs "
        "reference: max |q − q_ref| over the reference's dense grid, the reference being "
        f"the planner at Legendre {REFERENCE['degree']}, N = {REFERENCE['N']} from its default "
        "guess; opty's nodes are joined by a not-a-knot cubic spline (the CSV also has the "
        "error at the nodes alone). Solve time: wall time of `Problem.solve` (opty, Python "
        "callbacks included) and of Ipopt (planner), median of 3 solves (1 when the first "
        f"took over {ONE_SOLVE_ABOVE:g} s); a solve is stopped at {SOLVE_CAP:g} s and its "
        "method then goes no finer. Planner build: cold, in a fresh process. Ipopt's "
        "iteration limit is its default 3000 for opty, the planner's 500.",
    ]
    for name, ref in refs.items():
        mine = [r for r in rows if r["scene"] == name]
        parts.append(f"### {name}\n\nReference: objective {ref.objective:.6g}, "
                     f"{ref.solver.iterations} iterations, interval error "
                     f"{ref.verification.local_error:.1e} rad, open-loop replay "
                     f"{ref.verification.resimulation_error:.1e} rad.\n\n"
                     + harness.table(mine, COLUMNS))
    return "\n\n".join(parts)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench peer_opty", description=__doc__)
    parser.add_argument("--scenes", nargs="+", default=["arm-2", "under-2"])
    parser.add_argument("--nodes", nargs="+", type=int, default=list(NODES))
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    args = parser.parse_args(argv)
    started = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - started:7.1f} s] {message}", flush=True)

    install = install_opty()
    if "failure" in install:
        what, error = install["failure"]
        harness.write_section(DOC, SECTION,
                              f"Not run: installing opty failed. `{what}` ended with\n\n"
                              f"    {error}\n\n"
                              + harness.manifest("peer_opty", argv, started,
                                                 harness.machine_note()))
        log(f"install failed: {what}: {error}")
        return 1
    install_note = (f"{install['seconds']:.0f} s: {install['steps']}" if install["seconds"]
                    else "it was already there for this run")
    log(f"opty ready ({install_note})")
    note = harness.machine_note()
    rng = np.random.default_rng(6)
    rows, refs = [], {}
    for name in args.scenes:
        scene_out, refs[name] = scene_rows(name, args.nodes, args.methods, rng, log)
        rows += scene_out
    versions = next((r["versions"] for r in rows if "versions" in r), None)
    harness.write_csv(harness.RESULTS / "peer_opty.csv",
                      [{k: r.get(k) for k in CSV_KEYS} for r in rows])
    text = "\n\n".join([
        report(rows, refs, install_note, versions, args.nodes),
        f"Rows: `bench/results/peer_opty.csv`. "
        f"{harness.manifest('peer_opty', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    log("done")
    return 0
