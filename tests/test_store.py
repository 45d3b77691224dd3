"""SQLite job store: persistence, WAL, conditional transitions, claims and leases,
integrity, migrations, a store deleted under a running service, writers in two processes."""

from __future__ import annotations

import multiprocessing
import os
import pickle
import sqlite3
import time

import pytest

from app.store import (
    BUILDING,
    INTERRUPTED,
    SqliteJobStore,
    StoreDamaged,
    StoreUnavailable,
)
from app.store.sqlite import SCHEMA_VERSION

SCENE = {"robot": {"links": []}, "note": "stored verbatim"}


@pytest.fixture
def store(tmp_path) -> SqliteJobStore:
    s = SqliteJobStore(tmp_path / "jobs" / "db.sqlite3")
    yield s
    s.close()


def test_wal_mode_is_on(store):
    assert store.journal_mode == "wal"


def claim(store: SqliteJobStore, owner: str = "host", worker: str = "w1",
          lease: float = 60.0) -> str | None:
    """Claim the oldest queued job of `owner`; its id."""
    record = store.claim(owner, worker, time.time() + lease)
    return None if record is None else record.id


def test_a_job_survives_reopening_the_file(store, tmp_path):
    store.create("a", SCENE, "host")
    assert claim(store) == "a"
    assert store.report_progress("a", {"iteration": 3, "objective": 1.5})
    assert store.finish("a", "succeeded", {"t": [0.0, 1.0]}, None)
    store.close()
    again = SqliteJobStore(tmp_path / "jobs" / "db.sqlite3")
    record = again.get("a")
    assert (record.status, record.scene, record.plan, record.progress) == (
        "succeeded", SCENE, {"t": [0.0, 1.0]}, {"iteration": 3, "objective": 1.5})
    assert record.created <= record.started <= record.finished


def test_transitions_are_conditional_on_the_status(store):
    store.create("a", SCENE, "host")
    assert not store.finish("a", "succeeded", None, None)  # not running yet
    assert claim(store) == "a"
    assert claim(store) is None  # already claimed
    assert store.finish("a", "failed", None, "boom")
    assert not store.finish("a", "succeeded", None, None)  # a verdict is final
    assert not store.report_progress("a", {"iteration": 9})
    assert not store.fail("a", "late")
    assert store.get("a").error == "boom"


def test_cancel_queued_is_immediate_and_running_is_flagged(store):
    store.create("q", SCENE, "host")
    assert store.request_cancel("q").status == "cancelled"
    assert claim(store) is None
    store.create("r", SCENE, "host")
    claim(store)
    assert store.report_progress("r", {"iteration": 0})
    flagged = store.request_cancel("r")
    assert (flagged.status, flagged.cancel_requested) == ("running", True)
    assert not store.report_progress("r", {"iteration": 1})  # the worker is told to stop
    assert store.request_cancel("missing") is None


def test_interrupt_marks_only_the_owners_running_jobs(store):
    for job_id, owner in (("mine", "a"), ("other", "b"), ("waiting", "a")):
        store.create(job_id, SCENE, owner)
    assert claim(store, "a") == "mine"
    assert claim(store, "b") == "other"
    assert store.interrupt("a") == ["mine"]
    mine = store.get("mine")
    assert (mine.status, mine.error) == ("failed", INTERRUPTED)
    assert store.get("other").status == "running"
    assert store.get("waiting").status == "queued"


def test_claims_take_the_oldest_queued_job_of_the_owner_and_say_building(store):
    for job_id, owner in (("a1", "a"), ("b1", "b"), ("a2", "a")):
        store.create(job_id, SCENE, owner)
    record = store.claim("a", "worker-7", time.time() + 60)
    assert (record.id, record.status, record.worker, record.progress) == (
        "a1", "running", "worker-7", BUILDING)
    assert record.started is not None
    assert claim(store, None) == "b1"  # None claims anyone's
    assert claim(store, "a") == "a2"
    assert claim(store, "a") is None


