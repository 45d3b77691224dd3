"""Process and store faults against a live server: does any accepted plan job get lost?

Each probe starts uvicorn (`app.main:app`, 2 solver workers) on 127.0.0.1 with a fresh
store and the fake solve function of testbed/fake_solvers.py (20 ms a fake iteration),
submits plan jobs, applies its fault, restarts the server where the fault needs it, and
follows every job the server accepted (202) to its end:

- kill -9 of the server process while jobs run and others wait (its workers are left to
  notice), and of the server with all its workers at once (as `docker kill` does);
- SIGTERM of the server while jobs run and others wait;
- SIGKILL of one solver worker mid-solve;
- the store file deleted while the server runs;
- the store file damaged (pages overwritten) while the server runs;
- the `-wal` file deleted, or overwritten, after a clean shutdown;
- the `-wal` and `-shm` files deleted after kill -9 of the server and its workers (the loss
  the checkpoint interval bounds);
- the `-wal` file deleted, and the store file overwritten in place, while the server runs.

With `--postgres`, the same questions on a throwaway PostgreSQL server (`testbed.postgres`)
shared by one API-only server and two worker nodes (`undertow worker`), 4 plans running
and 6 queued at each fault: kill -9 of one node's main process alone, of one solver
process, of a whole node (its process group), SIGTERM of a node, and `pg_ctl restart -m
fast`. Every accepted plan must succeed, none with an infrastructure failure for a
restart; *requeue* is how long the plan that lost its worker stayed `running` afterwards.

A job counts as lost when the server no longer knows it (404) or when it is still queued or
running after the recovery's deadline. Writes the section "Reliability: process and store
faults" of docs/stability.md and bench/results/faults.csv.

    python -m bench faults [--tries 5] [--postgres] [--probes N]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import httpx

from bench import harness
from bench.scenes import request
from testbed.probes import worker_pids
from testbed.service import LiveServer

SECTION = "Reliability: process and store faults"
LONG = 150  # fake iterations of a job meant to be running at the fault (3 s)
SETTLE = 60.0  # [s] for every job to end after the recovery
FINAL = ("succeeded", "failed", "cancelled")


def server(folder: Path) -> LiveServer:
    """The server of a probe: 2 workers running the fake solve function, its store in `folder`."""
    return LiveServer(folder / "jobs.sqlite3", UNDERTOW_WORKERS="2", UNDERTOW_MAX_QUEUED="16",
                      UNDERTOW_SOLVE_FUNCTION="testbed.fake_solvers:fake_plan")


def scene(iterations: int = LONG) -> dict:
    """A plan request the fake solver takes `iterations` x 20 ms over, then converges."""
    return request("under-2", N=10, solver={"max_iter": iterations})


def submit(http: httpx.Client, count: int, iterations: int = LONG) -> list[str]:
    """Ids of the jobs the server accepted."""
    ids = []
    for _ in range(count):
        r = http.post("/v1/plans", json=scene(iterations))
        if r.status_code == 202:
            ids.append(r.json()["id"])
    return ids


def wait_running(http: httpx.Client, count: int, timeout: float = 30.0) -> list[str]:
    """Until `count` jobs run; their ids."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        items = http.get("/v1/plans?status=running").json()["items"]
        if len(items) >= count:
            return [j["id"] for j in items]
        time.sleep(0.05)
    raise RuntimeError(f"{count} jobs did not start in {timeout} s")


