"""Job stores, each test against both stores (SQLite and a throwaway PostgreSQL server)
unless it is about one of them: persistence, conditional transitions, claims and leases,
requeues, batches, migrations, writers in two processes; SQLite's WAL, checkpoints,
integrity and a file deleted under a running service; PostgreSQL's concurrent claims and
an unreachable server."""

from __future__ import annotations

import json
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
    DuplicateKey,
    JobStore,
    NameTaken,
    RetryPolicy,
    SqliteJobStore,
    StoreDamaged,
    StoreUnavailable,
)
from app.store.migrations import SCHEMA_VERSION, migrate
from app.store.postgres import PostgresJobStore
from app.store.postgres_sql import _execute as pg_execute

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
    assert isinstance(store, PostgresJobStore)
    return PostgresJobStore(store.url, lease=store.lease)


def lapse(store: JobStore) -> None:
    """Let the leases of the claims made so far run out: at once for SQLite's, whose
    claims name their end (claimed with a lease of -1 s), one lease for PostgreSQL's
    (procrastinate's), which count from the last renewal."""
    if isinstance(store, PostgresJobStore):
        time.sleep(store.lease + 0.05)


def test_wal_mode_is_on(sqlite):
    assert sqlite.journal_mode == "wal"


def test_sqlite_announces_no_queued_job_so_idle_workers_poll(sqlite):
    assert sqlite.listen() is None


def claim(store: JobStore, owner: str | None = "host", worker: str = "w1",
          lease: float = 60.0) -> str | None:
    """Claim the oldest queued job of `owner`; its id. A lease below 0 (one already over,
    for SQLite's claims, which name their end) is the store's own for PostgreSQL's, which
    run out by silence: `lapse`."""
    if lease < 0 and isinstance(store, PostgresJobStore):
        lease = store.lease
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


def test_a_status_is_read_as_the_job_says_it(store):
    assert store.status("missing") is None
    store.create("s", SCENE, "host")
    assert store.status("s") == store.get("s").status == "queued"
    claim(store)
    assert store.status("s") == "running"
    store.finish("s", "succeeded", {"verification": {"verified": True}}, None)
    assert store.status("s") == store.get("s").status == "succeeded"


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


def test_recover_requeues_only_the_owners_running_jobs_held_by_its_workers(store):
    for job_id, owner in (("mine", "a"), ("other", "b"), ("waiting", "a"), ("remote", "a")):
        store.create(job_id, SCENE, owner)
    assert claim(store, "a", worker="a/0/x") == "mine"
    assert claim(store, "b", worker="b/0/x") == "other"
    assert claim(store, "a", worker="ab/0/x") == "waiting"  # another instance's worker
    store.create("last", SCENE, "a")
    assert claim(store, "a", worker="elsewhere/0/x") == "remote"
    assert store.recover("a") == {"mine": "queued"}
    mine = store.get("mine")
    assert (mine.status, mine.error, mine.worker, mine.infra_failures) == (
        "queued", None, None, 1)
    assert mine.history[-1]["reason"] == "the server stopped while it ran"
    assert {store.get(j).status for j in ("other", "waiting", "remote")} == {"running"}
    assert store.get("last").status == "queued"


def test_a_server_name_is_held_by_one_live_server_at_a_time(store):
    held = store.hold_name("a")
    with pytest.raises(NameTaken, match="another server named 'a' runs on the job store"):
        reopen(store).hold_name("a")
    other = reopen(store).hold_name("b")  # another name, on the same store
    held.release()
    reopen(store).hold_name("a").release()
    other.release()


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


