"""Load test of the plan service on loopback: N concurrent POST /v1/plans.

Starts uvicorn (app.main:app) on 127.0.0.1 with a temporary store, fires N plan requests
at once from one bounded httpx async loop, then polls every accepted job to its end.
Checks: every answer is 202 or 429 (queue full), none 5xx, every accepted job reaches
a final state (none lost). Reports submit latency, job latency (submit -> final), and
throughput in the section "Concurrent plan requests on loopback" of
docs/bench-service.md; exits 1 when a check fails.

    python -m bench service_load [--requests 50] [--workers 2] [--max-queued 32]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench import harness
from testbed.probes import QUICK
from testbed.service import LiveServer

SCENE = {**QUICK, "transcription": {"intervals": 50}}
"""The two-link plan of `testbed.probes.QUICK` (one passive, one wavy active joint) on 50
intervals."""
DOC = harness.DOCS / "bench-service.md"
SECTION = "Concurrent plan requests on loopback"
FINAL = {"succeeded", "failed", "cancelled"}
DEADLINE = 600.0  # [s] the whole run stops by itself after this


async def submit(http: httpx.AsyncClient) -> tuple[int, float, str | None, float]:
    """POST one plan: status, latency [s], job id, submit time."""
    start = time.perf_counter()
    r = await http.post("/v1/plans", json=SCENE)
    job_id = r.json().get("id") if r.status_code == 202 else None
    return r.status_code, time.perf_counter() - start, job_id, start


async def follow(http: httpx.AsyncClient, job_id: str, stop: float) -> tuple[str, float]:
    """Poll a job until it ends: final status and the time it was seen ending."""
    while time.perf_counter() < stop:
        job = (await http.get(f"/v1/plans/{job_id}")).json()
        if job["status"] in FINAL:
            return job["status"], time.perf_counter()
        await asyncio.sleep(0.1)
    return "lost", time.perf_counter()


async def run(url: str, requests: int) -> dict:
    limits = httpx.Limits(max_connections=requests)
    async with httpx.AsyncClient(base_url=url, timeout=120, limits=limits) as http:
        await http.post("/v1/plans?wait=60", json=SCENE)  # build the NLP once (cache warm-up)
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        answers = await asyncio.gather(*(submit(http) for _ in range(requests)))
        stop = time.perf_counter() + DEADLINE
        accepted = [(job_id, start) for status, _, job_id, start in answers if job_id]
        ends = await asyncio.gather(*(follow(http, j, stop) for j, _ in accepted))
        t1 = max((end for _, end in ends), default=time.perf_counter())
    return {"answers": answers, "accepted": accepted, "ends": ends, "t0": t0, "t1": t1,
            "load": load}


def percentiles(values: list[float]) -> tuple[float, float]:
    if not values:
        return (0, 0)
    return (float(np.percentile(values, 50)), float(np.percentile(values, 95)))


def report(result: dict, args: argparse.Namespace) -> tuple[str, bool]:
    statuses = [a[0] for a in result["answers"]]
    counts = {s: statuses.count(s) for s in sorted(set(statuses))}
    finals = [status for status, _ in result["ends"]]
    job_latency = [end - start for (_, start), (_, end)
                   in zip(result["accepted"], result["ends"], strict=True)]
    submit_latency = [a[1] for a in result["answers"]]
    span = result["t1"] - result["t0"]
    done = sum(s in FINAL for s in finals)
    ok = all(s in (202, 429) for s in statuses) and done == len(result["accepted"])
    p50s, p95s = percentiles(submit_latency)
    p50j, p95j = percentiles(job_latency)
    lines = [
        (f"{args.workers} solver worker processes, queue of {args.max_queued} (so at most "
         f"{args.workers + args.max_queued} unfinished plans); 1-minute load average "
         f"{result['load']:.1f} when the requests were sent. Scene: a two-link arm (one "
         "passive, one wavy active joint), legendre collocation, "
         f"{SCENE['transcription']['intervals']} intervals (the NLP is built once per worker, "
         "before or during the run)."),
        "",
        "| quantity | value |",
        "|---|---|",
        f"| requests sent at once | {len(statuses)} |",
        *(f"| answered {code} | {n} |" for code, n in counts.items()),
        f"| accepted jobs that reached a final state | {done} of {len(result['accepted'])} |",
        *(f"| final state {s} | {finals.count(s)} |" for s in sorted(set(finals))),
        f"| submit latency p50 / p95 | {1e3 * p50s:.1f} ms / {1e3 * p95s:.1f} ms |",
        f"| job latency (submit to final) p50 / p95 | {p50j:.2f} s / {p95j:.2f} s |",
        f"| wall time, first submit to last job end | {span:.2f} s |",
        f"| throughput | {done / span:.2f} plans/s |",
        "",
        (f"Verdict: {'PASS' if ok else 'FAIL'} (every answer 202 or 429, none 5xx, "
         "no accepted job lost)."),
        "",
        "Refused requests carry `Retry-After`; a client that honours it gets its plan later.",
    ]
    return "\n".join(lines), ok


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench service_load", description=__doc__)
    parser.add_argument("--requests", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--max-queued", type=int, default=32)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    with tempfile.TemporaryDirectory() as tmp:
        env = {"UNDERTOW_WORKERS": str(args.workers),
               "UNDERTOW_MAX_QUEUED": str(args.max_queued)}
        with LiveServer(Path(tmp) / "jobs.sqlite3", None, **env) as live:
            result = asyncio.run(run(live.url, args.requests))
    text, ok = report(result, args)
    text += "\n\n" + harness.manifest("service_load", argv, started, note)
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0 if ok else 1
