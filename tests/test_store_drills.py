"""Drills of the SQLite job store under a live server (uvicorn in its own process, the fake
solver): its pages overwritten in place, its header overwritten, its write-ahead log
deleted, each while the server runs, then kill -9 and a restart. No submit is accepted
after the damage; every job accepted before it is still there after the restart, or, when
the start refuses the damaged store, after `undertow restore` of the backup taken before
(the jobs accepted since that backup went with the damage: back up often). And the
backups themselves: a damaged store never overwrites a good backup, a store in use is
never replaced."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from service_fixtures import two_link_scene
from test_job_faults import fake_server, post, wait_gone
from test_store_integrity import overwrite

from app.cli import main
from app.store import SqliteJobStore
from testbed.service import LiveServer, wait_final


def pages(db: Path) -> None:
    """Every page of the main file after the first, in place."""
    overwrite(db, 4096)


def header(db: Path) -> None:
    """SQLite's header, the first 100 bytes of the file, in place."""
    overwrite(db, 0, 100)


def wal(db: Path) -> None:
    """The write-ahead log, deleted."""
    os.unlink(f"{db}-wal")


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "pages": (pages, "store-damaged"), "header": (header, "store-damaged"),
    "wal": (wal, "unavailable")}
"""Each damage and the problem type of the 503 that answers submits after it."""


def undertow(capsys, *argv: str) -> tuple[int, str]:
    """Run `undertow` in this process (which holds no connection to the store); its exit
    status and what it wrote."""
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out + err


def run_jobs(api: httpx.Client, count: int) -> list[str]:
    """Submit `count` plans and wait for them to succeed; their ids."""
    ids = [post(api) for _ in range(count)]
    assert [wait_final(api, job_id)["status"] for job_id in ids] == ["succeeded"] * count
    return ids


def refused_after(api: httpx.Client, kind: str) -> None:
    """Every submit, /healthz and /metrics answer 503 problems of type `kind` (with
    Retry-After only where waiting may mend it): no 202 after the damage."""
    for _ in range(5):
        for method, path, body in (("post", "/v1/plans", two_link_scene()),
                                   ("post", "/v1/batches", {"base": two_link_scene(),
                                                            "overrides": [{}]}),
                                   ("get", "/healthz", None), ("get", "/metrics", None)):
            r = api.request(method, path, json=body)
            assert r.status_code == 503, (path, r.text)
            assert r.headers["content-type"] == "application/problem+json"
            assert r.json()["type"] == f"urn:undertow:problem:{kind}", r.json()
            assert ("retry-after" in r.headers) == (kind == "unavailable")


def kill_9(live: LiveServer) -> None:
    """SIGKILL the server and its workers: nothing shuts down cleanly."""
    assert live.proc is not None
    os.killpg(live.proc.pid, signal.SIGKILL)
    live.proc.wait(30)
    wait_gone(live.proc.pid)


def listed(api: httpx.Client) -> set[str]:
    """The ids of every job the server knows."""
    return {job["id"] for job in api.get("/v1/plans?limit=100").json()["items"]}


@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_damage_under_a_running_server_accepts_nothing_after_it_and_loses_nothing(
        tmp_path, capsys, damage):
    harm, kind = DAMAGES[damage]
    live, backup = fake_server(tmp_path), tmp_path / "backup.sqlite3"
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        backed_up = run_jobs(api, 4)
    assert undertow(capsys, "backup", "--db", str(live.db_path), str(backup))[0] == 0
    with live, httpx.Client(base_url=live.url, timeout=30) as api:  # pages in the main file
        since = run_jobs(api, 3)
        harm(live.db_path)
        refused_after(api, kind)
        kill_9(live)
    if damage == "pages":  # the start refuses the store, naming what to do
        assert live.refused() != 0
        said = live.log.read_text()
        assert f"the job store {live.db_path} failed its integrity check" in said
        assert "`undertow restore BACKUP`" in said and "Traceback" not in said
        code, out = undertow(capsys, "restore", "--db", str(live.db_path), str(backup))
        assert code == 0 and "restored 4 jobs" in out, out
        kept = backed_up  # the jobs accepted since the backup went with the damage
    else:
        kept = backed_up + since
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        assert listed(api) == set(kept)  # every one kept, none accepted after the damage
        assert {wait_final(api, job_id)["status"] for job_id in kept} == {"succeeded"}
        assert wait_final(api, post(api))["status"] == "succeeded"


def test_a_damaged_store_never_overwrites_a_good_backup(tmp_path, capsys):
    db, backup = tmp_path / "jobs.sqlite3", tmp_path / "backup.sqlite3"
    store = SqliteJobStore(db)
    for k in range(60):
        store.create(f"j{k}", {"pad": "x" * 500}, "host")
    store.checkpoint(final=True)
    store.close()
    code, out = undertow(capsys, "backup", "--db", str(db), str(backup))
    assert (code, out.split(" (")[0]) == (0, "backed up 60 jobs"), out
    good = backup.read_bytes()
    pages(db)
    code, out = undertow(capsys, "backup", "--db", str(db), str(backup))
    assert code == 3 and "it is damaged: keep the backups you have" in out, out
    assert backup.read_bytes() == good and not Path(f"{backup}.partial").exists()
    code, out = undertow(capsys, "restore", "--db", str(db), str(db))  # a damaged "backup"
    assert code == 3 and "failed its integrity check" in out, out


def test_a_store_in_use_is_not_replaced(tmp_path, capsys):
    db, backup = tmp_path / "jobs.sqlite3", tmp_path / "backup.sqlite3"
    store = SqliteJobStore(db)
    store.create("before", {}, "host")
    assert undertow(capsys, "backup", "--db", str(db), str(backup))[0] == 0
    store.create("after", {}, "host")
    code, out = undertow(capsys, "restore", "--db", str(db), str(backup))
    assert code == 3 and f"the job store {db} is in use" in out, out
    assert store.get("after") is not None
    store.close()
    code, out = undertow(capsys, "restore", "--db", str(db), str(backup))
    assert code == 0 and "restored 1 jobs" in out, out
    again = SqliteJobStore(db)
    assert again.get("before") is not None and again.get("after") is None
    assert [p.name for p in tmp_path.glob("jobs.sqlite3.before-restore-*")], "nothing aside"