def test_leases_are_renewed_by_job_and_worker_with_cancel_flags_and_expire(store):
    for job_id in ("a", "b", "c"):
        store.create(job_id, SCENE, "host")
    claim(store, worker="w1", lease=-1.0)  # a: lease already over
    claim(store, worker="w2", lease=-1.0)  # b
    claim(store, worker="w3", lease=-1.0)  # c
    lapse(store)
    store.request_cancel("b")
    assert store.renew([("a", "w1"), ("b", "w2"), ("c", "w9")], time.time() + 60) == {
        "a": False, "b": True}  # c is not w9's: its lease is not renewed
    assert store.renew([], time.time() + 60) == {}
    assert store.expire(time.time()) == {"c": "queued"}  # requeued: an infrastructure failure
    c = store.get("c")
    assert (c.status, c.worker, c.started, c.progress, c.error, c.infra_failures) == (
        "queued", None, None, None, None, 1)
    assert store.get("a").status == "running"


def test_a_short_lease_being_renewed_is_not_taken_by_a_look_ahead(store):
    # a process with a long lease looks ahead by its look interval (up to 15 s): a claim of
    # a node with a 1.5 s lease renewed a moment ago is healthy all the same; once silent
    # for its whole lease, it is lost
    store.create("a", SCENE, "host")
    assert claim(store, worker="w1", lease=1.5) == "a"
    assert store.expire(time.time() + 5.0) == {}
    time.sleep(1.6)  # silent for its whole lease
    assert store.renew([("a", "w1")], time.time() + 1.5) == {"a": False}
    assert store.expire(time.time() + 5.0) == {}  # renewed: healthy again
    time.sleep(1.6)
    assert store.expire(time.time() + 5.0) == {"a": "queued"}


def test_infrastructure_failures_are_retried_after_a_pause_then_dead_lettered(store):
    store.policy = RetryPolicy(max_retries=2, backoff=0.2, max_backoff=0.3)
    store.create("a", SCENE, "host")
    assert claim(store, worker="w1") == "a"
    assert store.requeue("a", "w2", "not w2's") is None
    assert store.requeue("a", "w1", "the worker process died") == "queued"
    assert not store.finish("a", "succeeded", None, None, worker="w1")  # w1 lost it
    assert claim(store, worker="w2") is None  # not before its pause
    time.sleep(0.25)
    assert claim(store, worker="w2", lease=-1.0) == "a"
    assert not store.report_progress("a", {"iteration": 1}, worker="w1")
    assert store.report_progress("a", {"iteration": 1}, worker="w2")
    lapse(store)
    assert store.expire(time.time()) == {"a": "queued"}
    time.sleep(0.35)  # the second pause: doubled, at most max_backoff
    assert claim(store, worker="w3") == "a"
    assert store.requeue_claimed("w3", "the node's main process died") == {"a": "failed"}
    a = store.get("a")
    assert (a.status, a.dead_letter, a.infra_failures, a.attempts, a.worker) == (
        "failed", True, 3, 3, "w3")
    assert a.error == ("dead letter: the node's main process died; it failed for "
                       "infrastructure reasons 3 times (UNDERTOW_MAX_RETRIES=2)")
    assert [(e["event"], e["worker"]) for e in a.history] == [
        ("claimed", "w1"), ("infrastructure-failure", "w1"), ("claimed", "w2"),
        ("infrastructure-failure", "w2"), ("claimed", "w3"), ("infrastructure-failure", "w3")]
    assert [e.get("reason") for e in a.history][1::2] == [
        "the worker process died", "its lease ran out: its worker or node was lost",
        "the node's main process died"]
    # re-submitted by id: queued again with a clean count, its history kept
    assert store.retry("a", "other-host")
    again = store.get("a")
    assert (again.status, again.owner, again.error, again.dead_letter, again.infra_failures,
            again.finished) == ("queued", "other-host", None, False, 0, None)
    assert again.history[-1]["event"] == "retried"
    assert not store.retry("a", "other-host")  # only failed or cancelled jobs
    store.create("b", SCENE, "host")
    assert claim(store, None, worker="w4") == "a"
    assert store.finish("a", "failed", None, "boom", worker="w4")
    assert not store.retry("a", "host", limit=1)  # host holds b already
    assert store.retry("a", "host", limit=2)
    assert store.get("a").history[-2]["reason"] == "failed"  # the verdict is in it too


