"""Everyday operations on a PostgreSQL cluster: a 60 s database outage, nodes with
different leases through a database restart, how soon an idle node takes a job queued
again, and a rolling upgrade from an earlier version.

Each try starts a throwaway PostgreSQL server, one API-only server and worker nodes
(`undertow worker`) on 127.0.0.1 running the fake solve function (20 ms an iteration, a
progress write each), `UNDERTOW_LEASE` 20 s unless a probe says otherwise:

- *outage*: two nodes of two processes, 6 plans of 20 s (4 run, 2 wait); the database is
  stopped (`pg_ctl stop -m fast`) for 60 s (and 40 s: `--outages`) while the 4 run, then
  started again. Every plan
  must succeed, none with an infrastructure failure, none claimed twice; the verdicts of
  the plans that ended during the outage must be written within 10 s of its return; a
  solve that waited on the store would take longer than its 20 s.
- *leases*: node 1 with a lease of 1 s, node 2 with 20 s, two processes each, 8 plans of
  10 s; `pg_ctl restart -m fast` while 4 run. No plan may be requeued.
- *requeue*: two idle nodes of one process; a plan of 10 s is taken by one of them, which
  is then stopped (SIGTERM: the plan is released, queued again at once), or its solver
  process killed (requeued after the retry pause, `UNDERTOW_RETRY_BACKOFF` 0.5 s). The
  time from the requeue (plus the pause) to the other node's claim, from the plan's
  history.
- *upgrade*: two nodes of an earlier version (each of `--previous`, git revisions, run
  from a checkout), two processes each, `UNDERTOW_DRAIN` 70 s, running on the store
  before the API server of this version migrates it, and 20 plans of 30 to 60 s; after
  40 s a node of this version starts and the first old node is stopped
  (SIGTERM: draining, where that version drains), after 100 s the same for the second.
  No plan may be claimed twice, lost or a dead letter.

Writes the section "Cluster operations on PostgreSQL" of docs/stability.md and
bench/results/cluster_ops.csv.

    python -m bench cluster_ops [--tries 3] [--probes outage leases requeue upgrade]
                                [--outages 60 40] [--previous REV ...] [--upgrade-tries 1]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from app.store import FINAL, JobRecord
from app.store.postgres import PostgresJobStore
from bench import harness
from bench.faults import scene
from testbed import postgres
from testbed.cluster import FAKE_SOLVER, WorkerNode, api_server
from testbed.probes import worker_pids
from testbed.service import ROOT

SECTION = "Cluster operations on PostgreSQL"
LEASE = 20.0  # [s]
OUTAGES = (60.0, 40.0)
"""[s] how long the outage probe stops the database, by default (the issue's 60 s, and
one that falls between two of psycopg_pool's own reconnection attempts)."""
OLD_NODES = ("old-1", "old-2")
"""The nodes of the earlier version in the upgrade probe."""
ITERATION = 0.02  # [s] of the fake solver
SETTINGS = {"UNDERTOW_SOLVE_FUNCTION": FAKE_SOLVER, "UNDERTOW_LEASE": str(LEASE),
            "UNDERTOW_MAX_QUEUED": "64", "UNDERTOW_RETRY_BACKOFF": "0.5"}
PREVIOUS = ("cc6413d",)
"""The earlier version of the upgrade probe, by default: the commit before the database
derived each job's status from its engine job's (its nodes write the status themselves,
as the database derives it). Releases before da7fea7 cannot run beside this one: a store
of this version refuses to open while their nodes are alive (`EarlierNodes`)."""


@dataclass
class Cluster:
    """A probe's PostgreSQL server, store, API server client and worker nodes."""

    server: postgres.PostgresServer
    url: str
    store: PostgresJobStore
    http: httpx.Client
    folder: Path
    stack: contextlib.ExitStack
    settings: dict[str, str]
    """The UNDERTOW_* settings of its API server and, unless a node says otherwise, nodes."""
    nodes: dict[str, WorkerNode] = field(default_factory=dict)

    def node(self, name: str, processes: int, root: Path = ROOT, **extra: str) -> WorkerNode:
        """Start worker node `name` running the code at `root`, with `extra` settings."""
        node = WorkerNode(self.folder, name, processes, UNDERTOW_DB_URL=self.url,
                          **{**self.settings, **extra}).of_version(root)
        self.nodes[name] = self.stack.enter_context(node)
        return node

    def submit(self, iterations: list[int]) -> list[str]:
        """Plans of `iterations` fake iterations each; their ids."""
        ids = []
        for count in iterations:
            r = self.http.post("/v1/plans", json=scene(count))
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        return ids

    def solving(self) -> list[JobRecord]:
        """The plans past their first iteration."""
        return [r for r in self.store.list(status="running", limit=100)
                if (r.progress or {}).get("phase") == "solving"]

    def wait_solving(self, count: int, timeout: float = 60.0) -> list[JobRecord]:
        deadline = time.monotonic() + timeout
        while len(running := self.solving()) < count:
            assert time.monotonic() < deadline, f"{count} plans did not start solving"
            time.sleep(0.05)
        return running

    def finals(self, ids: list[str], timeout: float) -> tuple[dict[str, JobRecord], dict]:
        """{id: record} of the plans that ended within `timeout` s, {id: when seen ended
        [time.time()]}; reads through database outages."""
        ended: dict[str, JobRecord] = {}
        seen: dict[str, float] = {}
        deadline = time.monotonic() + timeout
        while len(ended) < len(ids) and time.monotonic() < deadline:
            with contextlib.suppress(Exception):
                for job_id in ids:
                    if job_id not in ended and (r := self.store.get(job_id)) is not None \
                            and r.status in FINAL:
                        ended[job_id], seen[job_id] = r, time.time()
            time.sleep(0.05)
        return ended, seen


@contextlib.contextmanager
def cluster(old: Path | None = None, /, **extra: str) -> Iterator[Cluster]:
    """A fresh PostgreSQL server and API-only server, with SETTINGS and `extra` ones; no
    nodes, or with `old` two nodes of the code at `old` (`OLD_NODES`, two processes each,
    `UNDERTOW_DRAIN` 70 s) that run on the store before the API server of this version
    migrates it, as in a cluster being upgraded."""
    settings = {**SETTINGS, **extra}
    with tempfile.TemporaryDirectory() as folder, postgres.PostgresServer() as server, \
            contextlib.ExitStack() as stack:
        url = server.create_database("cluster")
        nodes = {} if old is None else {name: stack.enter_context(WorkerNode(
            Path(folder), name, 2, UNDERTOW_DB_URL=url, **settings,
            UNDERTOW_DRAIN="70").of_version(old)) for name in OLD_NODES}
        for node in nodes.values():
            node.wait_up(url)
        store = PostgresJobStore(url, timeout=2.0)
        stack.callback(store.close)
        api = stack.enter_context(api_server(Path(folder), url, "api", **settings))
        http = stack.enter_context(httpx.Client(base_url=api.url, timeout=30))
        yield Cluster(server, url, store, http, Path(folder), stack, settings, nodes)


def claims(record: JobRecord) -> int:
    return sum(e["event"] == "claimed" for e in record.history or [])


def _books(ids: list[str], ended: dict[str, JobRecord]) -> dict:
    """What became of the plans: succeeded, failed, lost, dead letters, infrastructure
    failures counted, plans claimed more than once."""
    records = list(ended.values())
    return {"plans": len(ids), "succeeded": sum(r.status == "succeeded" for r in records),
            "failed": sum(r.status != "succeeded" for r in records),
            "lost": len(ids) - len(records), "dead": sum(r.dead_letter for r in records),
            "infra": sum(r.infra_failures for r in records),
            "twice": sum(claims(r) > 1 for r in records)}


def _solve_time(record: JobRecord) -> float:
    return float(((record.plan or {}).get("solver") or {}).get("solve_time", float("nan")))


def outage(seconds: float) -> dict:
    """The database stopped for `seconds` while 4 plans of 20 s run."""
    with cluster() as c:
        for name in ("node-1", "node-2"):
            c.node(name, 2)
        ids = c.submit([1000] * 6)
        running = [r.id for r in c.wait_solving(4)]
        c.server.halt()
        time.sleep(seconds)
        c.server.resume()
        back = time.time()
        ended, seen = c.finals(ids, 180.0)
    verdicts = [seen[i] - back for i in running if i in seen]
    return {**_books(ids, ended), "verdict": max(verdicts) if verdicts else None,
            "solve": max((_solve_time(r) for r in ended.values()), default=None)}


def leases() -> dict:
    """Nodes with leases of 1 s and 20 s; the database restarted while 4 plans run."""
    with cluster() as c:
        c.node("node-1", 2, UNDERTOW_LEASE="1")
        c.node("node-2", 2)
        ids = c.submit([500] * 8)
        c.wait_solving(4)
        c.server.restart("fast")
        ended, _ = c.finals(ids, 120.0)
    return _books(ids, ended)


def _next_claim(record: JobRecord, after: str) -> float | None:
    """Seconds from the first `after` event of the history to the claim that follows it."""
    events = record.history or []
    starts = [k for k, e in enumerate(events) if e["event"] == after]
    if not starts:
        return None
    later = [e for e in events[starts[0]:] if e["event"] == "claimed"]
    return later[0]["at"] - events[starts[0]]["at"] if later else None


def _requeue_round(c: Cluster, kind: str) -> float | None:
    """One plan taken by a node, then its node stopped (`released`) or its solver killed
    (`infrastructure-failure`); the requeue-to-claim time [s], less the retry pause."""
    [job_id] = c.submit([250])
    [held] = c.wait_solving(1)
    node = next(n for n in c.nodes.values() if n.owns(held.worker))
    assert node.proc is not None
    if kind == "released":
        node.stop()
    else:
        os.kill(worker_pids(node.proc.pid)[0], signal.SIGKILL)
    ended, _ = c.finals([job_id], 60.0)
    if kind == "released":
        node.start()
        time.sleep(3.0)  # up and idle again
    pause = 0.0 if kind == "released" else float(SETTINGS["UNDERTOW_RETRY_BACKOFF"])
    took = _next_claim(ended[job_id], kind) if job_id in ended else None
    return None if took is None else took - pause


def requeue(rounds: int = 5) -> dict:
    """`rounds` requeues of each kind to two idle nodes of one process."""
    with cluster() as c:
        for name in ("node-1", "node-2"):
            c.node(name, 1)
        time.sleep(3.0)
        out = {}
        for kind, key in (("released", "released"), ("infrastructure-failure", "paused")):
            times = [_requeue_round(c, kind) for _ in range(rounds)]
            out[key] = [t for t in times if t is not None]
    return out


def upgrade(previous: str) -> dict:
    """Two nodes of `previous` replaced one at a time by nodes of this version while 20
    plans of 30 to 60 s run."""
    draw = random.Random(20261127)
    with harness.checkout(previous) as old, cluster(old) as c:
        ids = c.submit([draw.randint(1500, 3000) for _ in range(20)])
        started = time.monotonic()
        for k, (at, old_name) in enumerate(((40.0, "old-1"), (100.0, "old-2"))):
            time.sleep(max(0.0, started + at - time.monotonic()))
            c.node(f"new-{k + 1}", 2, UNDERTOW_DRAIN="70")
            c.nodes[old_name].stop(timeout=90.0)
        ended, _ = c.finals(ids, 600.0)
        span = time.monotonic() - started
    return {**_books(ids, ended), "span": span}


PROBES: dict[str, Callable[..., dict]] = {"outage": outage, "leases": leases,
                                          "requeue": requeue, "upgrade": upgrade}

COLUMNS = [("probe", "probe"), ("tries", "tries"), ("plans", "plans"),
           ("succeeded", "succeeded"), ("failed", "failed"), ("lost", "lost"),
           ("dead", "dead letters"), ("infra", "infrastructure failures"),
           ("twice", "claimed more than once"),
           ("verdict", "verdicts written after the database's return, longest [s]"),
           ("solve", "longest solve [s]"),
           ("released", "released to claimed, median (longest) [ms]"),
           ("paused", "requeued to claimed less the pause, median (longest) [ms]"),
           ("span", "plans submitted to the last one's end [s]")]
SUMMED = ("plans", "succeeded", "failed", "lost", "dead", "infra", "twice")


def _ms(values: list[float]) -> str:
    return (f"{1e3 * harness.median(values):.1f} ({1e3 * max(values):.1f}, "
            f"{len(values)} requeues)") if values else "–"


def _row(name: str, runs: list[dict]) -> dict:
    """One probe's tries in one row: counts summed, times at their worst or median."""
    row: dict = {"probe": name, "tries": len(runs)}
    for key in SUMMED:
        if key in runs[0]:
            row[key] = sum(r[key] for r in runs)
    for key in ("verdict", "solve", "span"):
        values = [r[key] for r in runs if r.get(key) is not None]
        row[key] = max(values) if values else None
    for key in ("released", "paused"):
        if key in runs[0]:
            row[key] = _ms([t for r in runs for t in r[key]])
    return row


def _revision(rev: str) -> str:
    """A git revision as its short hash and commit date."""
    out = subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h of %cs", rev],
                         capture_output=True, text=True, check=True).stdout.strip()
    return f"commit {out}"


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench cluster_ops", description=__doc__)
    parser.add_argument("--tries", type=int, default=3)
    parser.add_argument("--probes", nargs="+", choices=list(PROBES), default=list(PROBES))
    parser.add_argument("--previous", nargs="+", default=list(PREVIOUS),
                        help="the earlier versions of the upgrade probe (git revisions)")
    parser.add_argument("--upgrade-tries", type=int, default=1)
    parser.add_argument("--outages", type=float, nargs="+", default=list(OUTAGES),
                        help="how long the outage probe stops the database [s]")
    args = parser.parse_args(argv)
    reason = postgres.missing()
    if reason is not None:
        print(f"cannot run: {reason}")
        return 1
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for name in args.probes:
        if name == "outage":
            for seconds in args.outages:
                rows.append(_row(f"outage of {seconds:g} s", [
                    outage(seconds) for _ in range(args.tries)]))
                print(rows[-1], flush=True)
            continue
        if name != "upgrade":
            rows.append(_row(name, [PROBES[name]() for _ in range(args.tries)]))
            print(rows[-1], flush=True)
            continue
        for rev in args.previous:
            rows.append(_row(f"upgrade from {rev}", [
                upgrade(rev) for _ in range(args.upgrade_tries)]))
            print(rows[-1], flush=True)
    previous = "; ".join(_revision(rev) for rev in args.previous)
    text = "\n\n".join([
        "A throwaway PostgreSQL server, one API-only server and worker nodes (`undertow "
        "worker`) on 127.0.0.1, the fake solve function (20 ms an iteration, a progress "
        f"write each), `UNDERTOW_LEASE` {LEASE:g} s unless said otherwise, a fresh cluster "
        "per try. *outage of S s*: two nodes of two processes, 6 plans of 20 s, the database "
        "stopped for S s while 4 of them run. *leases*: node 1 with a lease of "
        "1 s, node 2 with 20 s, 8 plans of 10 s, `pg_ctl restart -m fast` while 4 run. "
        "*requeue*: two idle nodes of one process, a plan of 10 s released by its node's "
        "SIGTERM, or requeued after its solver process was killed (pause "
        f"{SETTINGS['UNDERTOW_RETRY_BACKOFF']} s), 5 of each per try; times from the "
        "plan's history. *upgrade from REV*: two nodes of two processes of the earlier "
        f"version REV ({previous}), `UNDERTOW_DRAIN` 70 s (where it knows it), started "
        "before the API server of this version migrates the store, 20 plans "
        "of 30 to 60 s; after 40 s and 100 s a node of this version starts and an old one "
        f"is stopped (SIGTERM). Load average at the end: {harness.load()}.",
        harness.table(rows, [(k, h) for k, h in COLUMNS
                             if any(r.get(k) is not None for r in rows)]),
        "Rows: `bench/results/cluster_ops.csv`. "
        + harness.manifest("cluster_ops", argv, started, note)])
    print(text)
    harness.write_csv(harness.RESULTS / "cluster_ops.csv", rows)
    harness.write_section(harness.DOCS / "stability.md", SECTION, text)
    return 0
