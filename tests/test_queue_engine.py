"""The PostgreSQL store's queue, procrastinate's (`app.store.postgres`): every transition
of a job moves its engine job the same way in the same transaction, so that their
statuses agree when each test ends (the interface's own behaviour is tests/test_store.py's,
run on this store too); a claim is held by its node's engine registration, whose heartbeat
is the lease (tests/test_engine_nodes.py); the engine's NOTIFY wakes a listener, and the
store's own wakes an idle worker for a job queued again (released, retried by id, requeued
after its pause); jobs queued or claimed by a version before procrastinate are taken over."""

from __future__ import annotations

import contextlib
import datetime
import multiprocessing
import select
import time
from collections.abc import Callable, Iterator

import psycopg
import pytest
from conftest import out_of_step

from app.idle_wait import IdleWait
from app.store import DuplicateKey, RetryPolicy
from app.store.migrations import migrate
from app.store.postgres import PostgresJobStore
from app.store.postgres_sql import _execute as pg_execute

SCENE = {"robot": {"links": []}}
LEASE = 0.5  # [s]
OWN_QUEUE_SCHEMA = 6
"""The schema version of the last databases undertow's own PostgreSQL queue wrote."""


@pytest.fixture
def store(postgres_url: str) -> Iterator[PostgresJobStore]:
    s = PostgresJobStore(postgres_url, lease=LEASE,
                         policy=RetryPolicy(max_retries=1, backoff=30.0))
    yield s
    try:
        assert out_of_step(s) == []  # every transition moved the engine job alike
    finally:
        s.close()


def engine(store: PostgresJobStore, job_id: str) -> dict:
    """The engine job of `job_id`: its status, queue, attempts, abort flag, seconds until
    its retry time (None when it has none) and whether a registration holds its claim."""
    rows = store._rows(
        "SELECT q.status, q.queue_name, q.attempts, q.abort_requested, "
        "EXTRACT(EPOCH FROM q.scheduled_at - now()), "
        "q.status = 'doing' AND q.worker_id IS NOT NULL "
        "FROM undertow_queue m JOIN procrastinate_jobs q ON q.id = m.queue_id "
        "WHERE m.job_id = %s", (job_id,))
    assert rows, f"job {job_id} has no engine job"
    status, queue, attempts, abort, wait, held = rows[0]
    return {"status": status, "queue": queue, "attempts": attempts, "abort": abort,
            "wait": None if wait is None else float(wait), "held": held}


def registrations(store: PostgresJobStore) -> int:
    return store._rows("SELECT COUNT(*) FROM procrastinate_workers")[0][0]


def claim(store: PostgresJobStore, owner: str | None = "host",
          worker: str = "w1") -> str | None:
    record = store.claim(owner, worker, time.time() + LEASE)
    return None if record is None else record.id


def test_a_job_and_its_engine_job_move_together(store):
    store.create("a", SCENE, "host")
    assert engine(store, "a")["status"] == "todo"
    assert engine(store, "a")["queue"] == "host"  # a queue per owner
    assert claim(store, "other") is None and registrations(store) == 0  # nothing held
    assert claim(store) == "a"
    assert engine(store, "a") == {**engine(store, "a"), "status": "doing", "held": True}
    assert registrations(store) == 1  # the node's registration, made by its first claim
    assert store.finish("a", "succeeded", {"k": 1}, None, worker="w1")
    assert engine(store, "a")["status"] == "succeeded"
    assert registrations(store) == 1  # it stays the node's


def queue_columns(store: PostgresJobStore, job_id: str) -> tuple:
    """The columns in which the SQLite store keeps its queue: (lease_until, not_before),
    and the lease the claim stored."""
    return store._rows("SELECT lease_until, not_before, lease FROM jobs WHERE id = %s",
                       (job_id,))[0]


