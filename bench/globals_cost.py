"""What an iteration costs on tasks with global variables, now and at an earlier commit.

The hard suite's categories whose NLPs carry global variables (`--categories`: wave
co-design, four of them per seed, and a free duration), on the suite's seed and the two
held-out seeds: each task's first solve on 50 intervals from the planner's initial guess
(refinement and retries off, one solver process), after one plan of the first task has
had the compiled kernels built. This code and the commit `--before` (when the stages read
one shared copy of the globals, which bordered the KKT matrix with dense rows and
columns) each run in a fresh process of their own checkout. Reported per category and
version: solves, those Ipopt ended successful, iterations, and wall and CPU time per
iteration over all the category's solves (each version's medians of `--repeats` runs).

    python -m bench globals_cost [--categories co-design,free-time] [--repeats 3] [--before C]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench import harness

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Cost of an iteration with global variables"
BEFORE = "89de303"
"""The last commit whose stages shared one copy of the global variables."""
SEEDS = (20261125, 31415926, 27182818)
"""The hard suite's seed and its held-out seeds (`testbed.suites.hard`)."""

_RUN = """
import json, os, sys, time
os.environ["UNDERTOW_SOLVER_PROCESSES"] = "1"
sys.path.insert(0, {root!r})
from bench import harness, suite
from planner import compiled
from planner.ocp import plan
from planner.scene import Scene
category, seeds, count = json.loads(sys.argv[1])
def first_solve(scene):
    data = scene.model_dump(mode="json")
    data["transcription"]["refinement"]["enabled"] = False
    data["solver"].update(retries=0, max_iter=500)
    return Scene.model_validate(data)
tasks = [(seed, name, first_solve(scene)) for seed in seeds
         for name, scene in suite.suite_tasks("hard", count, seed, (category,))]
plan(tasks[0][2])
compiled.wait()
rows = []
for seed, name, scene in tasks:
    cpu, started = harness.cpu_time(), time.perf_counter()
    result = plan(scene)
    rows.append({{"seed": seed, "task": name, "status": result.solver.status,
                 "iterations": result.solver.iterations,
                 "time": time.perf_counter() - started, "cpu": harness.cpu_time() - cpu}})
print("RESULT " + json.dumps({{"rows": rows}}))
"""


def _measure(root: Path, category: str, count: int) -> dict:
    """One category's solves in a fresh process of the checkout `root`."""
    return harness.run_at(root, _RUN.format(root=str(root)),
                          [json.dumps([category, list(SEEDS), count])], 3600)


def _summary(category: str, version: str, runs: list[list[dict]]) -> dict:
    """A category's figures of one version: medians over the runs of each run's totals."""
    def total(rows: list[dict], key: str) -> float:
        return float(sum(r[key] for r in rows))

    first = runs[0]
    return {"category": category, "version": version, "solves": len(first),
            "successful": sum(r["status"] == "Solve_Succeeded" for r in first),
            "iterations": int(total(first, "iterations")),
            "time": harness.median(total(rows, "time") for rows in runs),
            "wall_per_iteration": harness.median(
                1e3 * total(rows, "time") / max(total(rows, "iterations"), 1) for rows in runs),
            "cpu_per_iteration": harness.median(
                1e3 * total(rows, "cpu") / max(total(rows, "iterations"), 1) for rows in runs)}


def run(categories: list[str], repeats: int, before: str, count: int) -> list[dict]:
    """Per category and version, its summary row (runs alternate between the versions)."""
    out = []
    with harness.checkout(before) as old:
        for category in categories:
            runs: dict[str, list[list[dict]]] = {"this": [], f"before ({before})": []}
            for _ in range(repeats):
                for version, root in zip(runs, (harness.ROOT, old), strict=True):
                    result = _measure(root, category, count)
                    if "failure" in result:
                        raise RuntimeError(f"{category} at {version}: {result['failure']}")
                    runs[version].append(result["rows"])
            for version, done in runs.items():
                out.append(_summary(category, version, done))
                print(out[-1], flush=True)
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench globals_cost", description=__doc__)
    parser.add_argument("--categories", default="co-design,free-time")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--count", type=int, default=48,
                        help="tasks drawn per seed (the hard suite's 48; fewer for a smoke run)")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.categories.split(","), args.repeats, args.before, args.count)
    harness.write_csv(harness.RESULTS / "globals_cost.csv", rows)
    text = "\n\n".join([
        "The hard suite's tasks with global variables (the co-designed waves' amplitudes "
        "and phases, a free duration) on its seed and the held-out seeds 31415926 and "
        "27182818: each task's first solve on 50 intervals from the planner's initial "
        "guess, refinement and retries off, one solver process, the kernels compiled "
        "first; \"this\" with a copy of the globals in every stage, kept equal by linear "
        f"rows, \"before\" at {args.before} with one copy that every stage read (docs/"
        "planner.md, \"Global variables\"). Per category and version: the solves, those "
        "Ipopt ended successful and their iterations (of the first run: the versions' "
        "iterates differ where a first step makes the copies equal), and medians over "
        f"{args.repeats} runs of the solves' wall time and their wall and CPU time per "
        "iteration (OpenBLAS with its own thread count).",
        harness.table(rows, [("category", "category"), ("version", "version"),
                             ("solves", "solves"), ("successful", "successful"),
                             ("iterations", "iterations"), ("time", "wall [s]"),
                             ("wall_per_iteration", "wall per iteration [ms]"),
                             ("cpu_per_iteration", "CPU per iteration [ms]")]),
        "Rows: `bench/results/globals_cost.csv`. "
        f"{harness.manifest('globals_cost', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
