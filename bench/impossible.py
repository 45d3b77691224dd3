"""Impossible tasks: how many end `infeasible` with evidence, how soon, and within what
share of the budget.

The generated impossible suite (`testbed.suites.impossible`: durations and duration ranges
below the shortest one, unreachable tips, zero torque, contradictory bounds) on its own
seed and its held-out ones, default settings (a 60 s budget), one plan each as a service
worker runs it (both cores: a companion process where the planner forks one). Reported
per task: the outcome, whether it says `infeasible` (`plan.infeasibility` set, and by what:
the checks before a solve, agreeing starts, the duration probe), the evidence (the
shortest duration found, or the first violated field), wall and CPU time, and the wall time
as a share of the budget; per category and seed the share said infeasible within a quarter
of the budget; and the latest any plan returned past its budget.

    python -m bench impossible [--seeds 20261126,16180339,14142135] [--count 40]
"""

from __future__ import annotations

import argparse
import time

from bench import harness
from planner.ocp import plan
from planner.ocp.result import Plan
from testbed.suites import impossible as impossible_suite
from testbed.suites.hard import category

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Impossible tasks: said infeasible, and how soon"
BUDGET = 60.0  # [s] the default solver.max_wall_time


def _evidence(result: Plan, duration: float) -> str:
    found = result.infeasibility
    if found is None:
        return ""
    if found.shortest_duration is not None:
        return f"shortest {found.shortest_duration:.4g} s against {duration:.4g} s"
    if found.fields:
        return f"{found.fields[0].field}: {found.fields[0].kind}"
    return ", ".join(v.kind for v in found.violations[:2])


def _row(seed: int, name: str, result: Plan, wall: float, cpu: float) -> dict:
    """A task's row: said infeasible only by the plan's own status (agreeing starts that
    end locally infeasible are a solver failure, no verdict)."""
    found = result.infeasibility
    said = result.status == "infeasible" and found is not None
    longest = max(found.durations) if found is not None and found.durations else 0.0
    return {"seed": seed, "task": name, "category": category(name),
            "status": result.solver.status, "plan_status": result.status,
            "infeasible": found.source if said and found is not None else "no",
            "evidence": _evidence(result, longest), "time": wall, "cpu": cpu,
            "budget_share": wall / BUDGET, "past_budget": wall - BUDGET,
            "within_quarter": "yes" if said and wall <= BUDGET / 4 else "no"}


def _summary(rows: list[dict], key: str) -> list[dict]:
    out = []
    for value in dict.fromkeys(r[key] for r in rows):
        group = [r for r in rows if r[key] == value]
        quick = sum(r["within_quarter"] == "yes" for r in group)
        out.append({key: value, "tasks": len(group),
                    "infeasible": sum(r["infeasible"] != "no" for r in group),
                    "quarter": quick, "share": f"{100 * quick / len(group):.0f} %",
                    "median": harness.median(r["time"] for r in group),
                    "max": max(r["time"] for r in group)})
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench impossible")
    parser.add_argument("--seeds", default=",".join(
        str(s) for s in (impossible_suite.SEED, *impossible_suite.HELD_OUT)))
    parser.add_argument("--count", type=int, default=impossible_suite.COUNT)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for name, scene in impossible_suite.impossible_tasks(args.count, seed):
            cpu, wall = harness.cpu_time(), time.perf_counter()
            result = plan(scene)
            wall, cpu = time.perf_counter() - wall, harness.cpu_time() - cpu
            rows.append(_row(seed, name, result, wall, cpu))
            print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "impossible.csv", rows)
    quick = sum(r["within_quarter"] == "yes" for r in rows)
    latest = max(r["past_budget"] for r in rows)
    summary_columns = [("tasks", "tasks"), ("infeasible", "said infeasible"),
                       ("quarter", "within a quarter of the budget"), ("share", "share"),
                       ("median", "median wall [s]"), ("max", "max wall [s]")]
    text = "\n\n".join([
        f"The generated impossible suite (`testbed.suites.impossible`, {args.count} tasks a "
        f"seed; seeds {', '.join(args.seeds.split(','))}), default settings and a "
        f"{BUDGET:g} s budget, one plan "
        f"each in one process that may fork its companion. {quick} of {len(rows)} "
        f"({100 * quick / len(rows):.0f} %) end `infeasible` with evidence within a quarter "
        f"of the budget; " + (f"the latest plan returned {latest:.3g} s past its budget. "
                              if latest > 0 else "every plan returned within its budget. ")
        + "`infeasible` says by what: `checks` before any solve, `duration` (the duration "
        "probe's verified plan is longer than the task allows); starts that agree the task "
        "locally infeasible make a solver failure, not a verdict (`plan_status` in the "
        "rows).",
        harness.table(_summary(rows, "category"), [("category", "category"),
                                                   *summary_columns]),
        harness.table(_summary(rows, "seed"), [("seed", "seed"), *summary_columns]),
        harness.table(rows, [("seed", "seed"), ("task", "task"), ("status", "last solve"),
                             ("plan_status", "plan"),
                             ("infeasible", "said infeasible"), ("evidence", "evidence"),
                             ("time", "wall [s]"), ("cpu", "CPU [s]"),
                             ("budget_share", "share of the budget")]),
        f"Rows: `bench/results/impossible.csv`. "
        f"{harness.manifest('impossible', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
