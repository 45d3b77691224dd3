"""The built-in plan examples with their goals moved a little: how many plans verify, how fast.

A generated set: each plan example of `planner.examples`, at every number of intervals
among its own, 40, 50 and 100, with every final angle moved by a uniform offset in
[-MOVE, MOVE] rad (NumPy generator seeded 1 to `--variants`). A moved goal that puts the
goal itself inside the task's coupling margin (sigma_min(M_pa) below it, known before any
solve) is reported as such and left out of the figures. Each variant is planned once with
the planner's defaults, in this process (the NLP of a structure is built by its first plan).
Reported per plan: verified, wall and CPU time (this process and its companion processes),
iterations, the strategy that produced the plan; per example: verified share, median time
to a verified plan (unverified counted as never), maximum.

    python -m bench moved_goals [--variants 5] [--examples NAME,...]
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import time

import numpy as np

from bench import harness
from planner.coupling_block import at
from planner.examples import examples
from planner.ocp import plan
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Built-in plan examples with their goals moved"
MOVE = 0.05  # [rad] largest offset of a final angle
INTERVALS = (40, 50, 100)  # besides each example's own



def variants(count: int, names: list[str] | None = None) -> list[tuple[str, int, int, dict]]:
    """(example, intervals, variant, request) of the generated set (of the examples
    `names`, default every plan example)."""
    out = []
    for example in (e for e in examples() if e.kind == "plan"
                    and (names is None or e.name in names)):
        own = example.request["transcription"]["intervals"]
        for intervals in sorted({own, *INTERVALS}):
            for variant in range(1, count + 1):
                rng = np.random.default_rng(variant)
                request = copy.deepcopy(example.request)
                final = request["task"]["final"]["q"]
                request["task"]["final"]["q"] = (
                    np.asarray(final) + rng.uniform(-MOVE, MOVE, len(final))).round(6).tolist()
                request["transcription"]["intervals"] = intervals
                out.append((example.name, intervals, variant, request))
    return out


def _inside_margin(scene: Scene) -> bool:
    """Whether the goal itself has sigma_min(M_pa) below the task's coupling margin."""
    margin = scene.task.coupling_margin
    goal = scene.task.final.q
    if margin is None or any(v is None for v in goal):
        return False
    sigma = at(scene.robot, [float(v) for v in goal if v is not None]).sigma_min
    return sigma is not None and sigma < margin


def run(count: int, names: list[str] | None = None) -> list[dict]:
    rows = []
    for name, intervals, variant, request in variants(count, names):
        scene = Scene.model_validate(request)
        row = {"example": name, "intervals": intervals, "variant": variant}
        if _inside_margin(scene):
            rows.append({**row, "feasible": False})
            print(rows[-1], flush=True)
            continue
        cpu, started = harness.cpu_time(), time.perf_counter()
        result = plan(scene)
        elapsed, cpu = time.perf_counter() - started, harness.cpu_time() - cpu
        ok = bool(result.solver.success and result.verification.verified)
        rows.append({**row, "feasible": True, "verified": ok, "time": elapsed, "cpu": cpu,
                     "iterations": result.solver.iterations, "objective": result.objective,
                     "strategy": result.solver.strategy})
        print(rows[-1], flush=True)
    return rows


def _summary(rows: list[dict], name: str) -> dict:
    feasible = [r for r in rows if r["feasible"]]
    times = [r["time"] if r["verified"] else math.inf for r in feasible]
    median = statistics.median(times) if times else math.nan
    return {"example": name, "plans": len(rows), "feasible": len(feasible),
            "verified": sum(r["verified"] for r in feasible),
            "median_all": median if math.isfinite(median) else "never",
            "max_all": max(times) if times and math.isfinite(max(times)) else "never",
            "median_cpu": harness.median(r["cpu"] for r in feasible),
            "median_iterations": harness.median(r["iterations"] for r in feasible)}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench moved_goals", description=__doc__)
    parser.add_argument("--variants", type=int, default=5)
    parser.add_argument("--examples", default=None,
                        help="comma-separated names (default: every plan example)")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.variants, args.examples.split(",") if args.examples else None)
    harness.write_csv(harness.RESULTS / "moved_goals.csv", rows)
    names = sorted({r["example"] for r in rows})
    summary = [_summary([r for r in rows if r["example"] == n], n) for n in names]
    summary.append(_summary(rows, "all"))
    text = "\n\n".join([
        f"Each plan example at every number of intervals among its own, 40, 50 and 100, with "
        f"every final angle moved by up to {MOVE} rad ({args.variants} variants each, "
        "generator seeds 1 to {0}); default settings, one plan each in one process, so the "
        "first plan of a structure builds its NLP. A goal moved inside the task's coupling "
        "margin is infeasible before any solve and left out. Time: wall time to a verified "
        "plan, unverified counted as never; CPU: this process and its companion "
        "processes.".format(args.variants),
        harness.table(summary, [("example", "example"), ("plans", "plans"),
                                ("feasible", "feasible"), ("verified", "verified"),
                                ("median_all", "median time to a verified plan [s]"),
                                ("max_all", "maximum [s]"), ("median_cpu", "median CPU [s]"),
                                ("median_iterations", "median iterations")]),
        harness.table([r for r in rows if r["feasible"]],
                      [("example", "example"), ("intervals", "N"), ("variant", "variant"),
                       ("verified", "verified"), ("time", "wall [s]"), ("cpu", "CPU [s]"),
                       ("iterations", "iterations"), ("objective", "objective"),
                       ("strategy", "strategy")]),
        f"Rows: `bench/results/moved_goals.csv`. "
        f"{harness.manifest('moved_goals', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    for row in summary:
        print(row)
    return 0
