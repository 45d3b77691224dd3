"""The hard suite's slowest tasks, now against an earlier commit, one process per version:
where the time of a long plan goes, solve by solve.

The tasks (TASKS) are those of `testbed.suites.hard` on its seed and its two held-out
seeds that took more than 2.5 s in the hard-suite runs committed at 3b2cc4e and adbb3f7,
each stated as `python -m bench suite --suite hard` states it for the default planner
(with `task.uncertainty`). Each version plans every task in turn in one fresh process of
its own checkout with UNDERTOW_SOLVER_PROCESSES=1 (no companion: the plan is the same
sequence of solves every run, so the versions' iterations compare one to one), the
earlier version first. Per plan: verified, wall and CPU time, iterations, and every solve
(intervals, iterations, status).

    python -m bench refined_tails --before COMMIT [--tasks NAME:SEED,...]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from bench import harness

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Refined solves on the hard suite's slowest tasks"
CSV = harness.RESULTS / "refined_tails.csv"
TASKS = ("co-design-20:20261125", "co-design-32:20261125", "bounds-31:20261125",
         "links-5to8-35:20261125", "co-design-08:20261125", "torque-limit-04:20261125",
         "bounds-07:20261125", "torque-limit-16:27182818", "torque-limit-04:27182818",
         "bounds-31:27182818", "bounds-07:27182818", "co-design-20:31415926",
         "co-design-44:31415926", "bounds-19:31415926", "co-design-32:31415926",
         "co-design-08:31415926", "torque-limit-28:31415926")
TIMEOUT = 1800.0  # [s] one version's whole run

_RUN = """
import json, os, sys, time
os.environ["UNDERTOW_SOLVER_PROCESSES"] = "1"
sys.path.insert(0, os.getcwd())
from bench.harness import cpu_time
from bench.suite import with_uncertainty
from planner.ocp import plan
from planner.scene import Scene
from testbed.suites import hard
rows = []
for item in json.loads(sys.argv[1]):
    name, seed = item.split(":")
    scene = hard.hard_task(hard.index_of(name), int(seed))[1]
    scene = Scene.model_validate(with_uncertainty(scene.model_dump(mode="json")))
    started, used = time.perf_counter(), cpu_time()
    result = plan(scene)
    s = result.solver
    rows.append({"task": name, "seed": int(seed),
                 "verified": bool(s.success and result.verification.verified),
                 "wall": time.perf_counter() - started, "cpu": cpu_time() - used,
                 "iterations": s.iterations,
                 "solves": [[p.intervals, p.iterations, p.status]
                            for p in result.mesh_passes]})
    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
print("RESULT " + json.dumps({"rows": rows}))
"""


def run(before: str, tasks: list[str]) -> list[dict]:
    """Every task planned by the earlier version, then by this one (see the module)."""
    rows = []
    with harness.checkout(before) as old:
        for version, root in (("before", old), ("now", harness.ROOT)):
            out = harness.run_at(root, _RUN, [json.dumps(tasks)], TIMEOUT)
            if "failure" in out:
                raise RuntimeError(f"{version}: {out['failure']}")
            for row in out["rows"]:
                solves = row.pop("solves")
                rows.append({**row, "version": version, "count": len(solves),
                             "solves": " ".join(f"{n}:{it}:{status}"
                                                for n, it, status in solves)})
    return rows


def _summary(rows: list[dict]) -> list[dict]:
    """Per version: plans, verified, total and median wall time, total CPU and iterations."""
    out = []
    for version in dict.fromkeys(r["version"] for r in rows):
        mine = [r for r in rows if r["version"] == version]
        out.append({"version": version, "plans": len(mine),
                    "verified": sum(r["verified"] for r in mine),
                    "wall": sum(r["wall"] for r in mine),
                    "median": statistics.median(r["wall"] for r in mine),
                    "cpu": sum(r["cpu"] for r in mine),
                    "iterations": sum(r["iterations"] for r in mine)})
    return out


def _paired(rows: list[dict]) -> list[dict]:
    """Per task: each version's wall time, iterations and verdict side by side."""
    by = {(r["task"], r["seed"], r["version"]): r for r in rows}
    out = []
    for task, seed in dict.fromkeys((r["task"], r["seed"]) for r in rows):
        row: dict = {"task": task, "seed": seed}
        for version in ("before", "now"):
            r = by.get((task, seed, version))
            if r is not None:
                row.update({f"{version}_wall": r["wall"], f"{version}_iterations":
                            r["iterations"], f"{version}_verified": r["verified"],
                            f"{version}_solves": r["count"]})
        out.append(row)
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench refined_tails", description=__doc__)
    parser.add_argument("--before", required=True, help="the earlier commit")
    parser.add_argument("--tasks", default=",".join(TASKS),
                        help="comma-separated NAME:SEED of the hard suite")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.before, args.tasks.split(","))
    harness.write_csv(CSV, rows)
    text = "\n\n".join([
        f"{len(rows) // 2} tasks of the hard suite (`bench/refined_tails.py` says which), each "
        "planned in one process per version with no companion: the earlier version "
        f"({args.before}) first, then this one (the manifest's commit).",
        harness.table(_summary(rows), [("version", "version"), ("plans", "plans"),
                                       ("verified", "verified"), ("wall", "all plans [s]"),
                                       ("median", "median plan [s]"), ("cpu", "CPU [s]"),
                                       ("iterations", "iterations")]),
        harness.table(_paired(rows), [
            ("task", "task"), ("seed", "seed"), ("before_wall", "before [s]"),
            ("before_iterations", "iterations"), ("before_verified", "verified"),
            ("now_wall", "now [s]"), ("now_iterations", "iterations"),
            ("now_verified", "verified"), ("now_solves", "solves")]),
        "Rows, with every solve (intervals:iterations:status): "
        "`bench/results/refined_tails.csv`. " + harness.manifest("refined_tails", argv,
                                                                 started, note)])
    harness.write_section(DOC, SECTION, text)
    return 0
