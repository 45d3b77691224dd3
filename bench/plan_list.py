"""Listing plan jobs: what a page of 100 jobs with large plans costs, decoding the plans or not.

A SQLite job store in a temporary folder holds `--jobs` finished jobs, each with the plan of
the built-in example `seed-arm-plan` (planned once). A page of 100 is listed `--repeats`
times the way `GET /v1/plans` listed it before (every job's scene, plan and history read
and decoded, `store.list()`) and the way it lists it now (`store.list(summaries=True)`:
neither read nor decoded), then made into the page's `JobSummary` items either way.
Reported: median wall and CPU time of a listing and its peak Python allocation
(tracemalloc), in one run.

    python -m bench plan_list [--jobs 100] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

from app.schemas import JobSummary
from app.store import SqliteJobStore
from bench import harness
from planner.examples import example
from planner.ocp import plan
from planner.scene import Scene

DOC = harness.DOCS / "bench-service.md"
SECTION = "Listing plan jobs: GET /v1/plans with large plans"


def _fill(store: SqliteJobStore, jobs: int) -> int:
    """`jobs` finished jobs with the example's plan; the plan's JSON size [bytes]."""
    request = example("seed-arm-plan").request
    result = plan(Scene.model_validate(request)).model_dump(mode="json")
    for k in range(jobs):
        store.create(f"job{k:04d}", request, "bench")
        claimed = store.claim("bench", "bench-worker", time.time() + 60)
        assert claimed is not None
        store.finish(claimed.id, "succeeded", result, None)
    return len(Scene.model_validate(request).model_dump_json()) + len(str(result))


def _listed(store: SqliteJobStore, summaries: bool) -> dict:
    """One page of 100 as the route makes it: wall, CPU [s] and peak allocation [MB]."""
    tracemalloc.start()
    wall, cpu = time.perf_counter(), time.process_time()
    items = [JobSummary.of(r) for r in store.list(limit=100, summaries=summaries)]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    assert len(items) == 100
    return {"wall": wall, "cpu": cpu, "peak_mb": peak}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench plan_list", description=__doc__)
    parser.add_argument("--jobs", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    with tempfile.TemporaryDirectory() as folder:
        store = SqliteJobStore(Path(folder) / "jobs.sqlite3")
        size = _fill(store, args.jobs)
        rows = []
        for how, summaries in (("every job decoded (before)", False),
                               ("summaries only (now)", True)):
            runs = [_listed(store, summaries) for _ in range(args.repeats)]
            rows.append({"listing": how, **{k: statistics.median(r[k] for r in runs)
                                            for k in ("wall", "cpu", "peak_mb")}})
            print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "plan_list.csv", rows)
    text = "\n\n".join([
        f"A SQLite store with {args.jobs} finished jobs, each holding the plan of "
        f"`seed-arm-plan` (about {size / 1e3:.0f} kB of JSON with its scene); one page of "
        f"100 made into `JobSummary` items, median of {args.repeats} listings in one run "
        "(timed with tracemalloc running, which slows the allocating listing most).",
        harness.table(rows, [("listing", "listing"), ("wall", "wall [s]"), ("cpu", "CPU [s]"),
                             ("peak_mb", "peak allocation [MB]")]),
        f"Rows: `bench/results/plan_list.csv`. "
        f"{harness.manifest('plan_list', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