def test_an_infrastructure_failure_is_a_retry_of_the_engine_job_at_its_pause(store):
    store.create("a", SCENE, "host")
    claim(store)
    lease_until, not_before, lease = queue_columns(store, "a")
    assert (lease_until, not_before, lease) == (None, None, pytest.approx(LEASE, abs=0.05))
    assert store.requeue("a", "w1", "the worker process died") == "queued"
    assert queue_columns(store, "a")[:2] == (None, None)  # one set of books: the engine's
    first = engine(store, "a")
    assert (first["status"], first["held"]) == ("todo", False)
    assert 29.0 < first["wait"] <= 30.0  # the policy's first pause, kept by the engine
    assert claim(store, None) is None  # its fetch waits for the retry time
    store._rows("UPDATE procrastinate_jobs SET scheduled_at = now() WHERE id = "
                "(SELECT queue_id FROM undertow_queue WHERE job_id = 'a')")
    assert claim(store, None, "w2") == "a"
    assert store.requeue("a", "w2", "the worker process died again") == "failed"
    assert engine(store, "a")["status"] == "failed"  # a dead letter ends its engine job
    assert store.get("a").dead_letter and registrations(store) == 2  # w1's and w2's nodes


def test_claims_hold_where_the_database_derives_the_status_from_the_engines(store):
    for job_id in ("a", "b", "c"):
        store.create(job_id, SCENE, "host")
    assert claim(store) == "a"  # its status read `running` before the claim was written
    assert store.get("a").worker == "w1"  # type: ignore[union-attr]
    assert store.finish("a", "succeeded", {"k": 1}, None, worker="w1")
    assert claim(store, worker="w2") == "b"
    assert store.requeue("b", "w2", "the worker process died") == "queued"
    assert claim(store, worker="w3") == "c"
    assert store.release("c", "w3")
    assert [store.status(job_id) for job_id in "abc"] == ["succeeded", "queued", "queued"]


def test_a_release_requeues_the_engine_job_at_once(store):
    store.create("a", SCENE, "host")
    claim(store)
    assert store.release_claimed("w1", "the node was stopping") == ["a"]
    released = engine(store, "a")
    assert (released["status"], released["held"]) == ("todo", False)
    assert released["wait"] <= 0.0
    assert claim(store, None, "w2") == "a"


def test_a_queued_job_that_fails_ends_its_engine_job_failed(store):
    store.create("a", SCENE, "host")
    assert store.fail("a", "its scene cannot be read")
    assert engine(store, "a")["status"] == "failed"  # not cancelled: the API says failed


def test_cancels_reach_the_engine_job(store):
    store.create("q", SCENE, "host")
    store.request_cancel("q")
    assert engine(store, "q")["status"] == "cancelled"  # never fetched
    store.create("r", SCENE, "host")
    claim(store)
    store.request_cancel("r")
    assert engine(store, "r")["abort"]
    assert store.finish("r", "cancelled", None, "cancelled on request", worker="w1")
    assert engine(store, "r")["status"] == "aborted"
    members = [(f"b-{k}", SCENE) for k in range(3)]
    store.create_batch("b", {}, members, "host")
    claim(store, worker="w2")
    store.cancel_batch("b")
    assert [engine(store, f"b-{k}")["status"] for k in range(3)] == [
        "doing", "cancelled", "cancelled"]
    assert engine(store, "b-0")["abort"]


def test_a_retried_job_is_claimed_from_its_new_owners_queue(store):
    store.create("f", SCENE, "host")
    claim(store)
    store.finish("f", "failed", None, "boom", worker="w1")
    assert store.retry("f", "elsewhere")
    assert (engine(store, "f")["status"], engine(store, "f")["queue"]) == ("todo", "elsewhere")
    assert claim(store, "host") is None
    assert claim(store, "elsewhere") == "f"
    store.create("c", SCENE, "host")
    store.request_cancel("c")
    assert store.retry("c", "host")  # procrastinate does not retry a cancelled job: anew
    assert engine(store, "c")["status"] == "todo"
    assert claim(store, "host") == "c"


def test_nothing_of_a_refused_job_or_batch_reaches_the_engine(store):
    store.create("a", SCENE, "host", key="k")
    with pytest.raises(DuplicateKey):
        store.create("b", SCENE, "host", key="k")
    assert not store.create_batch("big", {}, [(f"m-{k}", SCENE) for k in range(3)], "host",
                                  limit=3)
    assert store._rows("SELECT COUNT(*) FROM procrastinate_jobs")[0][0] == 1


