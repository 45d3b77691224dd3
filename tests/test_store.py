"""Job stores, each test against both stores (SQLite and a throwaway PostgreSQL server)
unless it is about one of them: persistence, conditional transitions, claims and leases,
requeues, batches, migrations, writers in two processes; SQLite's WAL, checkpoints,
integrity and a file deleted under a running service; PostgreSQL's concurrent claims and
an unreachable server."""

from __future__ import annotations

import multiprocessing
import os
import pickle
import sqlite3
import threading
import time

import psycopg
import pytest

from app.store import (
    BUILDING,
    INTERRUPTED,
    JobStore,
    SqliteJobStore,
    StoreDamaged,
    StoreUnavailable,
)
from app.store import postgres as pg_store
from app.store import sqlite as sqlite_store
from app.store.postgres import PostgresJobStore

SCENE = {"robot": {"links": []}, "note": "stored verbatim", "x": 0.1, "tiny": 1e-300}


@pytest.fixture
def sqlite(tmp_path) -> SqliteJobStore:
    """A SQLite store, for what only a file has (WAL, checkpoints, damage)."""
    s = SqliteJobStore(tmp_path / "jobs" / "db.sqlite3")
    yield s
    s.close()


def reopen(store: JobStore) -> JobStore:
    """A new store object on the same file or database."""
    if isinstance(store, SqliteJobStore):
        return SqliteJobStore(store.path)
    return PostgresJobStore(store.url)


def test_both_stores_have_had_the_same_migrations():
    assert sqlite_store.SCHEMA_VERSION == pg_store.SCHEMA_VERSION == 4


def test_wal_mode_is_on(sqlite):
    assert sqlite.journal_mode == "wal"


def claim(store: JobStore, owner: str | None = "host", worker: str = "w1",
          lease: float = 60.0) -> str | None:
    """Claim the oldest queued job of `owner`; its id."""
    record = store.claim(owner, worker, time.time() + lease)
    return None if record is None else record.id


def test_a_job_survives_reopening_the_store(store):
    store.create("a", SCENE, "host")
    assert claim(store) == "a"
    assert store.report_progress("a", {"iteration": 3, "objective": 1.5})
    assert store.finish("a", "succeeded", {"t": [0.0, 1.0]}, None)
    store.close()
    again = reopen(store)
    record = again.get("a")
    assert (record.status, record.scene, record.plan, record.progress) == (
        "succeeded", SCENE, {"t": [0.0, 1.0]}, {"iteration": 3, "objective": 1.5})
    assert record.created <= record.started <= record.finished
    again.close()


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


def test_interrupt_marks_only_the_owners_running_jobs_held_by_its_workers(store):
    for job_id, owner in (("mine", "a"), ("other", "b"), ("waiting", "a"), ("remote", "a")):
        store.create(job_id, SCENE, owner)
    assert claim(store, "a", worker="a/0/x") == "mine"
    assert claim(store, "b", worker="b/0/x") == "other"
    assert claim(store, "a", worker="ab/0/x") == "waiting"  # another instance's worker
    store.create("last", SCENE, "a")
    assert claim(store, "a", worker="elsewhere/0/x") == "remote"
    assert store.interrupt("a") == ["mine"]
    mine = store.get("mine")
    assert (mine.status, mine.error) == ("failed", INTERRUPTED)
    assert {store.get(j).status for j in ("other", "waiting", "remote")} == {"running"}
    assert store.get("last").status == "queued"


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
    assert store.expire(time.time()) == {"c": "queued"}  # requeued: its first claim
    c = store.get("c")
    assert (c.status, c.worker, c.started, c.progress, c.error) == (
        "queued", None, None, None, None)
    assert store.get("a").status == "running"


def test_an_expired_job_is_requeued_once_then_interrupted_or_cancelled(store):
    store.create("a", SCENE, "host")
    store.create("b", SCENE, "host")
    assert claim(store, worker="w1", lease=-1.0) == "a"
    assert store.expire(time.time()) == {"a": "queued"}
    assert not store.finish("a", "succeeded", None, None, worker="w1")  # w1 lost it
    assert claim(store, worker="w2", lease=-1.0) == "a"  # its second claim
    assert not store.report_progress("a", {"iteration": 1}, worker="w1")
    assert store.report_progress("a", {"iteration": 1}, worker="w2")
    assert store.expire(time.time()) == {"a": "failed"}
    a = store.get("a")
    assert (a.status, a.error, a.worker) == ("failed", INTERRUPTED, "w2")
    assert claim(store, worker="w3", lease=-1.0) == "b"
    store.request_cancel("b")
    assert store.expire(time.time()) == {"b": "cancelled"}
    assert store.get("b").error == "cancelled on request"
    store.create("c", SCENE, "host")  # a released claim does not count
    assert claim(store, worker="w4", lease=-1.0) == "c"
    assert store.release("c", "w4")
    assert claim(store, worker="w5", lease=-1.0) == "c"
    assert store.expire(time.time()) == {"c": "queued"}


def test_a_verdict_is_written_only_by_the_worker_holding_the_job(store):
    store.create("a", SCENE, "host")
    claim(store, worker="w1")
    assert not store.finish("a", "succeeded", {"k": 1}, None, worker="w2")
    assert store.finish("a", "succeeded", {"k": 2}, None, worker="w1")
    assert store.get("a").plan == {"k": 2}


