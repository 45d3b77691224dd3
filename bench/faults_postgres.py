"""The PostgreSQL probes of `python -m bench faults --postgres` (see bench/faults.py).

Each try starts a throwaway PostgreSQL server, one API-only server and two worker nodes
(`undertow worker --processes 2`) on 127.0.0.1 with the fake solver, submits 10 plans of
3 s (4 run, 6 wait), applies the fault when node 1 solves one of them, and follows every
accepted plan to its end. Writes the section "Reliability: faults on PostgreSQL" of
docs/stability.md and bench/results/faults_postgres.csv.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from collections import Counter
from collections.abc import Callable

from app.store import FINAL
from app.store.postgres import PostgresJobStore
from bench import harness
from bench.cluster_ops import LEASE, cluster
from bench.faults import LONG
from testbed import postgres
from testbed.cluster import WorkerNode
from testbed.probes import worker_pids

SECTION = "Reliability: faults on PostgreSQL"
PLANS = 10
SETTLE = 120.0  # [s]


def _on_node(store: PostgresJobStore, node: WorkerNode) -> dict[str, str]:
    """{job id: worker} of the plans the node is solving (past their first iteration)."""
    return {r.id: r.worker for r in store.list(status="running", limit=100)
            if r.worker is not None and node.owns(r.worker)
            and (r.progress or {}).get("phase") == "solving"}


def _kill_main(node: WorkerNode, server: postgres.PostgresServer) -> None:
    assert node.proc is not None
    os.kill(node.proc.pid, signal.SIGKILL)


def _kill_solver(node: WorkerNode, server: postgres.PostgresServer) -> None:
    assert node.proc is not None
    os.kill(worker_pids(node.proc.pid)[0], signal.SIGKILL)


def _kill_node(node: WorkerNode, server: postgres.PostgresServer) -> None:
    node.kill()


def _sigterm(node: WorkerNode, server: postgres.PostgresServer) -> None:
    assert node.proc is not None
    node.proc.send_signal(signal.SIGTERM)


def _restart(node: WorkerNode, server: postgres.PostgresServer) -> None:
    server.restart("fast")


PROBES: list[tuple[str, Callable[[WorkerNode, postgres.PostgresServer], None], str]] = [
    ("kill -9 of a node's main process", _kill_main, "node"),
    ("kill -9 of one solver process", _kill_solver, "one"),
    (f"kill -9 of a whole node (its process group; lease {LEASE:g} s)", _kill_node, "node"),
    ("SIGTERM of a node", _sigterm, "none"),
    ("pg_ctl restart -m fast", _restart, "none"),
]
"""(fault, how, which plans count an infrastructure failure: every plan node 1 was running,
one of them, none)"""


def probe(fault: Callable[[WorkerNode, postgres.PostgresServer], None],
          counted: str, **extra: str) -> dict:
    """One try of `fault`; `extra`: more UNDERTOW_* settings of the servers and nodes."""
    with cluster(**extra) as c:
        store, server = c.store, c.server
        nodes = [c.node(name, 2) for name in ("node-1", "node-2")]
        ids = c.submit([LONG] * PLANS)
        deadline = time.monotonic() + 60
        while len(held := _on_node(store, nodes[0])) < 2:  # both of its processes busy
            assert time.monotonic() < deadline, "node 1 did not solve two plans"
            time.sleep(0.05)
        struck = time.monotonic()
        fault(nodes[0], server)
        requeue = None
        deadline = struck + SETTLE
        outcomes: Counter[str] = Counter()
        pending = list(ids)
        while pending and time.monotonic() < deadline:
            with contextlib.suppress(Exception):  # the database may be restarting
                if requeue is None:  # the first of node 1's plans to leave its worker
                    for job_id, holder in held.items():
                        record = store.get(job_id)
                        if record is not None and (record.status != "running"
                                                   or record.worker != holder):
                            requeue = time.monotonic() - struck
                            break
                job = store.get(pending[0])
                if job is not None and job.status in FINAL:
                    kind = ("dead letter" if job.dead_letter else job.status)
                    outcomes[kind] += 1
                    outcomes["infrastructure failures"] += job.infra_failures
                    pending.pop(0)
                    continue
            time.sleep(0.05)
        span = time.monotonic() - struck
    outcomes["lost"] += len(pending)
    expected = {"node": len(held), "one": 1, "none": 0}[counted]
    ok = outcomes["succeeded"] == PLANS and outcomes["infrastructure failures"] == expected
    return {"accepted": PLANS, "succeeded": outcomes["succeeded"],
            "failed": outcomes["failed"] + outcomes["dead letter"],
            "infra": outcomes["infrastructure failures"], "lost": outcomes["lost"],
            "requeue": requeue, "span": span, "ok": ok}


COLUMNS = [("probe", "fault"), ("tries", "tries"), ("accepted", "plans accepted"),
           ("succeeded", "succeeded"), ("failed", "failed"),
           ("infra", "infrastructure failures counted"), ("lost", "lost"),
           ("requeue", "requeue: node 1's first plan left its worker after [s], median"),
           ("requeue_max", "the same, the longest [s]"),
           ("span", "fault to the last plan's end [s], median"), ("ok", "as documented")]


def main(argv: list[str], tries: int, probes: int | None = None) -> int:
    """The PostgreSQL probes (the first `probes`, default all), `tries` times each."""
    reason = postgres.missing()
    if reason is not None:
        print(f"cannot run: {reason}")
        return 1
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for name, fault, counted in PROBES[:probes]:
        runs = [probe(fault, counted) for _ in range(tries)]
        requeues = [r["requeue"] for r in runs if r["requeue"] is not None]
        rows.append({"probe": name, "tries": tries,
                     **{k: sum(r[k] for r in runs)
                        for k in ("accepted", "succeeded", "failed", "infra", "lost")},
                     "requeue": harness.median(requeues) if requeues else None,
                     "requeue_max": max(requeues) if requeues else None,
                     "span": harness.median(r["span"] for r in runs),
                     "ok": f"{sum(r['ok'] for r in runs)} of {tries}"})
        print(rows[-1], flush=True)
    text = "\n\n".join([
        "A throwaway PostgreSQL server, one API-only server and two worker nodes (`undertow "
        "worker --processes 2`) on 127.0.0.1, the jobs queued by procrastinate, a fresh "
        "cluster per try, the fake solve "
        "function (plans of 3 s), `UNDERTOW_LEASE` "
        f"{LEASE:g} s, `UNDERTOW_RETRY_BACKOFF` 0.5 s. {PLANS} plans are submitted (4 "
        "run, 6 wait); the fault strikes while both of node 1's processes solve one. "
        "*As documented*: every accepted plan succeeds; each plan whose process died counts one "
        "infrastructure failure (both of node 1's when its main process or the whole node "
        "dies, one for one solver process), none for SIGTERM (released) or a database "
        "restart. *Requeue* is how long the first of node 1's two plans "
        "stayed `running` under its worker after the fault (for the restart: until it "
        f"ended, as nothing is requeued). Load average at the end: {harness.load()}.",
        harness.table(rows, COLUMNS),
        "Rows: `bench/results/faults_postgres.csv`. "
        + harness.manifest("faults", ["--postgres", *[a for a in argv if a != "--postgres"]],
                           started, note)])
    print(text)
    harness.write_csv(harness.RESULTS / "faults_postgres.csv", rows)
    harness.write_section(harness.DOCS / "stability.md", SECTION, text)
    return 0