def test_a_cancelled_job_is_not_requeued_and_a_release_is_not_a_failure(store):
    store.create("b", SCENE, "host")
    assert claim(store, worker="w3", lease=-1.0) == "b"
    store.request_cancel("b")
    lapse(store)
    assert store.expire(time.time()) == {"b": "cancelled"}
    assert store.get("b").error == "cancelled on request"
    store.create("c", SCENE, "host")  # a released claim does not count
    assert claim(store, worker="w4") == "c"
    assert store.release_claimed("w4", "the node was stopping") == ["c"]
    c = store.get("c")
    assert (c.status, c.attempts, c.infra_failures) == ("queued", 0, 0)
    assert c.history[-1] == {**c.history[-1], "event": "released",
                             "reason": "the node was stopping"}


def test_a_batch_is_cancelled_whole(store):
    members = [(f"b-{k:03d}", {**SCENE, "k": k}) for k in range(3)]
    assert store.create_batch("b", {"base": SCENE}, members, "host")
    assert claim(store) == "b-000"
    assert store.cancel_batch("b") and not store.cancel_batch("missing")
    assert [m.status for m in store.get_batch("b").members] == [
        "running", "cancelled", "cancelled"]
    assert store.get("b-000").cancel_requested
    assert not store.report_progress("b-000", {"iteration": 1})


def test_a_jobs_admission_is_stored_with_it_and_kept_by_a_retry(store):
    decided = {"issues": [], "warm_start": {"job_id": "x", "distance": 0.01}}
    store.create("a", SCENE, "host", admission=decided)
    store.create("old", SCENE, "host")  # as an earlier version stored it
    members = [("b-0", SCENE), ("b-1", SCENE)]
    assert store.create_batch("b", {"base": SCENE}, members, "host",
                              admissions=[decided, None])
    assert [store.get(k).admission for k in ("a", "old", "b-0", "b-1")] == [
        decided, None, decided, None]
    assert [r.admission for r in store.list(summaries=True)] == [None] * 4
    assert claim(store) == "a" and store.finish("a", "failed", None, "no", worker="w1")
    assert store.retry("a", "host") and store.get("a").admission == decided


def test_an_idempotency_key_names_one_job(store):
    assert store.find_key("k1") is None
    store.create("a", SCENE, "host", key="k1")
    assert store.find_key("k1") == "a"
    with pytest.raises(DuplicateKey):
        store.create("b", SCENE, "host", key="k1")
    assert store.get("b") is None


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


def test_requeue_claimed_requeues_only_the_workers_running_jobs(store):
    for job_id in ("a", "b", "c"):
        store.create(job_id, SCENE, "host")
    claim(store, worker="w1")
    claim(store, worker="w2")
    assert store.requeue_claimed("w1", "died") == {"a": "queued"}
    assert (store.get("a").status, store.get("a").infra_failures) == ("queued", 1)
    assert store.get("b").status == "running" and store.get("c").status == "queued"


def test_a_listing_of_summaries_reads_no_scene_plan_or_history(store):
    for k in range(3):
        store.create(f"j{k}", SCENE, "host")
    assert claim(store) == "j0"
    assert store.finish("j0", "succeeded", {"t": [0.0, 1.0]}, None)
    full, lean = store.list(limit=10), store.list(limit=10, summaries=True)
    assert full[-1].plan == {"t": [0.0, 1.0]} and full[-1].scene == SCENE and full[-1].history
    assert [(r.id, r.status, r.progress, r.error, r.attempts, r.created, r.finished)
            for r in lean] == [(r.id, r.status, r.progress, r.error, r.attempts, r.created,
                                r.finished) for r in full]
    assert all(r.plan is None and r.scene == {} and r.history is None for r in lean)


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
    try:
        for k in range(count):
            job_id = f"{prefix}{k}"
            store.create(job_id, SCENE, prefix)
            assert store.claim(prefix, prefix, time.time() + 60).id == job_id
            store.report_progress(job_id, {"iteration": k})
            store.finish(job_id, "succeeded", {"k": k}, None)
    finally:
        store.close()  # the process's own pool, not left to the interpreter's exit


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


