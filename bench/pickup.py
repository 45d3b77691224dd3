"""Pickup latency: how long a plan waits between its submission and its claim by an idle
worker, for the three ways a worker learns of a queued job.

- PostgreSQL, a worker node (`undertow worker --processes 1`) and an API-only server: the
  node LISTENs and procrastinate's trigger NOTIFYs whenever a job is deferred;
- SQLite, a server with its own solver worker: the server tells its worker over a pipe;
- SQLite, an API-only server and a worker node on the same file: the node polls the store
  every second (`app.worker.IDLE_POLL`), as every node did before LISTEN/NOTIFY.

Each configuration runs on 127.0.0.1 with the fake solver (one 20 ms iteration). After one
warm-up plan, `--plans` plans are submitted one at a time, each once the previous one has
ended (so the worker is idle); the latency is the job's `started` (written by the worker's
claim) minus its `created` (written by the API server's insert), both from the clock of
this one machine. Writes the section "Pickup latency" of docs/bench-service.md and
bench/results/pickup.csv.

    python -m bench pickup [--plans 30]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

from app.store import FINAL, JobStore, SqliteJobStore
from bench import harness
from testbed import postgres
from testbed.cluster import FAKE_SOLVER, WorkerNode, api_server
from testbed.probes import QUICK
from testbed.service import LiveServer

DOC = harness.DOCS / "bench-service.md"
SECTION = "Pickup latency"
FAKE = {**QUICK, "solver": {"max_iter": 1, "tol": 1e-8}}
SETTINGS = {"UNDERTOW_SOLVE_FUNCTION": FAKE_SOLVER}


@contextlib.contextmanager
def postgres_node(folder: Path) -> Iterator[tuple[str, JobStore]]:
    from app.store.postgres import PostgresJobStore

    with postgres.PostgresServer() as server:
        url = server.create_database("pickup")
        store = PostgresJobStore(url)
        with api_server(folder, url, "api", **SETTINGS) as api, \
                WorkerNode(folder, "node", 1, UNDERTOW_DB_URL=url, **SETTINGS):
            yield api.url, store
        store.close()


@contextlib.contextmanager
def sqlite_server(folder: Path) -> Iterator[tuple[str, JobStore]]:
    path = folder / "jobs.sqlite3"
    with LiveServer(path, UNDERTOW_WORKERS="1", UNDERTOW_SOLVE_FUNCTION=FAKE_SOLVER) as api:
        yield api.url, SqliteJobStore(path)


@contextlib.contextmanager
def sqlite_node(folder: Path) -> Iterator[tuple[str, JobStore]]:
    path = folder / "jobs.sqlite3"
    with LiveServer(path, UNDERTOW_WORKERS="0", UNDERTOW_SOLVE_FUNCTION=FAKE_SOLVER) as api, \
            WorkerNode(folder, "node", 1, UNDERTOW_DB_PATH=str(path), **SETTINGS):
        yield api.url, SqliteJobStore(path)


CONFIGURATIONS = [
    ("PostgreSQL, worker node (procrastinate's LISTEN/NOTIFY)", postgres_node),
    ("SQLite, the server's own worker (pipe)", sqlite_server),
    ("SQLite, worker node (1 s poll)", sqlite_node),
]


def measure(http: httpx.Client, store: JobStore, plans: int) -> list[float]:
    """Submit-to-claim latencies [s] of `plans` plans sent one at a time to an idle worker."""
    latencies = []
    for k in range(plans + 1):  # the first one warms the worker up
        job_id = http.post("/v1/plans", json=FAKE).json()["id"]
        deadline = time.monotonic() + 60
        while (record := store.get(job_id)) is not None and record.status not in FINAL:
            assert time.monotonic() < deadline, f"plan {job_id} did not end"
            time.sleep(0.01)
        assert record is not None and record.status == "succeeded", record
        assert record.started is not None
        if k:
            latencies.append(record.started - record.created)
        time.sleep(0.05)  # the worker is idle again, waiting
    return latencies


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench pickup", description=__doc__)
    parser.add_argument("--plans", type=int, default=30)
    args = parser.parse_args(argv)
    reason = postgres.missing()
    if reason is not None:
        print(f"cannot run: {reason}", file=sys.stderr)
        return 1
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for name, deployment in CONFIGURATIONS:
        with tempfile.TemporaryDirectory() as folder, \
                deployment(Path(folder)) as (url, store), \
                httpx.Client(base_url=url, timeout=60) as http:
            values = sorted(measure(http, store, args.plans))
        rows.append({"configuration": name, "plans": len(values),
                     "median_ms": 1e3 * statistics.median(values),
                     "p90_ms": 1e3 * values[int(0.9 * (len(values) - 1))],
                     "max_ms": 1e3 * values[-1], "load": harness.load()})
        print(rows[-1], flush=True)
    columns = [("configuration", "how the idle worker learns of the plan"),
               ("plans", "plans"), ("median_ms", "median [ms]"), ("p90_ms", "p90 [ms]"),
               ("max_ms", "max [ms]"), ("load", "load average after")]
    text = "\n\n".join([
        "Submit-to-claim latency with an idle worker: the job's `started` (the worker's "
        "claim) minus its `created` (the API server's insert), plans sent one at a time on "
        "127.0.0.1 with the fake solver (one 20 ms iteration), after one warm-up plan. On "
        "PostgreSQL (queued by procrastinate, the default) its trigger NOTIFYs its channel "
        "whenever a job is deferred and every idle solver process LISTENs on a connection "
        "of its own; the last row is the 1 s poll every worker node relied on before (and "
        "still falls back to when its listening connection breaks, and for a requeued or "
        "released job).",
        harness.table(rows, columns),
        f"Rows: `bench/results/pickup.csv`. {harness.manifest('pickup', argv, started, note)}"])
    print(text)
    harness.write_csv(harness.RESULTS / "pickup.csv", rows)
    harness.write_section(DOC, SECTION, text)
    return 0