def wait_gone(group: int, timeout: float = 30.0) -> None:
    """Until no process of the server's process group (its workers) is left."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    raise RuntimeError("a process of the server outlived it")


def settle(http: httpx.Client, ids: list[str]) -> Counter:
    """What became of each job: its final status ("interrupted" for the error of that
    name, "worker died" for a dead worker's job), or "lost"."""
    deadline, outcomes = time.monotonic() + SETTLE, Counter[str]()
    pending = list(ids)
    while pending and time.monotonic() < deadline:
        job = http.get(f"/v1/plans/{pending[0]}")
        if job.status_code == 404:
            outcomes["lost"] += 1
        elif job.json()["status"] in FINAL:
            outcomes[_kind(job.json())] += 1
        else:
            time.sleep(0.05)
            continue
        pending.pop(0)
    outcomes["lost"] += len(pending)  # still queued or running
    return outcomes


COUNTED = ("accepted", "succeeded", "interrupted", "worker died", "failed", "queued kept",
           "lost")
"""Per-try numbers summed over the tries; every other field of a probe is a note."""


def _kind(job: dict) -> str:
    error = job["error"] or ""
    if error == "interrupted":
        return "interrupted"
    if error.startswith("the worker process died"):
        return "worker died"
    return job["status"]


def _process(live: LiveServer) -> subprocess.Popen:
    """The server's process (it has been started)."""
    assert live.proc is not None, "the server has not been started"
    return live.proc


def kill_group(live: LiveServer) -> None:
    """SIGKILL the server and every process it started, at once."""
    os.killpg(_process(live).pid, signal.SIGKILL)
    _process(live).wait()


def _stopped_then_restarted(folder: Path, sig: int, group: bool = False) -> dict:
    live = server(folder)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 6)
        running = wait_running(http, 2)
        if group:
            kill_group(live)
        else:
            live.stop(sig)
        wait_gone(_process(live).pid)
    store = _store(folder)
    queued = [j for j in ids if j not in running]
    stayed = sum(store.get(j).status == "queued" and store.get(j).started is None
                 for j in queued)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        outcome = settle(http, ids)
    expected = Counter({"succeeded": 6})  # the running two requeued or released
    return {"accepted": len(ids), **outcome, "queued kept": stayed,
            "ok": outcome == expected and (sig != signal.SIGTERM or stayed == 4)}


def kill_9_server(folder: Path) -> dict:
    """2 jobs running, 4 queued; SIGKILL of the server process alone, then a restart."""
    return _stopped_then_restarted(folder, signal.SIGKILL)


def kill_9_all(folder: Path) -> dict:
    """2 jobs running, 4 queued; SIGKILL of the server and its workers, then a restart."""
    return _stopped_then_restarted(folder, signal.SIGKILL, group=True)


def sigterm_server(folder: Path) -> dict:
    """2 jobs running, 4 queued; SIGTERM, then a restart: the queued ones must still be
    queued (never started) and run after the restart."""
    return _stopped_then_restarted(folder, signal.SIGTERM)


def kill_worker(folder: Path) -> dict:
    """2 jobs running, 2 queued; SIGKILL of one worker: its job is requeued and succeeds."""
    live = server(folder)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 4)
        wait_running(http, 2)
        os.kill(worker_pids(_process(live).pid)[0], signal.SIGKILL)
        outcome = settle(http, ids)
        healthy = http.get("/healthz").status_code
    return {"accepted": len(ids), **outcome, "healthz after": f"{healthy}",
            "ok": outcome == Counter({"succeeded": 4}) and healthy == 200}


def store_deleted(folder: Path) -> dict:
    """2 jobs running, 2 queued; the store file deleted: health and new plans answer 503
    (the jobs already accepted went with the file)."""
    live = server(folder)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 4)
        wait_running(http, 2)
        os.unlink(folder / "jobs.sqlite3")
        healthy = http.get("/healthz").status_code
        after = [http.post("/v1/plans", json=scene()).status_code for _ in range(3)]
    return {"accepted": len(ids), "went with the file": f"{len(ids)} jobs",
            "healthz after": f"{healthy}", "new plans": "/".join(map(str, sorted(set(after)))),
            "ok": healthy == 503 and set(after) == {503}}


def store_damaged(folder: Path) -> dict:
    """8 finished jobs, moved into the database file by a clean restart; the file's pages
    overwritten while the server runs; a restart must refuse it with the integrity
    message (the jobs stay in the damaged file, for recovery)."""
    live = server(folder)
    path = folder / "jobs.sqlite3"
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 8, iterations=3)
        settle(http, ids)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        data = bytearray(path.read_bytes())
        data[4096:] = b"\xa5" * (len(data) - 4096)  # every page after the header's
        path.write_bytes(bytes(data))
        answers = Counter(http.get(f"/v1/plans/{j}").status_code for j in ids)
        healthy = http.get("/healthz").status_code
    try:
        live.start()
        refused = False
    except AssertionError:
        refused = "failed its integrity check" in live.log.read_text()
    finally:
        live.stop()
    return {"accepted": len(ids), "reads after": _answers(answers),
            "healthz after": f"{healthy}", "restart refused": refused, "ok": refused}