def test_plans_are_stored_compressed_and_those_stored_as_text_still_read(sqlite):
    plan = {"t": [0.1 * k for k in range(2000)], "objective": 2.5,
            "verification": {"verified": True}}
    solution = {"x": [1.0 / (k + 1) for k in range(500)]}
    for job_id in ("new", "old"):
        sqlite.create(job_id, SCENE, "host")
        assert claim(sqlite) == job_id
    assert sqlite.finish("new", "succeeded", plan, None, solution)
    sqlite._rows("UPDATE jobs SET status = 'succeeded', plan = ?, solution = ? "  # as before
                 "WHERE id = 'old'", (json.dumps(plan), json.dumps(solution)))
    def stored(job_id: str, column: str) -> tuple[str, int]:
        """How the column holds its value: SQLite's type, and its length [bytes]."""
        return sqlite._rows(f"SELECT typeof({column}), length({column}) FROM jobs "
                            "WHERE id = ?", (job_id,))[0]

    for column in ("plan", "solution"):
        (kind, size), (old_kind, old_size) = stored("new", column), stored("old", column)
        assert (kind, old_kind) == ("blob", "text") and size < old_size / 2
    for job_id in ("new", "old"):
        assert (sqlite.get(job_id).plan, sqlite.solution(job_id)) == (plan, solution)


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


def filled(path, jobs: int, busy_timeout: float = 30.0) -> SqliteJobStore:
    """A store of `jobs` jobs of 500 bytes each, all in its main file; `busy_timeout` [s]:
    the store's."""
    store = SqliteJobStore(path, busy_timeout)
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
    assert store._rows("PRAGMA user_version")[0][0] == SCHEMA_VERSION == store.schema_version


def test_a_postgres_database_of_the_first_schema_is_migrated(postgres_url):
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        assert migrate(lambda sql: pg_execute(conn, sql), "postgres", upto=1) == 1
        conn.execute("INSERT INTO jobs (id, status, scene, owner, created) "
                     "VALUES ('old', 'queued', '{}', 'host', 1.0)")
    store = PostgresJobStore(postgres_url)
    assert store.get("old").worker is None
    assert claim(store) == "old" and store.get("old").worker == "w1"
    assert store.finish("old", "succeeded", {"plan": 1}, None, {"x": [1.0]})
    assert store.solution("old") == {"x": [1.0]}
    assert store.schema_version == SCHEMA_VERSION
    store.close()
    again = PostgresJobStore(postgres_url)  # a second start migrates nothing
    assert again.schema_version == SCHEMA_VERSION and again.get("old") is not None
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


def test_a_write_ahead_log_deleted_under_the_service_refuses_writes_and_keeps_jobs(tmp_path):
    path = tmp_path / "db.sqlite3"
    store, worker = SqliteJobStore(path), SqliteJobStore(path)  # a server and its worker
    for k in range(5):
        store.create(f"j{k}", SCENE, "host")  # in the log only (no checkpoint yet)
    assert worker.get("j4") is not None
    os.unlink(tmp_path / "db.sqlite3-wal")
    with pytest.raises(StoreUnavailable, match="write-ahead log .* was deleted or replaced"):
        store.create("late", SCENE, "host")
    with pytest.raises(StoreUnavailable, match="write-ahead log"):
        store.check()
    with pytest.raises(StoreUnavailable, match="write-ahead log"):
        worker.claim(None, "w", time.time() + 60)
    store.close()
    worker.close()
    again = SqliteJobStore(path)  # the restart: every job accepted before is there
    assert [again.get(f"j{k}").status for k in range(5)] == ["queued"] * 5
    assert again.get("late") is None


