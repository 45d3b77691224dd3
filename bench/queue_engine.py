"""undertow's own PostgreSQL queue against procrastinate's (UNDERTOW_QUEUE=own and
=procrastinate, `app.store.queue_engine`), each part once per queue:

- tests: tests/test_node_faults.py and tests/test_distributed.py, run by pytest in a
  process of their own (one test at a time), with the queue in the environment of every
  server and node they start; passed and failed tests, wall and CPU time [s] (CPU of the
  test process and every undertow process it waited for; not PostgreSQL's);
- pickup: submit-to-claim latency with an idle worker node (`bench.pickup.measure`: one
  API-only server and one node with one solver process, the fake solver);
- faults: the probes of `python -m bench faults --postgres` (`bench.faults_postgres`): a
  node's main process, one solver process or a whole node killed with SIGKILL, SIGTERM, a
  `pg_ctl restart -m fast`, each while plans run and wait; whether every accepted plan
  succeeds with the infrastructure failures the fault should count and none lost;
- lines: what the engine takes over of undertow's queue code, and what this branch adds.

Each part writes bench/results/queue_engine_PART.csv; the section "Queue engine: own
queue against procrastinate" of docs/bench-service.md is made from every part's CSV.

    python -m bench queue_engine [--part tests|pickup|faults|lines ...] [--plans 30]
                                 [--tries 1]
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

from app.store import JobStore
from app.store.postgres import PostgresJobStore
from bench import faults_postgres, harness, pickup
from testbed import postgres
from testbed.cluster import WorkerNode, api_server

QUEUES = ("own", "procrastinate")
PARTS = ("tests", "pickup", "faults", "lines")
DOC = harness.DOCS / "bench-service.md"
SECTION = "Queue engine: own queue against procrastinate"
TESTS = ("tests/test_node_faults.py", "tests/test_distributed.py")
TEST_TIMEOUT = 1200.0  # [s] for both files, one queue
PICKUP_LIMIT = 0.050  # [s] the median submit-to-claim latency an engine must stay under

REPLACED: tuple[tuple[str, str, bool], ...] = (
    ("app/store/sql.py", "SqlJobStore.claim", True),
    ("app/store/sql.py", "SqlJobStore.renew", True),
    ("app/store/sql.py", "SqlJobStore.expire", True),
    ("app/store/postgres.py", "PostgresJobStore.claim_lock", False),
    ("app/store/postgres.py", "PostgresJobStore.expire_guard", False),
    ("app/store/migrations.py", "STEPS[4].postgres", False),
)
"""(file, definition, shared with SQLite): undertow's queue code whose work the engine
does on PostgreSQL: the claim, the renewal, the expiry and its guard, and the trigger that
NOTIFYs queued jobs. Definitions shared with SQLite stay, as SQLite keeps its own queue."""
QUEUE_CODE = ("app/store", "app/worker.py", "app/supervisor.py", "app/worker_node.py")
"""undertow's job and queue code, for scale."""


