"""What one iteration costs on the seed's 4-link arm, and where the time goes.

Scene "seed-4" (bench/scenes.py: the seed arm in a horizontal plane across waveless coupling
singularities, Legendre degree 3), one solve per plan of exactly `--iterations` iterations
from the planner's initial guess (refinement and retries off; the NLP built and cached
first, so no build is timed). Solvers: Ipopt with the stages' derivative kernels
interpreted, Ipopt with them compiled to C (`solver.jit`, the default; the library built
before timing), the same with MUMPS's workspace at its estimate plus Ipopt's own 1000 %
(`mumps_mem_percent`; the planner's setting before it was 200 %), and fatrop with the
stage structure declared (`solver.name: "fatrop"`; it differentiates the expanded NLP
itself). Reported per N and solver, medians of `--repeats` solves: CPU time per iteration,
the part in NLP function evaluations (CasADi's `t_proc_nlp_*` and the iteration callback)
and the solver's own part (the rest: the KKT factorizations, solves and vector work), the
CPU time the kernel spent for the process and the page faults it took, function calls per
iteration and, for Ipopt, KKT factorizations per iteration (counted in its log of one
more, untimed solve).

    python -m bench iteration_cost [--N 50 100] [--iterations 60] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import time

from bench import harness, suite
from bench.scenes import make_scene
from planner import compiled
from planner.ocp import plan
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Cost of an iteration on the seed arm"
SOLVERS: tuple[tuple[str, dict[str, object], dict[str, object]], ...] = (
    ("Ipopt, interpreted", {"jit": False}, {}),
    ("Ipopt, compiled (jit, the default)", {"jit": True}, {}),
    ("Ipopt, compiled, MUMPS workspace 1000 %", {"jit": True}, {"mumps_mem_percent": 1000}),
    ("fatrop", {"name": "fatrop", "jit": False}, {}))
"""Name, solver settings of the scene, Ipopt options beyond the planner's."""


def _scene(N: int, iterations: int, solver: dict) -> Scene:
    """The seed-4 scene on N intervals, one solve of exactly `iterations` iterations."""
    return make_scene("seed-4", N=N, one_solve=True,
                      solver={**solver, "max_iter": iterations, "tol": 1e-12})


def _measure(N: int, iterations: int, solver: dict) -> dict:
    """One solve of `iterations` iterations: CPU per iteration [ms], its split, calls."""
    scene = _scene(N, iterations, solver)
    _, timed = harness.build_instrumented(scene)
    plan(scene)
    stats = timed.stats()
    done = max(int(stats.get("iter_count", iterations)), 1)
    functions = sum(v for k, v in stats.items()
                    if k.startswith("t_proc_nlp") or k == "t_proc_callback_fun")
    calls = sum(v for k, v in stats.items() if k.startswith("n_call_nlp"))
    return {"iterations": done, "cpu_per_iteration": 1e3 * timed.cpu / done,
            "functions_per_iteration": 1e3 * functions / done,
            "solver_per_iteration": 1e3 * (timed.cpu - functions) / done,
            "kernel_per_iteration": 1e3 * timed.kernel / done,
            "faults_per_iteration": timed.faults / done,
            "calls_per_iteration": calls / done}


def _factorizations(N: int, iterations: int, solver: dict) -> float:
    """KKT factorizations per iteration of the same solve, counted in Ipopt's log at
    `bench.suite.LOG_LEVEL` (a solve of its own, not timed); NaN for a solver without
    that log (fatrop)."""
    if solver.get("name", "ipopt") != "ipopt":
        return math.nan
    with harness.ipopt_options({"print_level": suite.LOG_LEVEL}), suite.solver_log() as log:
        plan(_scene(N, iterations, solver))
    return suite.per_iteration([suite.log_counts(log(), iterations)])


def run(Ns: list[int], iterations: int, repeats: int) -> list[dict]:
    rows = []
    for N in Ns:
        for name, solver, options in SOLVERS:
            with harness.ipopt_options(options):
                _measure(N, iterations, solver)  # builds (and compiles) the NLP
                if solver.get("jit"):
                    compiled.wait()
                runs = [_measure(N, iterations, solver) for _ in range(repeats)]
                factorizations = _factorizations(N, iterations, solver)
            row = {"N": N, "solver": name, "iterations": runs[0]["iterations"],
                   **{k: harness.median(r[k] for r in runs)
                      for k in ("cpu_per_iteration", "functions_per_iteration",
                                "solver_per_iteration", "kernel_per_iteration",
                                "faults_per_iteration", "calls_per_iteration")},
                   "factorizations_per_iteration": factorizations}
            rows.append(row)
            print(row, flush=True)
    return rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench iteration_cost", description=__doc__)
    parser.add_argument("--N", type=int, nargs="+", default=[50, 100])
    parser.add_argument("--iterations", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.N, args.iterations, args.repeats)
    harness.write_csv(harness.RESULTS / "iteration_cost.csv", rows)
    text = "\n\n".join([
        f"The seed arm in a horizontal plane (\"seed-4\", Legendre 3), one solve of "
        f"{args.iterations} iterations from the planner's initial guess, the NLP built first; "
        f"medians of {args.repeats} solves, CPU time of this process. Functions: CasADi's "
        "NLP function evaluations and the iteration callback; solver: the rest (KKT "
        "factorizations and solves, vector work); of it in the kernel: the CPU time the "
        "kernel spent for the process during the solve, most of it faulting in the pages "
        "of memory the C heap mapped afresh.",
        harness.table(rows, [("N", "N"), ("solver", "solver"), ("iterations", "iterations"),
                             ("cpu_per_iteration", "CPU per iteration [ms]"),
                             ("functions_per_iteration", "functions [ms]"),
                             ("solver_per_iteration", "solver [ms]"),
                             ("kernel_per_iteration", "of it in the kernel [ms]"),
                             ("faults_per_iteration", "page faults per iteration"),
                             ("calls_per_iteration", "function calls per iteration"),
                             ("factorizations_per_iteration",
                              "KKT factorizations per iteration")]),
        f"Rows: `bench/results/iteration_cost.csv`. "
        f"{harness.manifest('iteration_cost', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