def test_a_claim_whose_heartbeats_stop_is_requeued_by_the_engines_stalled_jobs(store):
    for job_id in ("kept", "lost"):
        store.create(job_id, SCENE, "host")
    claim(store, worker="w1")
    claim(store, worker="w2")
    time.sleep(LEASE * 0.6)
    assert store.renew([("kept", "w1")], time.time() + LEASE) == {"kept": False}
    time.sleep(LEASE * 0.6)  # "lost" silent for more than a lease, "kept" for less
    assert store.expire(time.time()) == {"lost": "queued"}
    assert engine(store, "lost")["status"] == "todo"
    assert registrations(store) == 2  # the silent node's stays, for when it is heard again
    assert store.renew([("kept", "w1"), ("lost", "w2")], time.time() + LEASE) == {
        "kept": False}


def test_a_deferred_job_is_notified_on_the_engines_channel(store):
    listener = store.listen()
    try:
        store.create("a", SCENE, "host")
        ready, _, _ = select.select([listener], [], [], 5.0)
        assert ready and listener.drain() == [0.0]  # procrastinate's, claimable now
    finally:
        listener.close()


def stored_by_the_own_queue(conn: psycopg.Connection, job_id: str,
                            worker: str | None = None) -> None:
    """A job as undertow's own PostgreSQL queue left it: queued, or claimed by `worker`
    with a lease of 1 s renewed last 2 s ago; no engine job either way."""
    claimed = worker is not None
    conn.execute(
        "INSERT INTO jobs (id, status, scene, owner, created, started, worker, lease_until, "
        "lease, attempts) VALUES (%s, %s, '{}', 'host', %s, %s, %s, %s, %s, %s)",
        (job_id, "running" if claimed else "queued", time.time(),
         time.time() - 2.0 if claimed else None, worker,
         time.time() - 1.0 if claimed else None, 1.0 if claimed else None, int(claimed)))


def test_jobs_queued_or_claimed_by_the_own_queue_are_taken_over(postgres_url):
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        migrate(lambda sql: pg_execute(conn, sql), "postgres", upto=OWN_QUEUE_SCHEMA)
        stored_by_the_own_queue(conn, "running", worker="old-worker")
        stored_by_the_own_queue(conn, "queued")
        with contextlib.closing(PostgresJobStore(postgres_url, lease=LEASE)) as taken:
            assert engine(taken, "queued")["status"] == "todo"
            stored_by_the_own_queue(conn, "late")  # a server of the older version
            time.sleep(LEASE)  # the store's expiry waits a lease after the database started
            assert taken.expire(time.time()) == {"running": "queued"}  # by its own lease
            assert engine(taken, "late")["status"] == "todo"
            taken._rows("UPDATE procrastinate_jobs SET scheduled_at = now()")
            assert {claim(taken, None), claim(taken, None), claim(taken, "host", "w2")} == {
                "queued", "running", "late"}
        assert conn.execute("SELECT COUNT(*) FROM pg_trigger WHERE tgname = "
                            "'undertow_job_queued'").fetchone() == (0,)  # its NOTIFY is gone


def test_purge_deletes_the_engine_jobs_of_deleted_jobs(store):
    store.create("a", SCENE, "host")
    claim(store)
    store.finish("a", "succeeded", None, None)
    store.create("b", SCENE, "host")
    later = (datetime.datetime.now(datetime.UTC) + datetime.timedelta(days=1)).timestamp()
    assert store.purge(later, 0) == 1
    assert store._rows("SELECT COUNT(*) FROM procrastinate_jobs")[0][0] == 1
    assert engine(store, "b")["status"] == "todo"


def test_a_released_job_is_notified_at_once(store):
    store.create("a", SCENE, "host")
    assert claim(store) == "a"
    listener = store.listen()
    try:
        listener.drain()
        assert store.release("a", "w1")
        ready, _, _ = select.select([listener], [], [], 5.0)
        assert ready and listener.drain() == [0.0]
    finally:
        listener.close()


