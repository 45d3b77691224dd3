"""Mesh refinement on the built-in `two-link-plan` at other numbers of intervals, and what
each retry strategy recovers on the task suite's failures.

1. The example with only `transcription.intervals` changed, planned with refinement and
   retries off (one solve) and with the defaults: status, whether it verifies, the
   objective, its solves and the final number of intervals.
2. The suite's tasks over several seeds, planned with retries off; every task that does
   not verify is planned again with each retry strategy alone (the restart from the last
   iterate where the first solve did not converge, the inverse-dynamics start where it
   applies, a first mesh of twice and of half the intervals) and with the default retries.

    python -m bench refinement [--parts intervals,retries] [--seeds 20261123,1,2,3,4,5]
        [--intervals 20,30,...] [--count 48] [--max-iter N]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from bench import harness
from planner.examples import example
from planner.ocp import plan
from planner.scene import Scene
from testbed.suites.ordinary import tasks

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Mesh refinement on the two-link example"
RETRIES_SECTION = "Retries on the suite's failures"
SEEDS = "20261123,1,2,3,4,5"
INTERVALS = "20,30,40,50,60,80,100,120"
OWN_STARTS = ("direct", "coarse to fine")
"""The names of a scene's own first start, one of which every plan tries first."""


def _with(scene: Scene, **changes: dict) -> Scene:
    data = scene.model_dump(mode="json")
    for part, values in changes.items():
        data[part] = {**data[part], **values}
    return Scene.model_validate(data)


def _one(result) -> dict:
    v = result.verification
    return {"status": result.solver.status, "verified": bool(result.solver.success and v.verified),
            "objective": result.objective, "solves": len(result.mesh_passes),
            "final": len(result.t) - 1, "iterations": result.solver.iterations,
            "local_error": v.local_error, "strategy": result.solver.strategy}


def intervals_table(intervals: list[int]) -> list[dict]:
    """The two-link example at each number of intervals, one solve and the defaults."""
    base = Scene.model_validate(example("two-link-plan").request)
    rows = []
    for N in intervals:
        sc = _with(base, transcription={"intervals": N})
        single = _with(sc, transcription={"intervals": N, "refinement": {"enabled": False}},
                       solver={"retries": 0})
        row: dict[str, Any] = {"intervals": N}
        for name, scene in (("single", single), ("default", sc)):
            started = time.perf_counter()
            row.update({f"{name}_{k}": v for k, v in _one(plan(scene)).items()})
            row[f"{name}_time"] = time.perf_counter() - started
        rows.append(row)
        print(row, flush=True)
    return rows


def _retries(N: int) -> dict[str, str]:
    """The name of each retry's start for a scene of N intervals."""
    return {"restart": "restart from the last iterate",
            "inverse dynamics": "inverse-dynamics start",
            "twice the intervals": f"first mesh of {2 * N} intervals",
            "half the intervals": f"first mesh of {max(N // 2, 1)} intervals"}


def _alone(scene: Scene, name: str) -> dict | None:
    """The task planned with its own first start and then only the retry starting as
    `name` (`plan`'s `starts`); None when that retry does not apply to it (no solve of
    the plan belongs to it)."""
    result = plan(_with(scene, solver={"retries": 4}), starts={*OWN_STARTS, name})
    return _one(result) if any(p.strategy == name for p in result.mesh_passes) else None


def retries_table(seeds: list[int], count: int | None, max_iter: int | None) -> list[dict]:
    """Every one of the first `count` suite tasks (default all) of each seed that
    retries-off leaves unverified, with each retry alone; `max_iter`: every solve's
    iteration limit instead of the task's own."""
    rows = []
    for seed in seeds:
        for name, scene in tasks(seed=seed)[:count]:
            if max_iter is not None:
                scene = _with(scene, solver={"max_iter": max_iter})
            first = _one(plan(_with(scene, solver={"retries": 0})))
            if first["verified"]:
                continue
            row = {"seed": seed, "task": name, "without": first["status"]}
            for label, start in _retries(scene.transcription.intervals).items():
                out = _alone(scene, start)
                row[label] = "n/a" if out is None else "yes" if out["verified"] else "no"
            row["all retries"] = "yes" if _one(plan(scene))["verified"] else "no"
            rows.append(row)
            print(row, flush=True)
    return rows


def _intervals_section(values: list[int], argv: list[str], started: float, note: str) -> None:
    by_n = intervals_table(values)
    harness.write_csv(harness.RESULTS / "refinement_intervals.csv", by_n)
    text = "\n\n".join([
        "The built-in `two-link-plan` (passive shoulder, g = 0, coupling margin 0.01) with "
        "only `transcription.intervals` changed: one solve (refinement and retries off) "
        "against the defaults.",
        harness.table(by_n, [("intervals", "intervals"), ("single_status", "one solve"),
                             ("single_verified", "verified"),
                             ("single_objective", "objective"),
                             ("single_local_error", "interval error [rad]"),
                             ("default_verified", "defaults: verified"),
                             ("default_objective", "objective"),
                             ("default_solves", "solves"), ("default_final", "final intervals"),
                             ("default_strategy", "strategy"), ("default_time", "time [s]")]),
        "Rows: `bench/results/refinement_intervals.csv`. "
        f"{harness.manifest('refinement', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)


def _retries_section(seeds: list[int], count: int | None, max_iter: int | None,
                     argv: list[str], started: float, note: str) -> None:
    failures = retries_table(seeds, count, max_iter)
    if failures:
        harness.write_csv(harness.RESULTS / "refinement_retries.csv", failures)
    count = len(seeds) * len(tasks()[:count])
    recovered = {label: sum(r[label] == "yes" for r in failures)
                 for label in ("restart", "inverse dynamics", "twice the intervals",
                               "half the intervals", "all retries")}
    text = "\n\n".join(part for part in [
        f"The task suite over seeds {','.join(map(str, seeds))} ({count} tasks) with retries "
        f"off: {len(failures)} tasks do not verify. Each retry alone, after the same first "
        "attempt, recovers: " + ", ".join(f"{k} {v}" for k, v in recovered.items()
                                          if k != "all retries")
        + f"; the default retries in order recover {recovered['all retries']}.",
        harness.table(failures, [("seed", "seed"), ("task", "task"), ("without", "retries off"),
                                 ("restart", "restart"), ("inverse dynamics", "inverse dynamics"),
                                 ("twice the intervals", "twice the intervals"),
                                 ("half the intervals", "half the intervals"),
                                 ("all retries", "all retries")]) if failures else "",
        "Rows: `bench/results/refinement_retries.csv`. "
        f"{harness.manifest('refinement', argv, started, note)}"] if part)
    harness.write_section(DOC, RETRIES_SECTION, text)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench refinement", description=__doc__)
    parser.add_argument("--parts", default="intervals,retries",
                        help="comma-separated, from: intervals, retries")
    parser.add_argument("--seeds", default=SEEDS)
    parser.add_argument("--intervals", default=INTERVALS)
    parser.add_argument("--count", type=int, default=None,
                        help="the first this many suite tasks of each seed (default all)")
    parser.add_argument("--max-iter", type=int, default=None,
                        help="every retries solve's iteration limit (default: the task's)")
    args = parser.parse_args(argv)
    parts = args.parts.split(",")
    if "intervals" in parts:
        started, note = time.perf_counter(), harness.machine_note()
        _intervals_section([int(n) for n in args.intervals.split(",")], argv, started, note)
    if "retries" in parts:
        started, note = time.perf_counter(), harness.machine_note()
        _retries_section([int(s) for s in args.seeds.split(",")], args.count, args.max_iter,
                         argv, started, note)
    return 0