def test_a_released_claim_is_queued_again_unless_cancelled_meanwhile(store):
    store.create("a", SCENE, "host")
    store.create("b", SCENE, "host")
    assert claim(store, worker="w1") == "a"
    assert not store.release("a", "someone-else")
    assert store.release("a", "w1")
    again = store.get("a")
    assert (again.status, again.worker, again.started, again.progress) == (
        "queued", None, None, None)
    assert claim(store, worker="w2") == "a"
    store.request_cancel("a")
    assert store.release("a", "w2")
    assert store.get("a").status == "cancelled"


def test_the_limit_counts_the_owners_unfinished_jobs(store):
    assert store.create("a", SCENE, "host", limit=2) is not None
    assert store.create("b", SCENE, "host", limit=2) is not None
    assert store.create("c", SCENE, "host", limit=2) is None
    assert store.get("c") is None
    assert store.create("x", SCENE, "other", limit=2) is not None  # another owner's count
    store.request_cancel("a")  # a cancelled job is finished: its place is free
    assert store.create("c", SCENE, "host", limit=2) is not None
    claim(store)
    assert store.create("d", SCENE, "host", limit=2) is None  # running counts too


def test_leases_are_renewed_with_cancel_flags_and_expire(store):
    for job_id in ("a", "b", "c"):
        store.create(job_id, SCENE, "host")
    claim(store, worker="w1", lease=-1.0)  # a: lease already over
    claim(store, worker="w2", lease=-1.0)  # b
    claim(store, worker="w3", lease=-1.0)  # c
    store.request_cancel("b")
    assert store.renew(["w1", "w2"], time.time() + 60) == {"a": False, "b": True}
    assert store.renew([], time.time() + 60) == {}
    assert store.expire(time.time()) == ["c"]
    c = store.get("c")
    assert (c.status, c.error) == ("failed", INTERRUPTED)
    assert store.get("a").status == "running"


def test_fail_claimed_fails_only_the_workers_running_jobs(store):
    for job_id in ("a", "b", "c"):
        store.create(job_id, SCENE, "host")
    claim(store, worker="w1")
    claim(store, worker="w2")
    assert store.fail_claimed("w1", "died") == ["a"]
    assert (store.get("a").status, store.get("a").error) == ("failed", "died")
    assert store.get("b").status == "running" and store.get("c").status == "queued"


def test_list_is_newest_first_and_filters_by_status(store):
    for k in range(5):
        store.create(f"j{k}", SCENE, "host")
    assert claim(store) == "j0"
    assert [r.id for r in store.list(limit=3)] == ["j4", "j3", "j2"]
    assert [r.id for r in store.list(limit=3, offset=3)] == ["j1", "j0"]
    assert [r.id for r in store.list(status="running")] == ["j0"]
    assert store.count_by_status() == {"queued": 4, "running": 1, "succeeded": 0,
                                       "failed": 0, "cancelled": 0}


def test_the_store_pickles_as_its_path(store):
    clone = pickle.loads(pickle.dumps(store))
    store.create("a", SCENE, "host")
    assert clone.get("a").scene == SCENE


def _writer(store: SqliteJobStore, prefix: str, count: int, start) -> None:
    start.wait()
    for k in range(count):
        job_id = f"{prefix}{k}"
        store.create(job_id, SCENE, prefix)
        assert store.claim(prefix, prefix, time.time() + 60).id == job_id
        store.report_progress(job_id, {"iteration": k})
        store.finish(job_id, "succeeded", {"k": k}, None)


def test_two_processes_write_at_once_without_losing_a_job(store):
    ctx = multiprocessing.get_context("spawn")
    start = ctx.Event()
    count = 150
    procs = [ctx.Process(target=_writer, args=(store, p, count, start)) for p in "ab"]
    for p in procs:
        p.start()
    start.set()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert store.count_by_status()["succeeded"] == 2 * count
    assert {store.get(f"b{k}").plan["k"] for k in range(count)} == set(range(count))


