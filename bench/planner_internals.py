"""Measures behind the planner's design choices, each a section of
docs/bench-planner-internals.md (`--parts` picks them):

- residual: the dynamics residual formed as d/dt(dT/ddq) by one directional derivative
  against M ddq + h: expression nodes and the CPU cost of the Hessian of lambda' r over
  the 300 knots of the seed task at N = 100;
- compiled: interpreted against compiled (solver.jit: the stages' derivative kernels in
  C) NLPs on the same scenes, one solve per plan: build and compile time, library size,
  median solve time of `--repeats` solves, Ipopt iterations;
- seed: the seed arm's rest-to-rest task through waveless singularities (bench/scenes.py
  "seed-4"), one compiled solve per N, Legendre degree 3: interval error, open-loop
  replay error, defect, crossings.

    python -m bench planner_internals [--parts residual,compiled,seed] [--repeats 3]
        [--seed-N 50,100]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import casadi as ca
import numpy as np

from bench import harness
from bench.scenes import ROBOTS, make_scene
from planner import compiled
from planner.dynamics import derive, functions, selection
from planner.model import Robot, Structure, parameters
from planner.ocp import plan
from planner.ocp.problem import Problem, ProblemKey, problem
from planner.scene import Scene

DOC = harness.DOCS / "bench-planner-internals.md"
SECTIONS = {"residual": "The residual form",
            "compiled": "Compiled (solver.jit) against interpreted NLPs, Legendre degree 3",
            "seed": "The seed arm through waveless singularities, Legendre degree 3"}
KNOTS = 300  # knots of the seed task at N = 100, Legendre degree 3
CASES = [("2-link, fully actuated", "arm-2", 100), ("seed 4-link, margin 0.02", "seed-4", 50)]


def median_cpu(fn: Callable[[], object], repeats: int) -> float:
    """Median CPU time [s] of fn() over `repeats` calls."""
    return harness.median(harness.timed(fn)[2] for _ in range(repeats))


def residual_forms() -> tuple[str, list[dict]]:
    robot = Robot.model_validate(ROBOTS["seed-4"])
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
    args = [rng.normal(size=(x.numel(), KNOTS)), rng.normal(size=(s.n, KNOTS)),
            parameters(robot, s)]
    rows = []
    for name, expr in forms.items():
        f = ca.Function("r", [x, sym.p], [expr])
        H = ca.Function("H", [x, lam, sym.p], [ca.hessian(ca.dot(lam, expr), x)[0]])
        mapped = H.map(KNOTS)
        cpu = median_cpu(partial(mapped, *args), 21)
        rows.append({"form": name, "nodes": f.n_nodes(), "hessian_nodes": H.n_nodes(),
                     "cpu_ms": 1e3 * cpu})
    text = harness.table(rows, [("form", "residual form"), ("nodes", "nodes"),
                                ("hessian_nodes", "Hessian nodes"),
                                ("cpu_ms", f"Hessian of {KNOTS} knots [ms CPU, median of 21]")])
    return text, rows


def compiled_against_interpreted(repeats: int) -> tuple[str, list[dict]]:
    rows = []
    previous = os.environ.get("UNDERTOW_CACHE_DIR")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["UNDERTOW_CACHE_DIR"] = cache  # a cold cache of compiled stages
        for label, name, N in CASES:
            solves = {}
            for jit in (False, True):
                scene = make_scene(name, N=N, one_solve=True,
                                   solver={"jit": jit, "max_wall_time": 600})
                def build_nlp(s: Scene = scene) -> Problem:
                    return problem(ProblemKey.of(s), wait=True)

                _, build, _ = harness.timed(build_nlp)
                first = plan(scene)
                compiled.wait()  # the verification's dynamics, built in the background
                times = [plan(scene).solver.solve_time for _ in range(repeats)]
                solves[jit] = (build, statistics.median(times), first.solver.iterations)
            library = next(Path(cache).glob("stages_*.so"))
            rows.append({"scene": label, "N": N, "build": solves[True][0],
                         "library": library.stat().st_size / 1e6, "iterations": solves[True][2],
                         "interpreted": solves[False][1], "compiled": solves[True][1],
                         "ratio": solves[False][1] / solves[True][1]})
            library.unlink()
    if previous is None:
        del os.environ["UNDERTOW_CACHE_DIR"]
    else:
        os.environ["UNDERTOW_CACHE_DIR"] = previous
    text = "\n\n".join([
        (f"One solve per plan (refinement and retries off); solve times are medians of "
         f"{repeats} solves with the NLP cached; the compiled build includes the C "
         "compilation of the stages' derivative kernels, and the stage library is their "
         "compiled code (the verification's compiled dynamics apart)."),
        harness.table(rows, [("scene", "scene"), ("N", "N"), ("build", "build and compile [s]"),
                             ("library", "stage library [MB]"), ("iterations", "iterations"),
                             ("interpreted", "median solve, interpreted [s]"),
                             ("compiled", "median solve, compiled [s]"), ("ratio", "ratio")])])
    return text, rows


def seed_accuracy(grid: list[int]) -> tuple[str, list[dict]]:
    rows = []
    for N in grid:
        result = plan(make_scene("seed-4", N=N, one_solve=True,
                                 solver={"jit": True, "max_wall_time": 600}))
        v = result.verification
        rows.append({"N": N, "status": result.solver.status,
                     "iterations": result.solver.iterations, "objective": result.objective,
                     "interval_error": v.local_error, "replay_error": v.resimulation_error,
                     "defect": v.defect, "crossings": len(v.waveless_singular_crossings),
                     "min_sigma": v.min_sigma})
    text = "\n\n".join([
        "One compiled solve per N (refinement and retries off), from the interpolation guess.",
        harness.table(rows, [("N", "N"), ("status", "status"), ("iterations", "iterations"),
                             ("objective", "objective"),
                             ("interval_error", "interval error [rad]"),
                             ("replay_error", "open-loop replay [rad]"),
                             ("defect", "defect [N m s]"), ("crossings", "waveless crossings"),
                             ("min_sigma", "min sigma_min")])])
    return text, rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench planner_internals",
                                     description=__doc__)
    parser.add_argument("--parts", default=",".join(SECTIONS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed-N", default="50,100")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    runs = {"residual": residual_forms,
            "compiled": lambda: compiled_against_interpreted(args.repeats),
            "seed": lambda: seed_accuracy([int(n) for n in args.seed_N.split(",")])}
    for part in args.parts.split(","):
        text, rows = runs[part]()
        harness.write_csv(harness.RESULTS / f"planner_internals_{part}.csv", rows)
        harness.write_section(DOC, SECTIONS[part], "\n\n".join([
            text, f"Rows: `bench/results/planner_internals_{part}.csv`. "
                  f"{harness.manifest('planner_internals', argv, started, note)}"]))
        print(text, flush=True)
    return 0