@pytest.mark.parametrize("damage", ["garbage", "pages", "other database"])
def test_a_file_overwritten_in_place_refuses_new_jobs_and_health(tmp_path, damage):
    path = tmp_path / "db.sqlite3"
    store = filled(path, 50, busy_timeout=2.0)  # another database's file is waited on first
    store.check()
    if damage == "garbage":
        path.write_bytes(b"\x5a" * path.stat().st_size)  # same inode, same size
    elif damage == "pages":
        overwrite(path, 4096)  # every page after the first
    else:
        other = tmp_path / "other.sqlite3"
        conn = sqlite3.connect(other)
        conn.execute("CREATE TABLE unrelated (x)")
        conn.commit()
        conn.close()
        path.write_bytes(other.read_bytes())
    with pytest.raises(StoreUnavailable):
        store.check()
    with pytest.raises(StoreUnavailable):
        store.create("new", SCENE, "host")
    with pytest.raises(StoreUnavailable):
        store.create_batch("b", {}, [("b-0", SCENE)], "host")


def test_finished_jobs_past_their_retention_are_deleted(store):
    for k in range(5):
        store.create(f"j{k}", SCENE, "host")
    members = [(f"b-{k}", SCENE) for k in range(2)]
    store.create_batch("b", {"base": SCENE}, members, "host")
    for k in range(4):
        job_id = claim(store, worker=f"w{k}")
        assert store.finish(job_id, "succeeded", None, None)
        time.sleep(0.01)
    assert store.purge(time.time() - 3600, keep=3) == 1  # the oldest finished one
    assert store.get("j0") is None and store.get("j1") is not None
    assert store.purge(time.time() + 1, keep=100) == 3  # every finished one: all too old
    assert sorted(r.id for r in store.list(limit=10)) == ["b-0", "b-1", "j4"]  # unfinished stay
    for k in range(3):
        job_id = claim(store, worker=f"v{k}")
        store.finish(job_id, "failed", None, "x")
    assert store.purge(time.time() + 1, keep=100) == 3
    assert store.get_batch("b") is None  # no member left


def test_finished_jobs_beyond_the_retention_in_bytes_are_deleted_oldest_first(store):
    plan = {"t": [0.1 * k for k in range(3000)], "objective": 1.0}
    for k in range(6):
        store.create(f"j{k}", SCENE, "host")
        assert claim(store) == f"j{k}"
        assert store.finish(f"j{k}", "succeeded", plan, None, {"x": plan["t"]})
    store.create("waiting", SCENE, "host")  # never deleted, and not counted
    held = dict(store._rows(f"SELECT id, {store._stored_bytes()} FROM jobs "
                            "WHERE status = 'succeeded'"))
    assert min(held.values()) > 10_000  # the plans and solutions are counted
    newest = held["j5"] + held["j4"] + held["j3"]
    assert store.purge(0.0, keep=100, size=newest) == 3
    assert sorted(r.id for r in store.list(limit=10)) == ["j3", "j4", "j5", "waiting"]
    assert store.purge(0.0, keep=100, size=newest) == 0


def test_heartbeats_list_the_live_workers(store):
    started = time.time()
    store.heartbeat("node-b:worker:7", 2, 1, started)
    store.heartbeat("api-a", 1, 0, started)
    store.heartbeat("node-b:worker:7", 2, 2, started)
    listed = store.workers(started - 1)
    assert [(w.name, w.processes, w.busy) for w in listed] == [
        ("api-a", 1, 0), ("node-b:worker:7", 2, 2)]
    assert store.workers(time.time() + 1) == []  # none heard from since
    store.forget_worker("api-a")
    assert [w.name for w in store.workers(started - 1)] == ["node-b:worker:7"]
