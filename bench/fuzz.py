"""Generated input against every operation of the service (issue 35): schemathesis over the
committed OpenAPI document (openapi/openapi.json) against a live server with a solver
worker; no request may get a 5xx and no worker process may die.

The server: uvicorn serving app.main:app (`testbed.service.LiveServer`) with an API key,
which the run sends, one solver worker process and the tight limits of
tests/test_schemathesis.py (`LIMITS`), so that any plan or wave design the run manages to
submit is small. Before the run the bench leaves data for the operations that take an
id: a plan that succeeded, one that failed (one Ipopt iteration), one cancelled, a batch
of two; their ids, the batch's and the example names are a schemathesis dictionary that
half of the generated path parameters are drawn from (the other half are generated), so
that those operations reach jobs, plots, samples, retries (which queue the job for the
worker again) and cancels instead of a 404.

The run: every operation, all of schemathesis' checks but `positive_data_acceptance`
(docs/api.md, "Fuzzing": the service refuses bodies by rules a JSON schema cannot state),
the coverage, fuzzing and stateful phases, a fixed seed, one schemathesis worker. Cases
are counted from schemathesis' own NDJSON report (`bench.fuzz_cases`), one request each;
the server's /metrics before and after give its own count of 5xx answers and of plan
solves; the server's worker processes are watched throughout (`testbed.worker_watch`).
After the run /healthz must answer 200 and a small plan must still succeed.

Writes bench/results/fuzz.csv (one row per operation, then a total row with the run's
figures) and the section "Fuzzing every operation" of docs/benchmarks.md; exits 1 when a
5xx, a dead worker, a failed check or a server that no longer serves was found, and then
keeps the server's log, schemathesis' output and its reports in the temporary folder it
names (deleted otherwise).

    python -m bench fuzz [--max-examples 100] [--seed 1] [--phases coverage,fuzzing,stateful]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
from prometheus_client.parser import text_string_to_metric_families

from bench import fuzz_cases, harness
from bench.scenes import request
from testbed.service import LiveServer, wait_final
from testbed.worker_watch import WorkerWatch, dead, supervisor_lines

KEY = "fuzz-key"
LIMITS = {"UNDERTOW_MAX_NODES": "200", "UNDERTOW_MAX_WALL_TIME": "2", "UNDERTOW_WORKERS": "1",
          "UNDERTOW_MAX_QUEUED": "0", "UNDERTOW_MAX_POINTS": "200", "UNDERTOW_MAX_HORIZON": "10",
          "UNDERTOW_MAX_WAIT": "2", "UNDERTOW_MAX_WAVE_STARTS": "2",
          "UNDERTOW_MAX_WAVE_FREQUENCY": "3"}
"""The server's settings besides its key and store: tests/test_schemathesis.py's."""
DOCUMENT = harness.ROOT / "openapi" / "openapi.json"
CSV = harness.RESULTS / "fuzz.csv"
DOC = harness.DOCS / "benchmarks.md"
SECTION = "Fuzzing every operation"
GOAL = 5_000  # cases the run is to reach (issue 35)
SMALL = request("arm-2", N=10, solver={"max_wall_time": 2.0})
"""A plan the limits admit: the two-link arm on 10 intervals, solved in about a second."""
WAIT = 300.0  # [s] longest wait for a plan of the bench's own to be accepted, and to end
DRAWN = 0.5  # share of the generated path parameters drawn from the dictionaries


def plan(http: httpx.Client, scene: dict, cancel: bool = False) -> dict:
    """Submit `scene` (again while the queue is full, `WAIT` s at most), cancel it at once
    when `cancel`, and return the job once it ended."""
    deadline = time.monotonic() + WAIT
    while (answer := http.post("/v1/plans", json=scene)).status_code == 429:
        assert time.monotonic() < deadline, "the queue stayed full"
        time.sleep(float(answer.headers.get("retry-after", 1)))
    assert answer.status_code == 202, answer.text[:500]
    job_id = answer.json()["id"]
    if cancel:
        http.delete(f"/v1/plans/{job_id}")
    return wait_final(http, job_id, WAIT)


def seed_data(http: httpx.Client) -> dict[str, list[str]]:
    """Jobs, a batch and the example names for the operations that take an id, by the name
    of their dictionary ("jobs", "batches", "examples")."""
    jobs = [plan(http, SMALL), plan(http, {**SMALL, "solver": {**SMALL["solver"], "max_iter": 1}}),
            plan(http, SMALL, cancel=True)]
    answer = http.post("/v1/batches", json={"base": SMALL, "grid": {"duration": [1.5, 2.0]}})
    assert answer.status_code == 202, answer.text[:500]
    batch = answer.json()
    members = [wait_final(http, m["job_id"], WAIT) for m in batch["members"]]
    return {"jobs": [job["id"] for job in jobs + members], "batches": [batch["id"]],
            "examples": [e["name"] for e in http.get("/v1/examples").json()]}


def config(dictionaries: dict[str, list[str]]) -> str:
    """The schemathesis configuration (TOML) drawing path parameters from `dictionaries`."""
    lines = []
    for name, values in dictionaries.items():
        lines += [f"[dictionaries.{name}]", f"values = {json.dumps(values)}", ""]
    lines.append("[parameters]")
    for parameter, name in (("job_id", "jobs"), ("batch_id", "batches"), ("name", "examples")):
        lines.append(f'"path.{parameter}" = {{ dictionary = "{name}", probability = {DRAWN} }}')
    return "\n".join(lines) + "\n"


def command(url: str, folder: Path, args: argparse.Namespace) -> list[str]:
    """The schemathesis run: its configuration and reports under `folder`."""
    return [harness.PYTHON, "-m", "schemathesis.cli", "--config-file",
            str(folder / "schemathesis.toml"), "run", str(DOCUMENT), "--url", url,
            "--checks", "all", "--exclude-checks", "positive_data_acceptance",
            "--header", f"X-API-Key: {KEY}", "--max-examples", str(args.max_examples),
            "--seed", str(args.seed), "--phases", args.phases, "--workers", "1",
            "--request-timeout", str(args.request_timeout), "--generation-database", "none",
            "--no-color", "--report", "ndjson,json",
            "--report-ndjson-path", str(folder / "events.ndjson"),
            "--report-json-path", str(folder / "report.json")]


def server_counts(http: httpx.Client) -> dict[str, float]:
    """The server's own counts (/metrics): answers by status class ("5xx") and plan solves
    by their status ("solves succeeded")."""
    counts: dict[str, float] = {}
    for family in text_string_to_metric_families(http.get("/metrics").text):
        for sample in family.samples:
            if sample.name == "undertow_http_requests_total":
                key = f"{sample.labels['status'][0]}xx"
            elif sample.name == "undertow_solve_duration_seconds_count":
                key = f"solves {sample.labels['status']}"
            else:
                continue
            counts[key] = counts.get(key, 0.0) + sample.value
    return counts


def _since(after: dict[str, float], before: dict[str, float], prefix: str) -> int:
    return int(sum(v - before.get(k, 0.0) for k, v in after.items() if k.startswith(prefix)))


def serve_and_fuzz(folder: Path, args: argparse.Namespace) -> dict:
    """Start the server, leave the data, run schemathesis, check the server still serves:
    the run's figures (besides its cases)."""
    with LiveServer(folder / "jobs.sqlite3", None, UNDERTOW_API_KEY=KEY, **LIMITS) as live:
        assert live.proc is not None
        watch = WorkerWatch(live.proc.pid).start()
        http = httpx.Client(base_url=live.url, headers={"X-API-Key": KEY}, timeout=WAIT)
        (folder / "schemathesis.toml").write_text(config(seed_data(http)))
        before, start = server_counts(http), time.perf_counter()
        run = subprocess.run(command(live.url, folder, args), cwd=folder, check=False,
                             capture_output=True, text=True)
        wall = time.perf_counter() - start
        (folder / "schemathesis.out").write_text(run.stdout + run.stderr)
        after = server_counts(http)
        health = http.get("/healthz").status_code
        after_plan = plan(http, SMALL)["status"]
        watch.stop()
    lines = supervisor_lines(live.log)
    return {"schemathesis_exit": run.returncode, "wall_time": round(wall, 1),
            "server_5xx": _since(after, before, "5xx"),
            "solves": _since(after, before, "solves "),
            "worker_processes": len(watch.seen), "workers_ended": len(watch.ended),
            "workers_stopped": lines["stopped"], "dead_workers": dead(watch, lines),
            "errors_logged": lines["errors"], "health_after": health,
            "plan_after": after_plan}


