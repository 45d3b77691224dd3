"""What one iteration costs on the seed's 4-link arm, and where the time goes, now and at an
earlier commit.

Scene "seed-4" (bench/scenes.py: the seed arm in a horizontal plane across waveless coupling
singularities, Legendre degree 3), one solve per plan of exactly `--iterations` iterations
from the planner's initial guess (refinement and retries off; the NLP built and cached
first, so no build is timed). Configurations, each in a fresh process: Ipopt with the
stages' kernels compiled to C (`solver.jit`, the default; the library built before timing)
and interpreted, fatrop with the stage structure declared (`solver.name: "fatrop"`) on the
same assembled derivative kernels, compiled and interpreted, and the default at the commit
`--before` (a checkout of its own). Reported per N and configuration, medians of `--repeats`
solves: the NLP's variables and rows, CPU time per iteration, the part in NLP function
evaluations (CasADi's `t_proc_nlp_*` and the iteration callback) and the solver's own part
(the rest: the KKT factorizations, solves and vector work), the kernel's CPU time for the
process and its page faults, function calls per iteration, for fatrop the part its own
statistics give its search directions (`compute_sd_time`: the stage-wise factorization and
solve of the KKT system) and, for Ipopt, KKT factorizations per iteration (counted in its
log of one more, untimed solve).

    python -m bench iteration_cost [--N 50 100] [--iterations 60] [--repeats 3] [--before C]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench import harness

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Cost of an iteration on the seed arm"
BEFORE = "95d4e3d"
"""The last commit before collocation was condensed and the NLP's rows and cost compiled."""
CONFIGS: tuple[tuple[str, dict[str, object], bool], ...] = (
    ("Ipopt, compiled (jit, the default)", {"jit": True}, False),
    ("Ipopt, interpreted", {"jit": False}, False),
    ("fatrop, compiled", {"name": "fatrop", "jit": True}, False),
    ("fatrop, interpreted", {"name": "fatrop", "jit": False}, False),
    ("before: Ipopt, compiled (jit, the default)", {"jit": True}, True))
"""Name, solver settings of the scene, whether at the commit `--before`."""
KEYS = ("cpu_per_iteration", "functions_per_iteration", "solver_per_iteration",
        "kernel_per_iteration", "faults_per_iteration", "calls_per_iteration",
        "kkt_per_iteration")

_RUN = """
import json, math, sys
sys.path.insert(0, {root!r})
from bench import harness, suite
from bench.scenes import make_scene
from planner import compiled
from planner.ocp import plan
N, iterations, repeats, solver = json.loads(sys.argv[1])
def scene():
    return make_scene("seed-4", N=N, one_solve=True,
                      solver={{**solver, "max_iter": iterations, "tol": 1e-12}})
plan(scene())  # builds the NLP, and starts the build of its compiled kernels
compiled.wait()
runs = []
for _ in range(repeats):
    s = scene()
    _, timed = harness.build_instrumented(s)
    plan(s)
    stats = timed.stats()
    done = max(int(stats.get("iter_count", iterations)), 1)
    functions = sum(v for k, v in stats.items()
                    if k.startswith("t_proc_nlp") or k == "t_proc_callback_fun")
    calls = sum(v for k, v in stats.items() if k.startswith("n_call_nlp"))
    runs.append({{"iterations": done, "cpu_per_iteration": 1e3 * timed.cpu / done,
                 "functions_per_iteration": 1e3 * functions / done,
                 "solver_per_iteration": 1e3 * (timed.cpu - functions) / done,
                 "kernel_per_iteration": 1e3 * timed.kernel / done,
                 "faults_per_iteration": timed.faults / done,
                 "calls_per_iteration": calls / done,
                 "kkt_per_iteration": 1e3 * stats.get("fatrop", {{}}).get(
                     "compute_sd_time", math.nan) / done}})
from planner.ocp.problem import ProblemKey, problem
built = problem(ProblemKey.of(scene()), wait=True)
factorizations = math.nan
if solver.get("name", "ipopt") == "ipopt":
    with harness.ipopt_options({{"print_level": suite.LOG_LEVEL}}), suite.solver_log() as log:
        plan(scene())
    factorizations = suite.per_iteration([suite.log_counts(log(), iterations)])
print("RESULT " + json.dumps({{"runs": runs, "variables": built.layout.size,
                              "rows": int(built.lbg.size),
                              "factorizations_per_iteration": factorizations}}))
"""


def _measure(root: Path, N: int, iterations: int, repeats: int, solver: dict) -> dict:
    """One configuration on N intervals, in a fresh process of the checkout `root`."""
    return harness.run_at(root, _RUN.format(root=str(root)),
                          [json.dumps([N, iterations, repeats, solver])], 1800)


def run(Ns: list[int], iterations: int, repeats: int, before: str) -> list[dict]:
    rows = []
    with harness.checkout(before) as old:
        for N in Ns:
            for name, solver, earlier in CONFIGS:
                out = _measure(old if earlier else harness.ROOT, N, iterations, repeats, solver)
                row: dict = {"N": N, "solver": name.replace("before", f"before ({before})")}
                if "failure" in out:
                    row["failure"] = out["failure"]
                else:
                    runs = out["runs"]
                    row.update({"iterations": runs[0]["iterations"],
                                "variables": out["variables"], "rows": out["rows"],
                                **{k: harness.median(r[k] for r in runs) for k in KEYS},
                                "factorizations_per_iteration":
                                    out["factorizations_per_iteration"]})
                rows.append(row)
                print(row, flush=True)
    return rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench iteration_cost", description=__doc__)
    parser.add_argument("--N", type=int, nargs="+", default=[50, 100])
    parser.add_argument("--iterations", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default=BEFORE)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.N, args.iterations, args.repeats, args.before)
    harness.write_csv(harness.RESULTS / "iteration_cost.csv", rows)
    text = "\n\n".join([
        f"The seed arm in a horizontal plane (\"seed-4\", Legendre 3), one solve of "
        f"{args.iterations} iterations from the planner's initial guess, the NLP built first; "
        f"medians of {args.repeats} solves, CPU time of the solving process, each "
        f"configuration in a process of its own, \"before\" at commit {args.before} (the NLP "
        "with the collocation states as variables, its rows and cost interpreted). "
        "Functions: CasADi's NLP function evaluations and the iteration callback; solver: "
        "the rest (KKT factorizations and solves, vector work); of it in the kernel: the CPU "
        "time the kernel spent for the process during the solve.",
        harness.table(rows, [("N", "N"), ("solver", "configuration"),
                             ("iterations", "iterations"), ("variables", "variables"),
                             ("rows", "rows"),
                             ("cpu_per_iteration", "CPU per iteration [ms]"),
                             ("functions_per_iteration", "functions [ms]"),
                             ("solver_per_iteration", "solver [ms]"),
                             ("kernel_per_iteration", "of it in the kernel [ms]"),
                             ("faults_per_iteration", "page faults per iteration"),
                             ("calls_per_iteration", "function calls per iteration"),
                             ("kkt_per_iteration", "of it in the KKT system (fatrop) [ms]"),
                             ("factorizations_per_iteration",
                              "KKT factorizations per iteration")]),
        f"Rows: `bench/results/iteration_cost.csv`. "
        f"{harness.manifest('iteration_cost', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
