"""Message versions in a rolling upgrade: a worker that claims a job whose messages (its
scene and admission) are of a newer version than it knows gives it back, counted as
nothing, and claims nothing more, so that the job waits for a node of the newer version
instead of failing on a scene it would read wrongly."""

from __future__ import annotations

import multiprocessing
import time

from service_fixtures import two_link_scene

from app.admission import MESSAGE_VERSION, Admission, message_version
from app.store import SqliteJobStore
from app.worker import WorkerSpec, serve
from app.worker_pipe import READY, STOP
from testbed.fake_solvers import fake_plan
from testbed.service import wait_for


def admission(version: int) -> dict:
    return {**Admission(issues=[], warm_start=None).model_dump(mode="json"), "message": version}


def test_an_admission_carries_this_versions_messages_and_older_jobs_read_as_version_1(
        tmp_path):
    store = SqliteJobStore(tmp_path / "jobs.sqlite3")
    stored = Admission(issues=[], warm_start=None).model_dump(mode="json")
    assert stored["message"] == MESSAGE_VERSION
    assert message_version(store.create("a", two_link_scene(), "host", admission=stored)) \
        == MESSAGE_VERSION
    assert message_version(store.create("b", two_link_scene(), "host")) == 1
    store.close()


def test_a_job_of_a_newer_message_version_is_given_back_and_its_worker_retires(tmp_path):
    store = SqliteJobStore(tmp_path / "jobs.sqlite3")
    newer = MESSAGE_VERSION + 1
    store.create("newer", two_link_scene(), "host", admission=admission(newer))
    store.create("known", two_link_scene(), "host", admission=admission(MESSAGE_VERSION))
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()
    worker = context.Process(target=serve, args=(
        WorkerSpec(store, fake_plan, "host", "host/0/w", None, 60.0, "WARNING"), theirs))
    worker.start()
    try:
        assert ours.poll(60) and ours.recv() == READY
        released = wait_for(lambda: [e for e in store.get("newer").history or []
                                     if e["event"] == "released"], 30, "the job given back")
        assert released[0]["reason"] == (
            f"its messages are of version {newer}, newer than version {MESSAGE_VERSION} "
            "that this node knows: left to a node of a newer version")
        time.sleep(1.5)  # longer than the idle worker's poll: it claims nothing more
        assert [e["event"] for e in store.get("newer").history] == ["claimed", "released"]
        for job_id in ("newer", "known"):
            record = store.get(job_id)
            assert (record.status, record.attempts, record.infra_failures) == ("queued", 0, 0)
        assert [e["event"] for e in store.get("known").history or []] == []
    finally:
        ours.send(STOP)
        worker.join(10)
        store.close()
    assert worker.exitcode == 0