def test_a_batch_is_stored_whole_within_the_limit_and_summarised(store):
    members = [(f"b-{k:03d}", {**SCENE, "k": k}) for k in range(3)]
    store.create("solo", SCENE, "host")
    assert not store.create_batch("b", {"base": SCENE}, members, "host", limit=3)
    assert store.get_batch("b") is None and store.get("b-000") is None  # none stored
    assert store.create_batch("b", {"base": SCENE, "n": 3}, members, "host", limit=4)
    assert claim(store) == "solo"
    assert [claim(store, worker=f"w{k}") for k in range(2)] == ["b-000", "b-001"]
    plan = {"objective": 2.5, "verification": {"verified": True}}
    assert store.finish("b-000", "succeeded", plan, None)
    assert store.finish("b-001", "failed", None, "boom")
    batch = store.get_batch("b")
    assert (batch.id, batch.spec, batch.owner) == ("b", {"base": SCENE, "n": 3}, "host")
    assert [(m.job_id, m.index, m.status, m.verified, m.objective, m.error)
            for m in batch.members] == [
        ("b-000", 0, "succeeded", True, 2.5, None), ("b-001", 1, "failed", None, None, "boom"),
        ("b-002", 2, "queued", None, None, None)]
    assert batch.members[0].started <= batch.members[0].finished
    assert store.get("b-002").scene == {**SCENE, "k": 2}
    assert store.get_batch("missing") is None


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


def test_the_store_pickles_as_its_address(store):
    clone = pickle.loads(pickle.dumps(store))
    try:
        store.create("a", SCENE, "host")
        assert clone.get("a").scene == SCENE
    finally:
        # The clone opened a pool of its own; left to the garbage collector, psycopg's pool
        # is finalised on one of its own threads and warns (cannot join current thread).
        clone.close()


def _writer(store: JobStore, prefix: str, count: int, start) -> None:
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


def test_concurrent_claims_take_every_job_exactly_once(store):
    jobs = 60
    for k in range(jobs):
        store.create(f"j{k:02d}", SCENE, f"owner{k % 3}")
    taken: list[list[str]] = [[] for _ in range(4)]
    start = threading.Barrier(len(taken))

    def take(mine: list[str], name: str) -> None:
        start.wait()
        while (record := store.claim(None, name, time.time() + 60)) is not None:
            mine.append(record.id)
            assert store.finish(record.id, "succeeded", None, None, worker=name)

    threads = [threading.Thread(target=take, args=(t, f"w{i}")) for i, t in enumerate(taken)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    every = [job for mine in taken for job in mine]
    assert sorted(every) == [f"j{k:02d}" for k in range(jobs)]  # none twice, none left
    assert store.count_by_status()["succeeded"] == jobs


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
    assert store._rows("PRAGMA user_version")[0][0] == sqlite_store.SCHEMA_VERSION


def test_a_postgres_database_of_the_first_schema_is_migrated(postgres_url):
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        for statement in pg_store._MIGRATIONS[0]:
            conn.execute(statement)
        conn.execute("CREATE TABLE undertow_schema (version integer NOT NULL)")
        conn.execute("INSERT INTO undertow_schema VALUES (1)")
        conn.execute("INSERT INTO jobs (id, status, scene, owner, created) "
                     "VALUES ('old', 'queued', '{}', 'host', 1.0)")
    store = PostgresJobStore(postgres_url)
    assert store.get("old").worker is None
    assert claim(store) == "old" and store.get("old").worker == "w1"
    assert store.finish("old", "succeeded", {"plan": 1}, None, {"x": [1.0]})
    assert store.solution("old") == {"x": [1.0]}
    assert store.schema_version == pg_store.SCHEMA_VERSION
    store.close()
    again = PostgresJobStore(postgres_url)  # a second start migrates nothing
    assert again.schema_version == pg_store.SCHEMA_VERSION and again.get("old") is not None
    again.close()


def test_servers_starting_together_migrate_a_new_database_once(postgres_url):
    stores: list[JobStore] = []
    threads = [threading.Thread(target=lambda: stores.append(PostgresJobStore(postgres_url)))
               for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert len(stores) == 4
    assert stores[0]._rows("SELECT COUNT(*) FROM undertow_schema") == [(1,)]
    for s in stores:
        s.close()


def test_an_unreachable_postgres_server_is_unavailable_without_its_password():
    from testbed.service import free_port

    with pytest.raises(StoreUnavailable, match=r"PostgreSQL 127\.0\.0\.1:\d+/x") as caught:
        PostgresJobStore(f"postgresql://u:secret@127.0.0.1:{free_port()}/x", timeout=1.0)
    assert "secret" not in str(caught.value)


def test_a_store_deleted_under_the_service_is_unavailable_not_recreated(sqlite):
    sqlite.create("a", SCENE, "host")
    sqlite.check()
    os.unlink(sqlite.path)
    with pytest.raises(StoreUnavailable, match="was deleted or replaced"):
        sqlite.check()
    with pytest.raises(StoreUnavailable):
        sqlite.create("b", SCENE, "host")
    assert not os.path.exists(sqlite.path)


def test_check_reads_the_file_not_a_cache(tmp_path):
    path = tmp_path / "db.sqlite3"
    store = filled(path, 50)
    store.check()
    assert store.get("j49") is not None  # this connection now holds the pages in its cache
    overwrite(path, 4096)  # every page after the header's
    with pytest.raises(StoreUnavailable, match="malformed"):
        store.check()