def measure(args: argparse.Namespace, folder: Path) -> tuple[list[dict], dict]:
    """The rows by operation and the total row with the run's figures (the server's store
    and log, schemathesis' output and reports under `folder`)."""
    figures = serve_and_fuzz(folder, args)
    report = json.loads((folder / "report.json").read_text())
    rows = fuzz_cases.rows(folder / "events.ndjson", json.loads(DOCUMENT.read_text()))
    total = {**fuzz_cases.total(rows), "cases_reported": report["test_cases"]["generated"],
             "failures": report["test_cases"]["unique_failures"],
             "operations_tested": report["operations"]["tested"],
             "operations": report["operations"]["total"], "seed": args.seed,
             "max_examples": args.max_examples, "phases": args.phases,
             "date": time.strftime("%Y-%m-%d"), **figures}
    return rows, total


def failed(total: dict) -> list[str]:
    """What the run found wrong (empty: nothing)."""
    found = {"5xx answers": total["5xx"] + total["server_5xx"],
             "dead workers": total["dead_workers"], "failed checks": total["failures"],
             "requests without an answer": total["no response"],
             "schemathesis exit status": total["schemathesis_exit"]}
    problems = [f"{what}: {n}" for what, n in found.items() if n]
    if total["health_after"] != 200 or total["plan_after"] != "succeeded":
        problems.append(f"after the run /healthz {total['health_after']}, a small plan "
                        f"{total['plan_after']}")
    return problems