def wal_deleted_while_running(folder: Path) -> dict:
    """4 jobs accepted (2 running); the -wal file deleted under the running server: new
    plans and /healthz answer 503; kill -9 of everything and a restart: every accepted
    job is still known."""
    live = server(folder)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 4)
        wait_running(http, 2)
        (folder / "jobs.sqlite3-wal").unlink()
        healthy = http.get("/healthz").status_code
        after = [http.post("/v1/plans", json=scene()).status_code for _ in range(3)]
        kill_group(live)
        wait_gone(_process(live).pid)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        outcome = settle(http, ids)
    return {"accepted": len(ids), **outcome, "healthz after": f"{healthy}",
            "new plans": "/".join(map(str, sorted(set(after)))),
            "ok": healthy == 503 and set(after) == {503} and outcome["lost"] == 0}


def overwritten_while_running(folder: Path) -> dict:
    """8 finished jobs in the database file; the file overwritten in place (the same
    inode) while the server runs: new plans and /healthz answer 503."""
    live = server(folder)
    path = folder / "jobs.sqlite3"
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 8, iterations=3)
        settle(http, ids)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        with open(path, "r+b") as file:
            file.write(b"\xa5" * path.stat().st_size)
        healthy = http.get("/healthz").status_code
        after = [http.post("/v1/plans", json=scene()).status_code for _ in range(3)]
    return {"accepted": len(ids), "healthz after": f"{healthy}",
            "new plans": "/".join(map(str, sorted(set(after)))),
            "ok": healthy == 503 and set(after) == {503}}


def _answers(counts: Counter) -> str:
    return ", ".join(f"{count} x {status}" for status, count in sorted(counts.items()))


def _after_shutdown(folder: Path, damage: Callable[[Path], None], clean: bool) -> dict:
    live = server(folder)
    with live, httpx.Client(base_url=live.url, timeout=30) as http:
        ids = submit(http, 7, iterations=3)
        settle(http, ids)
        if clean:
            live.stop(signal.SIGTERM)
        else:
            kill_group(live)
        wait_gone(_process(live).pid)
    damage(folder)
    try:
        with live, httpx.Client(base_url=live.url, timeout=30) as http:
            outcome = settle(http, ids)
        refused = False
    except AssertionError:
        outcome, refused = Counter(), "failed its integrity check" in live.log.read_text()
    return {"accepted": len(ids), **outcome, "restart refused": refused}


def _delete(*suffixes: str) -> Callable[[Path], None]:
    def damage(folder: Path) -> None:
        for suffix in suffixes:
            (folder / f"jobs.sqlite3{suffix}").unlink(missing_ok=True)
    return damage


def _overwrite_wal(folder: Path) -> None:
    (folder / "jobs.sqlite3-wal").write_bytes(b"\x5a" * 65536)


def wal_deleted(folder: Path) -> dict:
    """7 finished jobs; SIGTERM; the -wal file deleted; a restart finds all 7."""
    row = _after_shutdown(folder, _delete("-wal"), clean=True)
    return {**row, "ok": row.get("succeeded") == 7}


def wal_overwritten(folder: Path) -> dict:
    """7 finished jobs; SIGTERM; the -wal file overwritten with garbage; all 7 found."""
    row = _after_shutdown(folder, _overwrite_wal, clean=True)
    return {**row, "ok": row.get("succeeded") == 7}


def wal_deleted_after_kill(folder: Path) -> dict:
    """7 finished jobs, younger than the checkpoint interval; kill -9 of the server and
    its workers; -wal and -shm deleted: what the write-ahead log still held is gone
    (reported, not a pass/fail)."""
    return {**_after_shutdown(folder, _delete("-wal", "-shm"), clean=False), "ok": None}


def _store(folder: Path):
    from app.store import SqliteJobStore

    return SqliteJobStore(folder / "jobs.sqlite3")


