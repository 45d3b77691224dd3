"""SQLite job store: persistence, WAL, conditional transitions, writers in two processes."""

from __future__ import annotations

import multiprocessing
import pickle

import pytest

from app.store import INTERRUPTED, SqliteJobStore

SCENE = {"robot": {"links": []}, "note": "stored verbatim"}


@pytest.fixture
def store(tmp_path) -> SqliteJobStore:
    s = SqliteJobStore(tmp_path / "jobs" / "db.sqlite3")
    yield s
    s.close()


def test_wal_mode_is_on(store):
    assert store.journal_mode == "wal"


def test_a_job_survives_reopening_the_file(store, tmp_path):
    store.create("a", SCENE, "host")
    assert store.claim("a") is not None
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
    assert store.claim("a") is not None
    assert store.claim("a") is None  # already claimed
    assert store.finish("a", "failed", None, "boom")
    assert not store.finish("a", "succeeded", None, None)  # a verdict is final
    assert not store.report_progress("a", {"iteration": 9})
    assert not store.fail("a", "late")
    assert store.get("a").error == "boom"


def test_cancel_queued_is_immediate_and_running_is_flagged(store):
    store.create("q", SCENE, "host")
    assert store.request_cancel("q").status == "cancelled"
    assert store.claim("q") is None
    store.create("r", SCENE, "host")
    store.claim("r")
    assert store.report_progress("r", {"iteration": 0})
    flagged = store.request_cancel("r")
    assert (flagged.status, flagged.cancel_requested) == ("running", True)
    assert not store.report_progress("r", {"iteration": 1})  # the worker is told to stop
    assert store.request_cancel("missing") is None


def test_interrupt_marks_only_the_owners_running_jobs(store):
    for job_id, owner in (("mine", "a"), ("other", "b"), ("waiting", "a")):
        store.create(job_id, SCENE, owner)
    store.claim("mine")
    store.claim("other")
    assert store.interrupt("a") == ["mine"]
    mine = store.get("mine")
    assert (mine.status, mine.error) == ("failed", INTERRUPTED)
    assert store.get("other").status == "running"
    assert store.queued("a") == ["waiting"]


def test_list_is_newest_first_and_filters_by_status(store):
    for k in range(5):
        store.create(f"j{k}", SCENE, "host")
    store.claim("j1")
    assert [r.id for r in store.list(limit=3)] == ["j4", "j3", "j2"]
    assert [r.id for r in store.list(limit=3, offset=3)] == ["j1", "j0"]
    assert [r.id for r in store.list(status="running")] == ["j1"]
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
        store.claim(job_id)
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