def summary(total: dict, rows: list[dict]) -> str:
    """The run's figures, as a list."""
    goal = "reached" if total["cases"] >= GOAL else "NOT reached"
    refused = ", ".join(f"`{r['operation']}`" for r in rows if not r["2xx"]) or "none"
    return "\n".join([
        f"- **{total['cases']:,} cases** (requests; schemathesis counted "
        f"{total['cases_reported']:,}) on {total['operations_tested']} of "
        f"{total['operations']} operations, in {total['wall_time']:.0f} s; the goal of "
        f"{GOAL:,} {goal}.",
        f"- **{total['5xx']} answers with a 5xx** ({total['server_5xx']} by the server's own "
        f"count); {total['failures']} failed checks; {total['no response']} requests "
        f"without an answer.",
        f"- **{total['dead_workers']} dead workers**. Worker processes: "
        f"{total['worker_processes']} ran, {total['workers_ended']} ended while the server "
        f"ran, {total['workers_stopped']} stopped by the supervisor (a job past its budget, "
        f"an ignored cancel). Server log lines of level ERROR: {total['errors_logged']}.",
        f"- Plan solves by the worker during the run: {total['solves']}. Operations that "
        f"accepted no generated request: {refused}. After the run /healthz answered "
        f"{total['health_after']} and a small plan ended {total['plan_after']}."])


def text(rows: list[dict], total: dict, argv: list[str], started: float, note: str) -> str:
    """The section: the setup, the figures, the cases by operation, the manifest."""
    setup = (f"schemathesis over every operation of `openapi/openapi.json` against a live "
             f"server (`app.main:app`, an API key, one solver worker, the limits of "
             f"`tests/test_schemathesis.py`), all checks but `positive_data_acceptance`, "
             f"phases {total['phases']}, seed {total['seed']}, `--max-examples` "
             f"{total['max_examples']}, one schemathesis worker, run on {total['date']}. "
             "Half of the path parameters are ids of jobs and a batch left before the run "
             "(succeeded, failed, cancelled) or example names. A case is one request; "
             "`5xx` counts answers with a server error.")
    columns = [("operation", "operation"), ("cases", "cases"), *[(p, p) for p in
               fuzz_cases.PHASES if total[p]], *[(c, c) for c in fuzz_cases.CLASSES]]
    return "\n\n".join([
        setup, summary(total, rows), harness.table([*rows, total], columns),
        f"Rows: `bench/results/fuzz.csv`. {harness.manifest('fuzz', argv, started, note)}"])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench fuzz", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--max-examples", type=int, default=100,
                        help="schemathesis' examples per operation and phase")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--phases", default="coverage,fuzzing,stateful")
    parser.add_argument("--request-timeout", type=float, default=300.0, help="[s]")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    folder = Path(tempfile.mkdtemp(prefix="undertow-fuzz-"))
    rows, total = measure(args, folder)
    harness.write_csv(CSV, [*rows, total])
    harness.write_section(DOC, SECTION, text(rows, total, argv, started, note))
    print(summary(total, rows), flush=True)
    problems = failed(total)
    for problem in problems:
        print(f"FOUND {problem}", flush=True)
    if problems:
        print(f"the server's log, schemathesis' output and reports: {folder}", flush=True)
        return 1
    shutil.rmtree(folder)  # its event report alone is some 100 MB
    return 0