PROBES: list[tuple[str, Callable[[Path], dict], str]] = [
    ("kill -9 of the server, 2 running + 4 queued", kill_9_server, "process"),
    ("kill -9 of the server and its workers, 2 running + 4 queued", kill_9_all, "process"),
    ("SIGTERM of the server, 2 running + 4 queued", sigterm_server, "process"),
    ("SIGKILL of one worker mid-solve, 2 running + 2 queued", kill_worker, "process"),
    ("store file deleted while running", store_deleted, "store"),
    ("store file damaged while running", store_damaged, "store"),
    ("-wal deleted after a clean shutdown", wal_deleted, "store"),
    ("-wal overwritten after a clean shutdown", wal_overwritten, "store"),
    ("-wal deleted while the server runs, then kill -9 and restart",
     wal_deleted_while_running, "store"),
    ("store file overwritten in place while the server runs", overwritten_while_running,
     "store"),
    ("-wal and -shm deleted after kill -9 of server and workers", wal_deleted_after_kill,
     "store"),
]
COLUMNS = [("probe", "fault"), ("tries", "tries"), ("accepted", "jobs accepted"),
           ("succeeded", "succeeded"), ("interrupted", "interrupted"),
           ("worker died", "failed: worker died"), ("failed", "failed: other"),
           ("queued kept", "queued kept queued"),
           ("lost", "lost"), ("other", "other outcome"), ("ok", "as documented")]


def run(probe: Callable[[Path], dict], tries: int) -> dict:
    """The probe `tries` times, each on a fresh store; counts summed."""
    totals: Counter = Counter()
    notes, oks = [], []
    for _ in range(tries):
        with tempfile.TemporaryDirectory() as folder:
            row = probe(Path(folder))
        oks.append(row.pop("ok"))
        for key, value in row.items():
            if key in COUNTED:
                totals[key] += value
            else:
                notes.append(f"{key}: {value}")
    note = "; ".join(sorted(set(notes)))
    verdict = ("–" if oks[0] is None else f"{sum(oks)} of {tries}")
    return {"tries": tries, **totals, "other": note or "–", "ok": verdict}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench faults", description=__doc__)
    parser.add_argument("--tries", type=int, default=5)
    parser.add_argument("--postgres", action="store_true",
                        help="the PostgreSQL probes (a server, two worker nodes) instead")
    parser.add_argument("--probes", type=int, default=None,
                        help="run the first this many probes (default all)")
    args = parser.parse_args(argv)
    if args.postgres:
        from bench import faults_postgres

        return faults_postgres.main(argv, args.tries, args.probes)
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for name, probe, kind in PROBES[:args.probes]:
        tries = args.tries if kind == "process" else max(1, args.tries // 2)
        rows.append({"probe": name, **run(probe, tries)})
        print(rows[-1], flush=True)
    lost = sum(r.get("lost", 0) for r in rows[:-1])
    text = "\n\n".join([
        ("A live uvicorn (`app.main:app`, 2 solver workers, `testbed.service.LiveServer`) on "
         "127.0.0.1 with a fresh store per try and the fake solve function of "
         "`testbed/fake_solvers.py` (20 ms a fake iteration; running jobs take 3 s). Every "
         "job the server accepted (202) is followed to its end after the recovery; *lost* "
         "counts jobs the server no longer knows or that stay queued or running after "
         f"{SETTLE:g} s. *As documented*: running jobs of a stopped or killed server are "
         "requeued (released on SIGTERM) and succeed after the restart, queued ones stay "
         "queued and run after it, a dead worker's job is requeued and succeeds, a deleted "
         "store, a deleted `-wal` or a file overwritten in place answers 503 to `/healthz` "
         "and new plans (and a deleted `-wal` loses no accepted job), a damaged one is "
         "refused at start with the integrity message, a write-ahead log lost after a clean "
         f"shutdown costs nothing. Load average at the end: "
         f"{harness.load()}."),
        harness.table(rows, COLUMNS),
        (f"Jobs lost over the documented probes: {lost}. The last row is the residual "
         "risk, not a defect: when every process is killed at once, jobs written within "
         "the last checkpoint interval (60 s of writes) live only in the `-wal` file, and "
         "deleting it together with `-shm` loses them. (When only the server dies, its "
         "workers close the store as they leave, which moves the log into the database "
         "file.)"),
        f"Rows: `bench/results/faults.csv`. {harness.manifest('faults', argv, started, note)}"])
    print(text)
    harness.write_csv(harness.RESULTS / "faults.csv",
                      [{k: r.get(k) for k, _ in COLUMNS} for r in rows])
    harness.write_section(harness.DOCS / "stability.md", SECTION, text)
    return 0