def test_each_claim_is_judged_by_the_lease_it_stored(store, postgres_url):
    longer = 3.0  # [s] the lease of the other node
    up = float(store._rows("SELECT EXTRACT(EPOCH FROM now() - pg_postmaster_start_time())")[0][0])
    time.sleep(max(0.0, longer - up))  # no claim runs out within its lease of a restart
    for job_id in ("short", "long"):
        store.create(job_id, SCENE, "host")
    assert store.claim("host", "w1", time.time() + LEASE).id == "short"
    assert store.claim("host", "w2", time.time() + longer).id == "long"
    time.sleep(LEASE * 1.2)  # both silent: "short" past its lease, "long" well within
    with contextlib.closing(PostgresJobStore(postgres_url, lease=0.1)) as quick:
        assert quick.expire(time.time()) == {"short": "queued"}  # not by its own 0.1 s
    assert store.get("long").status == "running"


POLL = 30.0
"""[s] the idle worker's poll in the pickup tests below, far longer than any of them takes:
a job it claimed sooner was announced to it."""
PAUSE = 1.0  # [s] the pause before a job requeued after an infrastructure failure


@pytest.fixture
def paused(postgres_url: str) -> Iterator[PostgresJobStore]:
    """A store whose first requeue of a job pauses it PAUSE seconds."""
    s = PostgresJobStore(postgres_url, lease=LEASE, policy=RetryPolicy(backoff=PAUSE))
    yield s
    s.close()


def idle_pickup(store: PostgresJobStore, queue_again: Callable[[], object]) -> float:
    """An idle worker as `app.worker.serve` runs one (it waits on its supervisor's pipe and
    the store's announcements, `IdleWait`, and claims anyone's job whenever the wait
    ends), listening before `queue_again()` queues a job again: the seconds from then
    until it claimed the job (AssertionError when it did not within POLL)."""
    ours, supervisor = multiprocessing.Pipe()
    idle = IdleWait(store, ours)
    try:
        assert not idle.stop_requested(0.0) and idle.listener is not None  # listening
        started = time.monotonic()
        queue_again()
        while time.monotonic() < started + POLL and not idle.stop_requested(POLL):
            if store.claim(None, "idle", time.time() + LEASE) is not None:
                return time.monotonic() - started
        raise AssertionError(f"no claim within {POLL:g} s")
    finally:
        idle.close()
        ours.close()
        supervisor.close()


def released(store: PostgresJobStore) -> Callable[[], object]:
    return lambda: store.release("a", "w1")


def retried(store: PostgresJobStore) -> Callable[[], object]:
    store.finish("a", "failed", None, "boom", worker="w1")
    return lambda: store.retry("a", "host")


def died(store: PostgresJobStore) -> Callable[[], object]:
    return lambda: store.requeue("a", "w1", "the worker process died")


def stalled(store: PostgresJobStore) -> Callable[[], object]:
    """The look for stalled claims, once the claim's registration has been silent for
    longer than its lease (and the database up for longer than that)."""
    up = float(store._rows("SELECT EXTRACT(EPOCH FROM now() - pg_postmaster_start_time())")[0][0])
    time.sleep(max(LEASE * 1.5, LEASE - up))
    return lambda: store.expire(time.time())


QUEUED_AGAIN: dict[str, tuple[Callable[[PostgresJobStore], Callable[[], object]], float]] = {
    "released by its stopping worker": (released, 0.0),
    "retried by id after it failed": (retried, 0.0),
    "requeued after its worker died": (died, PAUSE),
    "requeued as a stalled claim": (stalled, PAUSE),
}
"""How a running job "a" (claimed by w1) is queued again: the setup, which returns the
action, and the pause before the job may be claimed again [s]."""


@pytest.mark.parametrize("how", sorted(QUEUED_AGAIN))
def test_an_idle_worker_claims_a_job_queued_again_as_soon_as_it_may_not_at_its_poll(paused,
                                                                                   how):
    setup, pause = QUEUED_AGAIN[how]
    paused.create("a", SCENE, "host")
    assert claim(paused) == "a"
    took = idle_pickup(paused, setup(paused))
    assert pause * 0.9 <= took < POLL / 3, took  # its pause honoured, its poll not awaited
    record = paused.get("a")
    assert (record.worker, record.infra_failures) == ("idle", 1 if pause else 0)
