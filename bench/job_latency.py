"""Plan jobs through the service, submit to answer: where the time goes beside the plan.

Live servers on 127.0.0.1 (`testbed.service.LiveServer`), one of this checkout and one of
each earlier commit (`--before`), each with one solver worker and a SQLite store of its
own, run side by side (an idle one costs nothing). Each plans the first `--count` tasks of
the default suite once (its worker builds their NLPs), then each task is submitted
`--repeats` times to each server in turn, one plan at a time (the order of the servers
alternating), as `POST /v1/plans?wait=30`: the answer carries the plan. Per job, from
the job's own times (one machine's clock) and the plan's report:

- submit: the request's start to the job's `created` (admission and the insert);
- pickup: `created` to `started` (the worker's claim);
- plan: the plan's `solver.total_time`;
- worker beside the plan: `started` to `finished` less the plan (what the worker does
  before and after the plan: the progress writer's end, the verdict, the plan's JSON and
  its compression, the store write);
- answer: `finished` to the answer's last byte (the server learning of the end, reading
  the job back and writing the response);
- whole: the request's start to its answer; its share beside the plan;
- and the sizes: the answer, a plan and an NLP solution as each store keeps them.

    python -m bench job_latency --before COMMIT[,COMMIT...] [--count 16] [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import sqlite3
import statistics
import tempfile
import time
from datetime import datetime
from pathlib import Path

import httpx
import numpy as np

from bench import harness
from testbed.service import LiveServer
from testbed.suites.ordinary import SEED, tasks

DOC = harness.DOCS / "bench-service.md"
SECTION = "Plan jobs through the service: submit to answer"
CSV = harness.RESULTS / "job_latency.csv"
STAGES = [("submit", "submit [ms]"), ("pickup", "pickup [ms]"), ("plan", "plan [ms]"),
          ("worker", "worker beside the plan [ms]"), ("answer", "answer [ms]"),
          ("whole", "whole [ms]"), ("beside", "beside the plan [ms]")]


def _seconds(stamp: str) -> float:
    return datetime.fromisoformat(stamp).timestamp()


def submit(http: httpx.Client, body: dict) -> dict:
    """One plan job, submitted and answered with its plan: its stages [ms]."""
    sent = time.time()
    answer = http.post("/v1/plans", params={"wait": 30}, json=body)
    done = time.time()
    answer.raise_for_status()
    job = answer.json()
    if job.get("plan") is None:
        raise RuntimeError(f"no plan within the wait: {job['status']}")
    created, started, finished = (_seconds(job[k]) for k in ("created", "started", "finished"))
    plan = job["plan"]["solver"]["total_time"]
    stages = {"submit": created - sent, "pickup": started - created, "plan": plan,
              "worker": finished - started - plan, "answer": done - finished,
              "whole": done - sent, "beside": done - sent - plan}
    return {**{k: 1e3 * v for k, v in stages.items()}, "status": job["status"],
            "verified": bool(job["plan"]["verification"]["verified"]),
            "bytes": len(answer.content)}


def run(befores: list[str], count: int, repeats: int) -> list[dict]:
    """Every measured job of this checkout ("now") and of each earlier commit, as rows."""
    chosen = [(name, scene.model_dump(mode="json")) for name, scene in tasks(count, SEED)]
    rows = []
    with contextlib.ExitStack() as stack:
        roots = {"now": harness.ROOT, **{c: stack.enter_context(harness.checkout(c))
                                         for c in befores}}
        folders = {v: Path(stack.enter_context(tempfile.TemporaryDirectory())) for v in roots}
        servers = {v: stack.enter_context(LiveServer(folders[v] / "jobs.sqlite3", root=root,
                                                     UNDERTOW_WORKERS="1"))
                   for v, root in roots.items()}
        clients = {v: stack.enter_context(httpx.Client(base_url=live.url, timeout=120))
                   for v, live in servers.items()}
        for http in clients.values():  # the workers build the tasks' NLPs
            for _, body in chosen:
                submit(http, body)
        for r in range(repeats):
            order = list(clients) if r % 2 == 0 else list(clients)[::-1]
            for name, body in chosen:
                for version in order:
                    rows.append({"version": version, "task": name, "repeat": r,
                                 **submit(clients[version], body)})
                    print(rows[-1], flush=True)
        sizes = {v: stored(folder) for v, folder in folders.items()}
    return [{**row, **sizes[row["version"]]} for row in rows]


def stored(folder: Path) -> dict:
    """The median size of a plan and of an NLP solution as the store in `folder` keeps
    them [kB] (compressed, since schema version 9)."""
    with contextlib.closing(sqlite3.connect(folder / "jobs.sqlite3")) as db:
        sizes = db.execute("SELECT length(plan), length(solution) FROM jobs "
                           "WHERE plan IS NOT NULL").fetchall()
    return {"stored_plan_kb": statistics.median(p for p, _ in sizes) / 1e3,
            "stored_solution_kb": statistics.median(s or 0 for _, s in sizes) / 1e3}


def summary(rows: list[dict], version: str) -> dict:
    """Medians of each stage over the version's jobs."""
    mine = [r for r in rows if r["version"] == version]
    out = {"version": version, "jobs": len(mine),
           "verified": sum(r["verified"] for r in mine)}
    for key, _ in STAGES:
        out[key] = statistics.median(r[key] for r in mine)
    for key in ("whole", "beside"):
        out[f"{key}_p90"] = float(np.percentile([r[key] for r in mine], 90))
    out["share"] = statistics.median(100 * r["beside"] / r["whole"] for r in mine)
    out["kb"] = statistics.median(r["bytes"] for r in mine) / 1e3
    out["stored_plan_kb"] = mine[0]["stored_plan_kb"]
    out["stored_solution_kb"] = mine[0]["stored_solution_kb"]
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench job_latency", description=__doc__)
    parser.add_argument("--before", required=True,
                        help="the earlier commits, comma-separated")
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    befores = args.before.split(",")
    rows = run(befores, args.count, args.repeats)
    table = [summary(rows, v) for v in ("now", *befores)]
    columns = [("version", "version"), ("jobs", "jobs"), ("verified", "verified"),
               *STAGES, ("whole_p90", "whole, 90th percentile [ms]"),
               ("beside_p90", "beside the plan, 90th percentile [ms]"),
               ("share", "median share beside the plan [%]"),
               ("kb", "answer [kB]"), ("stored_plan_kb", "plan as stored [kB]"),
               ("stored_solution_kb", "NLP solution as stored [kB]")]
    text = "\n\n".join([
        f"The first {args.count} tasks of the default suite, each submitted {args.repeats} "
        "times to a server of this checkout (now) and one of each earlier commit "
        f"({', '.join(befores)}) in turn, one plan at a time, as `POST /v1/plans?wait=30` on "
        "127.0.0.1; each server has one solver worker and a SQLite store of its own, its "
        "NLPs built by a first pass over the tasks. Medians over the jobs, from each job's "
        "`created`, `started` and `finished` and its plan's `solver.total_time`: submit, "
        "the request to the job's insert; pickup, to the worker's claim; the plan; the "
        "worker beside the plan (the progress writer's end, the verdict, the plan's JSON "
        "and its compression, the store write); the answer, the job's end to the "
        "response's last byte; whole, the request to its answer, and what of it is beside "
        "the plan (with their 90th percentiles over the jobs). The sizes: the answer's "
        "JSON, and the median plan and NLP solution as each store keeps them "
        "(zlib-compressed JSON).",
        harness.table(table, columns),
        f"Rows: `bench/results/job_latency.csv`. "
        f"{harness.manifest('job_latency', argv, started, note)}"])
    print(text)
    harness.write_csv(CSV, rows)
    harness.write_section(DOC, SECTION, text)
    return 0