def _cpu_children() -> float:
    """CPU time [s] of the waited-for children of this process so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_tests(queue: str) -> dict:
    """The fault test files against `queue`: counts, failing tests, wall and CPU [s]."""
    env = {**os.environ, "UNDERTOW_QUEUE": queue}
    wall, cpu = time.perf_counter(), _cpu_children()
    try:
        run = subprocess.run([harness.PYTHON, "-m", "pytest", *TESTS, "-p", "no:xdist", "-q",
                              "-p", "no:cacheprovider"], cwd=harness.ROOT, env=env,
                             capture_output=True, text=True, timeout=TEST_TIMEOUT)
        out = run.stdout
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"").decode() if isinstance(exc.stdout, bytes) else exc.stdout or ""
        out += f"\ntimeout after {TEST_TIMEOUT:g} s"
    counts = {kind: int(n) for n, kind in re.findall(r"(\d+) (passed|failed|error)", out)}
    failing = re.findall(r"^(?:FAILED|ERROR) (\S+)", out, re.MULTILINE)
    return {"queue": queue, "passed": counts.get("passed", 0),
            "failed": counts.get("failed", 0) + counts.get("error", 0),
            "failing": "; ".join(f.split("::")[-1] for f in failing) or "–",
            "wall_s": time.perf_counter() - wall, "cpu_s": _cpu_children() - cpu}


@contextlib.contextmanager
def node_cluster(folder: Path, queue: str) -> Iterator[tuple[str, JobStore]]:
    """An API-only server and a worker node with one solver process on a throwaway
    PostgreSQL, queued by `queue`; (the API's URL, a store to read the jobs)."""
    settings = {**pickup.SETTINGS, "UNDERTOW_QUEUE": queue}
    with postgres.PostgresServer() as server:
        url = server.create_database("pickup")
        store = PostgresJobStore(url)
        with api_server(folder, url, "api", **settings) as api, \
                WorkerNode(folder, "node", 1, UNDERTOW_DB_URL=url, **settings):
            yield api.url, store
        store.close()


def run_pickup(queue: str, plans: int) -> dict:
    """Submit-to-claim latencies [ms] of `plans` plans on an idle node."""
    with tempfile.TemporaryDirectory() as folder, \
            node_cluster(Path(folder), queue) as (url, store), \
            httpx.Client(base_url=url, timeout=60) as http:
        values = sorted(pickup.measure(http, store, plans))
    return {"queue": queue, "plans": len(values),
            "median_ms": 1e3 * statistics.median(values),
            "p90_ms": 1e3 * values[int(0.9 * (len(values) - 1))], "max_ms": 1e3 * values[-1],
            "under_limit": statistics.median(values) < PICKUP_LIMIT, "load": harness.load()}


def run_faults(queue: str, tries: int) -> list[dict]:
    """The PostgreSQL fault probes against `queue`, `tries` times each."""
    rows = []
    for name, fault, counted in faults_postgres.PROBES:
        wall, cpu = time.perf_counter(), _cpu_children()
        runs = [faults_postgres.probe(fault, counted, UNDERTOW_QUEUE=queue)
                for _ in range(tries)]
        requeues = [r["requeue"] for r in runs if r["requeue"] is not None]
        rows.append({"queue": queue, "probe": name, "tries": tries,
                     **{k: sum(r[k] for r in runs)
                        for k in ("accepted", "succeeded", "failed", "infra", "lost")},
                     "requeue": harness.median(requeues) if requeues else None,
                     "span": harness.median(r["span"] for r in runs),
                     "ok": f"{sum(r['ok'] for r in runs)} of {tries}",
                     "wall_s": time.perf_counter() - wall, "cpu_s": _cpu_children() - cpu})
        print(rows[-1], flush=True)
    return rows


def _source_lines(node: ast.AST) -> int:
    """Lines of a definition, its docstring included."""
    end = getattr(node, "end_lineno", None)
    return 0 if end is None else end - getattr(node, "lineno", end) + 1


def definition_lines(path: str, name: str) -> int:
    """Lines of `name` in `path`: "Class.method", "Class.attribute", or "STEPS[k].field"
    (a keyword of the k-th element of the list STEPS)."""
    tree = ast.parse((harness.ROOT / path).read_text())
    if name.startswith("STEPS["):
        index, field = int(name[6:name.index("]")]), name.rsplit(".", 1)[1]
        for node in ast.walk(tree):
            targets = (node.targets if isinstance(node, ast.Assign) else [node.target]
                       if isinstance(node, ast.AnnAssign) else [])
            if any(isinstance(t, ast.Name) and t.id == "STEPS" for t in targets):
                assert isinstance(node, ast.Assign | ast.AnnAssign)
                assert isinstance(node.value, ast.Tuple)
                step = node.value.elts[index]
                assert isinstance(step, ast.Call)
                return sum(_source_lines(k.value) for k in step.keywords if k.arg == field)
        raise LookupError(name)
    owner, member = name.split(".")
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name == owner:
            for item in node.body:
                names = ([item.name] if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef)
                         else [t.id for t in getattr(item, "targets", []) if
                               isinstance(t, ast.Name)])
                if member in names:
                    return _source_lines(item)
    raise LookupError(name)


def _nonblank(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.strip())


def branch_change(folders: tuple[str, ...]) -> tuple[int, int]:
    """(lines added, lines removed) under `folders` since this branch left main."""
    base = subprocess.run(["git", "-C", str(harness.ROOT), "merge-base", "HEAD", "main"],
                          capture_output=True, text=True, check=False).stdout.strip()
    if not base:
        return 0, 0
    out = subprocess.run(["git", "-C", str(harness.ROOT), "diff", "--numstat", base, "--",
                          *folders], capture_output=True, text=True, check=False).stdout
    added = removed = 0
    for line in out.splitlines():
        a, r, _ = line.split("\t", 2)
        if a != "-":
            added, removed = added + int(a), removed + int(r)
    return added, removed


def run_lines() -> list[dict[str, object]]:
    """The replaced definitions, the engine adapter and this branch's change, in lines."""
    counts = [definition_lines(path, name) for path, name, _ in REPLACED]
    rows: list[dict[str, object]] = [
        {"what": f"{path}: {name}", "lines": count,
         "kind": "replaced on PostgreSQL, kept for SQLite" if shared
         else "replaced on PostgreSQL, PostgreSQL only"}
        for (path, name, shared), count in zip(REPLACED, counts, strict=True)]
    total = sum(counts)
    only_pg = sum(c for (_, _, shared), c in zip(REPLACED, counts, strict=True) if not shared)
    adapter = harness.ROOT / "app" / "store" / "queue_engine.py"
    code = [p for f in QUEUE_CODE for p in ((harness.ROOT / f).rglob("*.py")
                                            if (harness.ROOT / f).is_dir()
                                            else [harness.ROOT / f]) if p != adapter]
    added, removed = branch_change(("app",))
    test_added, test_removed = branch_change(("tests",))
    rows += [
        {"what": "undertow's queue code the engine replaces on PostgreSQL", "lines": total,
         "kind": "sum"},
        {"what": "of which PostgreSQL-only (removable if the engine were the only "
                 "PostgreSQL queue)", "lines": only_pg, "kind": "sum"},
        {"what": "undertow's job and queue code (non-blank lines of "
                 + ", ".join(QUEUE_CODE) + ", the adapter not counted)",
         "lines": sum(_nonblank(p) for p in code), "kind": "scale"},
        {"what": "app/store/queue_engine.py (non-blank lines)",
         "lines": _nonblank(adapter) if adapter.exists() else 0, "kind": "added"},
        {"what": "app/ lines added / removed by this branch", "lines": f"{added} / {removed}",
         "kind": "added"},
        {"what": "tests/ lines added / removed by this branch",
         "lines": f"{test_added} / {test_removed}", "kind": "added"},
    ]
    return rows


