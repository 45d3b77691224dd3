"""A job's status on PostgreSQL is derived by the database from its engine job's
(`app.store.postgres_status`): no statement of the store writes it, every engine status
gives the API's along the API's transitions only, and a store does not install the
derivation while a node of a release that writes the status itself is alive."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import pytest

from app.store.base import EarlierNodes
from app.store.postgres import PostgresJobStore
from app.store.postgres_status import TRIGGERS, derived

SCENE = {"robot": {"links": []}}
LEASE = 0.5  # [s]
RECORDER = """
CREATE TABLE status_writes (job_id text, status text);
CREATE FUNCTION record_status_write() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN
    IF pg_trigger_depth() = 1 AND NEW.status IS DISTINCT FROM OLD.status THEN
        INSERT INTO status_writes VALUES (NEW.id, NEW.status);
    END IF;
    RETURN NEW;
END $$;
CREATE TRIGGER record_status_write BEFORE UPDATE ON jobs FOR EACH ROW
    EXECUTE FUNCTION record_status_write()"""
"""Records each change of a job's status made by a statement itself (trigger depth 1),
not by a trigger of the engine's tables (depth 2)."""


@pytest.fixture
def store(postgres_url: str) -> Iterator[PostgresJobStore]:
    with contextlib.closing(PostgresJobStore(postgres_url, lease=LEASE)) as s:
        yield s


def claim(store: PostgresJobStore, owner: str | None = "host", worker: str = "n/0/a") -> str:
    record = store.claim(owner, worker, time.time() + LEASE)
    assert record is not None
    return record.id


def lifecycle(store: PostgresJobStore) -> list[str | None]:
    """Every transition of the interface, once each: the statuses they leave."""
    store.create("a", SCENE, "host")
    store.create_batch("b", {}, [("b0", SCENE), ("b1", SCENE)], "host")
    assert claim(store) == "a"
    assert store.report_progress("a", {"phase": "solving"}, "n/0/a")
    assert store.release("a", "n/0/a")
    assert claim(store) == "a"
    assert store.requeue("a", "n/0/a", "the worker process died") == "queued"
    assert claim(store) == "b0"
    assert store.finish("b0", "succeeded", {"k": 1}, None, worker="n/0/a")
    assert store.cancel_batch("b")  # b1, queued
    store._rows("UPDATE procrastinate_jobs SET scheduled_at = now()")
    assert claim(store) == "a"
    store.request_cancel("a")  # running: flagged
    assert store.finish("a", "cancelled", None, "cancelled", worker="n/0/a")
    assert store.retry("a", "host")
    assert store.fail("a", "refused")  # queued
    return [store.status(job_id) for job_id in ("a", "b0", "b1")]


def test_no_statement_of_the_store_writes_a_jobs_status(store):
    store._rows(RECORDER)
    assert lifecycle(store) == ["failed", "succeeded", "cancelled"]
    assert store._rows("SELECT * FROM status_writes") == []


def test_the_recorder_finds_a_store_that_writes_the_status(store, monkeypatch):
    monkeypatch.setattr(PostgresJobStore, "_status",  # the planted fault
                        lambda self, value: f"status = {value}, ")
    store._rows(RECORDER)
    lifecycle(store)
    assert ("b0", "succeeded") in store._rows("SELECT * FROM status_writes")


def engine_moves(store: PostgresJobStore, job_id: str, status: str) -> str | None:
    """The job's status once its engine job is set to `status` (as a stray move would)."""
    store._rows("UPDATE procrastinate_jobs SET status = %s WHERE id = "
                "(SELECT queue_id FROM undertow_queue WHERE job_id = %s)", (status, job_id))
    return store.status(job_id)


def test_a_job_follows_its_engine_job_along_the_apis_transitions_only(store):
    store.create("a", SCENE, "host")
    assert engine_moves(store, "a", "succeeded") == "succeeded"
    assert engine_moves(store, "a", "doing") == "succeeded"  # not claimed when final
    assert engine_moves(store, "a", "failed") == "succeeded"  # one final status is kept
    assert engine_moves(store, "a", "todo") == "queued"  # a retry
    assert engine_moves(store, "a", "doing") == "running"
    assert engine_moves(store, "a", "aborted") == "cancelled"
    store.create("b", SCENE, "host")
    assert claim(store) == "b"
    assert engine_moves(store, "b", "todo") == "queued"  # a release
    assert engine_moves(store, "b", "cancelled") == "cancelled"


def an_earlier_node(store: PostgresJobStore, seen: float) -> None:
    """A database from before the derivation, where a node of a release before da7fea7
    wrote its heartbeat at `seen` [s]."""
    for trigger, table in zip(TRIGGERS, ("procrastinate_jobs", "undertow_queue"), strict=True):
        store._rows(f"DROP TRIGGER {trigger} ON {table}")
    store._rows("INSERT INTO workers (name, processes, busy, started, seen) "
                "VALUES ('old-node:worker:7', 2, 1, %s, %s)", (seen - 60.0, seen))


def test_a_store_does_not_derive_the_status_beside_a_node_that_writes_it(store, postgres_url):
    an_earlier_node(store, time.time())
    with pytest.raises(EarlierNodes, match=r"node\(s\) old-node:worker:7 of a release "
                                           r"before da7fea7 are running on it"):
        PostgresJobStore(postgres_url, lease=LEASE)
    assert not derived(store._rows)  # nothing installed
    store._rows("UPDATE workers SET seen = %s", (time.time() - 2 * LEASE,))  # gone silent
    with contextlib.closing(PostgresJobStore(postgres_url, lease=LEASE)) as later:
        assert derived(later._rows)
    store._rows("UPDATE workers SET seen = %s", (time.time(),))
    PostgresJobStore(postgres_url, lease=LEASE).close()  # installed: nothing more to refuse