def test_a_final_checkpoint_leaves_every_job_in_the_main_file(tmp_path):
    path = tmp_path / "db.sqlite3"
    store, reader = SqliteJobStore(path), SqliteJobStore(path)  # as two threads of a server
    for k in range(7):
        store.create(f"j{k}", SCENE, "host")
    assert reader.get("j6") is not None
    store.checkpoint(final=True)
    wal = tmp_path / "db.sqlite3-wal"
    assert wal.stat().st_size == 0  # though a connection stays open
    copy = tmp_path / "copy.sqlite3"  # the main file alone
    copy.write_bytes(path.read_bytes())
    assert SqliteJobStore(copy).count_by_status()["queued"] == 7


def test_writes_checkpoint_the_log_every_interval(tmp_path):
    store = SqliteJobStore(tmp_path / "db.sqlite3", checkpoint_interval=0.0)
    for k in range(7):
        store.create(f"j{k}", SCENE, "host")
    copy = tmp_path / "copy.sqlite3"  # the main file alone, as if the log were lost
    copy.write_bytes((tmp_path / "db.sqlite3").read_bytes())
    assert SqliteJobStore(copy).count_by_status()["queued"] == 7


def filled(path, jobs: int) -> SqliteJobStore:
    """A store of `jobs` jobs of 500 bytes each, all in its main file."""
    store = SqliteJobStore(path)
    for k in range(jobs):
        store.create(f"j{k}", {"pad": "x" * 500}, "host")
    store.checkpoint(final=True)
    return store


def overwrite(path, start: int, end: int | None = None) -> None:
    """Overwrite the file's bytes from `start` to `end` (its end) with garbage."""
    data = bytearray(path.read_bytes())
    end = len(data) if end is None else end
    data[start:end] = b"\xa5" * (end - start)
    path.write_bytes(bytes(data))


def test_a_damaged_store_is_refused_with_a_clear_message(tmp_path):
    path = tmp_path / "db.sqlite3"
    filled(path, 200).close()
    overwrite(path, 4096 * 2, 4096 * 3)  # one page of the table's b-tree
    with pytest.raises(StoreDamaged, match=r"failed its integrity check .*refusing to start"):
        SqliteJobStore(path)
    path.write_bytes(b"not a database at all" * 100)
    with pytest.raises(StoreDamaged, match="file is not a database"):
        SqliteJobStore(path)


def test_a_store_of_the_first_schema_is_migrated(tmp_path):
    path = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE jobs (id TEXT PRIMARY KEY, status TEXT NOT NULL, scene TEXT "
                 "NOT NULL, progress TEXT, plan TEXT, error TEXT, cancel_requested INTEGER "
                 "NOT NULL DEFAULT 0, owner TEXT NOT NULL, created REAL NOT NULL, started "
                 "REAL, finished REAL)")
    conn.execute("INSERT INTO jobs (id, status, scene, owner, created) "
                 "VALUES ('old', 'queued', '{}', 'host', 1.0)")
    conn.commit()
    conn.close()
    store = SqliteJobStore(path)
    assert store.get("old").worker is None
    assert claim(store) == "old" and store.get("old").worker == "w1"
    assert store.finish("old", "succeeded", {"plan": 1}, None, {"x": [1.0]})
    assert store.solution("old") == {"x": [1.0]}
    assert store._rows("PRAGMA user_version")[0][0] == SCHEMA_VERSION == 3


def test_a_store_deleted_under_the_service_is_unavailable_not_recreated(store):
    store.create("a", SCENE, "host")
    store.check()
    os.unlink(store.path)
    with pytest.raises(StoreUnavailable, match="was deleted or replaced"):
        store.check()
    with pytest.raises(StoreUnavailable):
        store.create("b", SCENE, "host")
    assert not os.path.exists(store.path)


def test_check_reads_the_file_not_a_cache(tmp_path):
    path = tmp_path / "db.sqlite3"
    store = filled(path, 50)
    store.check()
    assert store.get("j49") is not None  # this connection now holds the pages in its cache
    overwrite(path, 4096)  # every page after the header's
    with pytest.raises(StoreUnavailable, match="malformed"):
        store.check()