def _csv(part: str) -> Path:
    return harness.RESULTS / f"queue_engine_{part}.csv"


def render(argv: list[str], started: float, note: str) -> str:
    """The doc section from every part's CSV there is."""
    blocks = [
        "undertow's own PostgreSQL queue (`UNDERTOW_QUEUE=own`: its claim statement, leases "
        "renewed by absolute end time, a NOTIFY trigger) against procrastinate 3.10 "
        "(`UNDERTOW_QUEUE=procrastinate`, `app/store/queue_engine.py`: procrastinate's fetch, "
        "heartbeats, stalled-job search, retry and NOTIFY, with undertow's `jobs` rows kept "
        "as the record and its supervisor running each solve in a process of its own). "
        "Everything on 127.0.0.1 with a throwaway PostgreSQL server per cluster and the fake "
        "solve function."]
    parts = {
        "tests": ("Fault tests (`" + "`, `".join(TESTS) + "`, one test at a time; CPU of "
                  "pytest and the undertow processes it started, PostgreSQL's not counted)",
                  [("queue", "queue"), ("passed", "passed"), ("failed", "failed"),
                   ("failing", "failing tests"), ("wall_s", "wall [s]"),
                   ("cpu_s", "CPU [s]")]),
        "pickup": (f"Submit-to-claim latency, idle node (`bench.pickup.measure`); the engine "
                   f"must stay under {1e3 * PICKUP_LIMIT:g} ms median",
                   [("queue", "queue"), ("plans", "plans"), ("median_ms", "median [ms]"),
                    ("p90_ms", "p90 [ms]"), ("max_ms", "max [ms]"),
                    ("under_limit", "median under the limit"),
                    ("load", "load average after")]),
        "faults": ("Fault probes of `python -m bench faults --postgres` (`UNDERTOW_LEASE` "
                   f"{faults_postgres.LEASE:g} s, {faults_postgres.PLANS} plans of 3 s, two "
                   "nodes of two processes; *as documented* as in docs/stability.md: every "
                   "accepted plan succeeds, with the infrastructure failures the fault should "
                   "count)",
                   [("queue", "queue"), ("probe", "fault"), ("tries", "tries"),
                    ("accepted", "accepted"), ("succeeded", "succeeded"),
                    ("failed", "failed"), ("infra", "infrastructure failures"),
                    ("lost", "lost"), ("requeue", "node 1's first plan left it after [s]"),
                    ("span", "fault to last plan's end [s]"), ("ok", "as documented"),
                    ("wall_s", "wall [s]"), ("cpu_s", "CPU [s]")]),
        "lines": ("Lines: what the engine replaces, what the branch adds",
                  [("what", "what"), ("kind", "kind"), ("lines", "lines")]),
    }
    for part, (title, columns) in parts.items():
        if _csv(part).exists():
            blocks += [f"**{title}.**", harness.table(harness.read_csv(_csv(part)), columns)]
    blocks.append("Rows: `bench/results/queue_engine_*.csv`. "
                  + harness.manifest("queue_engine", argv, started, note))
    return "\n\n".join(blocks)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench queue_engine", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", action="append", choices=PARTS,
                        help="the parts to run (default: all)")
    parser.add_argument("--plans", type=int, default=30, help="pickup: plans per queue")
    parser.add_argument("--tries", type=int, default=1, help="faults: tries per probe")
    args = parser.parse_args(argv)
    parts = args.part or list(PARTS)
    reason = postgres.missing()
    if reason is not None and parts != ["lines"]:
        print(f"cannot run: {reason}", file=sys.stderr)
        return 1
    started, note = time.perf_counter(), harness.machine_note()
    for part in parts:
        rows: list[dict] = []
        if part == "lines":
            rows = run_lines()
        for queue in QUEUES if part != "lines" else ():
            if part == "tests":
                rows.append(run_tests(queue))
            elif part == "pickup":
                rows.append(run_pickup(queue, args.plans))
            else:
                rows += run_faults(queue, args.tries)  # prints each probe's row
            if part != "faults":
                print(rows[-1], flush=True)
        harness.write_csv(_csv(part), rows)
    text = render(argv, started, note)
    print(text)
    harness.write_section(DOC, SECTION, text)
    return 0
