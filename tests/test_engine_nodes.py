"""A node's liveness on PostgreSQL is its queue engine registration
(`app.store.postgres_nodes`): one registration per node, made by its first heartbeat or
claim, named by its `workers` row; its heartbeat is what `workers` lists and what holds
every claim of the node's solver processes; a job's end leaves it; a node that stops, or
is silent for an hour, is forgotten with it."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from app.store.postgres import PostgresJobStore
from app.store.postgres_nodes import FORGOTTEN, node_of

SCENE = {"robot": {"links": []}}
LEASE = 0.5  # [s]


@pytest.fixture
def store(postgres_url: str) -> Iterator[PostgresJobStore]:
    s = PostgresJobStore(postgres_url, lease=LEASE)
    yield s
    s.close()


def registrations(store: PostgresJobStore) -> list[int]:
    return [row[0] for row in store._rows("SELECT id FROM procrastinate_workers ORDER BY id")]


def node_registration(store: PostgresJobStore, node: str) -> int | None:
    rows = store._rows("SELECT engine_worker FROM workers WHERE name = %s", (node,))
    return rows[0][0] if rows else None


def held_by(store: PostgresJobStore, job_id: str) -> int | None:
    """The engine registration that holds job `job_id`'s claim."""
    return store._rows("SELECT q.worker_id FROM undertow_queue m JOIN procrastinate_jobs q "
                       "ON q.id = m.queue_id WHERE m.job_id = %s", (job_id,))[0][0]


def silent(store: PostgresJobStore, registration: int, seconds: float) -> None:
    """Set the registration's last heartbeat `seconds` back."""
    store._rows("UPDATE procrastinate_workers SET last_heartbeat = now() - "
                "make_interval(secs => %s) WHERE id = %s", (seconds, registration))


def test_a_worker_name_names_its_node():
    assert node_of("host:worker:12/3/ab12cd34") == "host:worker:12"
    assert node_of("api/with/slash/0/ab12cd34") == "api/with/slash"
    assert node_of("w1") == "w1"


@pytest.mark.parametrize("before", ["no row", "a row whose registration was removed"])
def test_the_processes_of_a_node_claim_under_its_one_registration(store, before):
    if before != "no row":  # as a node of an earlier version leaves it when it settles
        store.heartbeat("node", 2, 0, 100.0)
        store._rows("SELECT procrastinate_unregister_worker_v1(%s)",
                    (node_registration(store, "node"),))
    for job_id in ("a", "b"):
        store.create(job_id, SCENE, "host")
    barrier = threading.Barrier(2)

    def claim(slot: int) -> None:
        barrier.wait()
        store.claim(None, f"node/{slot}/x", time.time() + LEASE)

    threads = [threading.Thread(target=claim, args=(slot,)) for slot in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    registered = node_registration(store, "node")
    assert registrations(store) == [registered]
    assert held_by(store, "a") == held_by(store, "b") == registered


def test_the_nodes_heartbeat_is_its_listing_and_its_claims_lease(store):
    store.heartbeat("node", 2, 0, 100.0)
    [listed] = store.workers(time.time() - 5.0)
    assert (listed.name, listed.processes, listed.busy, listed.started) == ("node", 2, 0, 100.0)
    assert abs(listed.seen - time.time()) < 2.0  # the database's heartbeat, in our clock
    assert store._rows("SELECT seen FROM workers")[0][0] is None  # no heartbeat of its own
    store.create("a", SCENE, "host")
    assert store.claim(None, "node/0/x", time.time() + LEASE).id == "a"  # type: ignore[union-attr]
    assert held_by(store, "a") == node_registration(store, "node")
    for _ in range(6):  # 1.2 s, over two leases, with the node's heartbeats alone
        time.sleep(LEASE * 0.4)
        store.heartbeat("node", 2, 1, 100.0)
    assert store.expire(time.time()) == {}
    time.sleep(LEASE * 1.2)  # then silent for longer than the lease
    assert store.expire(time.time()) == {"a": "queued"}
    assert registrations(store) == [node_registration(store, "node")]  # kept for the node


def test_a_jobs_end_leaves_the_nodes_other_claims_held(store):
    for job_id in ("a", "b"):
        store.create(job_id, SCENE, "host")
    store.claim(None, "node/0/x", time.time() + LEASE)
    store.claim(None, "node/1/y", time.time() + LEASE)
    assert store.finish("a", "succeeded", {"k": 1}, None, worker="node/0/x")
    assert store.renew([("b", "node/1/y")], time.time() + LEASE) == {"b": False}
    assert store.expire(time.time()) == {}
    assert held_by(store, "b") == node_registration(store, "node")


def test_a_silent_node_is_not_listed_and_is_forgotten_after_an_hour(store):
    store.heartbeat("gone", 1, 0, 100.0)
    store.heartbeat("quiet", 1, 0, 100.0)
    silent(store, node_registration(store, "quiet"), 60.0)  # type: ignore[arg-type]
    silent(store, node_registration(store, "gone"), FORGOTTEN + 60.0)  # type: ignore[arg-type]
    store.heartbeat("here", 1, 0, 100.0)
    assert [w.name for w in store.workers(time.time() - 15.0)] == ["here"]
    assert [w.name for w in store.workers(time.time() - 120.0)] == ["here", "quiet"]
    assert sorted(registrations(store)) == sorted(
        [node_registration(store, "here"), node_registration(store, "quiet")])


def test_a_stopped_node_is_forgotten_with_its_registration(store):
    store.heartbeat("node", 1, 0, 100.0)
    store.heartbeat("other", 1, 0, 100.0)
    store.forget_worker("node")
    assert [w.name for w in store.workers(0.0)] == ["other"]
    assert registrations(store) == [node_registration(store, "other")]


def test_a_registration_removed_by_an_earlier_version_is_made_again(store):
    store.heartbeat("node", 1, 0, 100.0)
    first = node_registration(store, "node")
    store._rows("SELECT procrastinate_unregister_worker_v1(%s)", (first,))  # as it settles
    store.heartbeat("node", 1, 0, 100.0)
    again = node_registration(store, "node")
    assert again != first and registrations(store) == [again]
    assert [w.name for w in store.workers(time.time() - 5.0)] == ["node"]


def test_a_node_of_an_earlier_version_is_listed_by_its_own_heartbeat(store):
    store._rows("INSERT INTO workers (name, processes, busy, started, seen) "
                "VALUES ('old', 2, 1, 1.0, %s)", (time.time(),))
    [listed] = store.workers(time.time() - 5.0)
    assert (listed.name, listed.processes, listed.busy) == ("old", 2, 1)
