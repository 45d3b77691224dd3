"""Measures behind the planner's design choices; writes docs/bench-planner-internals.md.

1. The dynamics residual formed as d/dt(dT/ddq) by one directional derivative against
   M ddq + h: expression nodes and the cost of the Hessian of lambda' r per knot.
2. Interpreted (expanded SX) against compiled (C, solver.jit) NLPs on the same scenes:
   code size, compile time, median solve time, Ipopt iterations.
3. The seed arm's rest-to-rest task through waveless singularities: re-simulation error
   against N for Legendre degree 3.

Run: .venv/bin/python bench/planner_internals.py
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from seed_printed import SEED_ARM  # noqa: E402

from planner.dynamics import derive, functions, selection  # noqa: E402
from planner.model import Robot, Structure, parameters  # noqa: E402
from planner.ocp import plan  # noqa: E402
from planner.scene import Scene  # noqa: E402

SEED = {**SEED_ARM, "gravity": 0.0}
SEED_TASK = {"duration": 4.0,
             "initial": {"q": [0.766, -1.157, -1.148, -1.287], "dq": [0.0] * 4},
             "final": {"q": [0.676, -0.67, -1.306, -1.202], "dq": [0.0] * 4},
             "coupling_margin": 0.02}
TWO_LINK = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "active"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 9.81}
TWO_LINK_TASK = {"duration": 1.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
                 "final": {"q": [0.6, 1.2], "dq": [0.0, 0.0]}}


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.process_time()
        fn()
        times.append(time.process_time() - start)
    return statistics.median(times)


def residual_forms() -> list[str]:
    robot = Robot.model_validate(SEED)
    s = Structure.of(robot)
    sym = derive(s)
    ddq, tau = ca.SX.sym("ddq", s.n), ca.SX.sym("tau", len(s.active_idx))
    lam = ca.SX.sym("lam", s.n)
    B = ca.DM(selection(s))
    forms = {
        "M ddq + h - B tau": ca.mtimes(sym.mass, ddq) + sym.bias - ca.mtimes(B, tau),
        "d/dt(dT/ddq) - dT/dq + dV/dq - B tau (planner)":
            functions(s)["residual"](sym.q, sym.dq, ddq, tau, sym.p),
    }
    x = ca.vertcat(sym.q, sym.dq, ddq, tau)
    rng = np.random.default_rng(0)
    K = 300  # knots of the seed task at N = 100, Legendre degree 3
    args = [rng.normal(size=(x.numel(), K)), rng.normal(size=(s.n, K)), parameters(robot, s)]
    rows = ["| residual form | nodes | Hessian nodes | Hessian of 300 knots [ms CPU] |",
            "|---|---|---|---|"]
    for name, expr in forms.items():
        f = ca.Function("r", [x, sym.p], [expr])
        H = ca.Function("H", [x, lam, sym.p], [ca.hessian(ca.dot(lam, expr), x)[0]])
        mapped = H.map(K)
        t = median_time(lambda: mapped(*args), 21)
        rows.append(f"| {name} | {f.n_nodes()} | {H.n_nodes()} | {1e3 * t:.2f} |")
    return rows


def compiled_against_interpreted() -> list[str]:
    rows = ["| scene | N | build and compile [s] | library [MB] | iterations | median solve, interpreted [s] "
            "| median solve, compiled [s] | ratio |", "|---|---|---|---|---|---|---|---|"]
    cases = [("2-link, fully actuated", TWO_LINK, TWO_LINK_TASK, 100),
             ("seed 4-link, margin 0.02", SEED, SEED_TASK, 50)]
    with tempfile.TemporaryDirectory() as cache:
        os.environ["UNDERTOW_CACHE_DIR"] = cache
        for label, robot, task, N in cases:
            solves = {}
            for jit in (False, True):
                scene = Scene.model_validate({
                    "robot": robot, "task": task,
                    "transcription": {"method": "legendre", "intervals": N, "degree": 3},
                    "solver": {"jit": jit, "max_wall_time": 600}})
                start = time.perf_counter()
                first = plan(scene)
                build = time.perf_counter() - start - first.solver.solve_time
                times = [plan(scene).solver.solve_time for _ in range(3)]
                solves[jit] = (build, statistics.median(times), first.solver.iterations)
            library = next(Path(cache).glob("nlp_*.so"))
            size = library.stat().st_size / 1e6
            ratio = solves[False][1] / solves[True][1]
            rows.append(f"| {label} | {N} | {solves[True][0]:.1f} | {size:.1f} | {solves[True][2]} "
                        f"| {solves[False][1]:.3f} | {solves[True][1]:.3f} | {ratio:.1f} |")
            library.unlink()
    return rows


def seed_accuracy() -> list[str]:
    rows = ["| N | status | iterations | objective | re-simulation error [rad] | defect [N m s] "
            "| waveless crossings | min sigma_min |", "|---|---|---|---|---|---|---|---|"]
    for N in (50, 100):
        scene = Scene.model_validate({
            "robot": SEED, "task": SEED_TASK,
            "transcription": {"method": "legendre", "intervals": N, "degree": 3},
            "solver": {"jit": True, "max_wall_time": 600}})
        result = plan(scene)
        v = result.verification
        rows.append(f"| {N} | {result.solver.status} | {result.solver.iterations} "
                    f"| {result.objective:.4f} | {v.resimulation_error:.2e} | {v.defect:.2e} "
                    f"| {len(v.waveless_singular_crossings)} | {v.min_sigma:.4f} |")
    return rows


def main() -> None:
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    sections = [
        "# Planner internals (measured)",
        "",
        "Produced by `.venv/bin/python bench/planner_internals.py` on a shared 2-core machine "
        f"(`uptime` at the start: {load}). CPU times are medians; solve times are medians of 3.",
        "",
        "## The residual form",
        "",
        *residual_forms(),
        "",
        "## Compiled (solver.jit) against interpreted NLPs, Legendre degree 3",
        "",
        *compiled_against_interpreted(),
        "",
        "## The seed arm through waveless singularities, Legendre degree 3",
        "",
        *seed_accuracy(),
        "",
    ]
    out = ROOT / "docs" / "bench-planner-internals.md"
    out.write_text("\n".join(sections))
    print("\n".join(sections))


if __name__ == "__main__":
    main()
