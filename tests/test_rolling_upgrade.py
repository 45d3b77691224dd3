"""A rolling upgrade on one PostgreSQL database: a worker node of the previous version
(`PREVIOUS`, run from a checkout of it) runs on the store before any process of this
version opens it; then it solves plans submitted to an API server of this version (which
migrated the store), a node of this version starts beside it and the old node is stopped,
draining (`UNDERTOW_DRAIN`). Every plan succeeds, each claimed once, none a dead letter,
and the old node's running plans end on it (docs/deploy.md, "Upgrading a cluster"). A
node of this version does not start beside a running node of a release before da7fea7,
which could not run beside a status the database derives (`app.store.postgres_status`)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_fixtures import two_link_scene

from app.store.postgres import PostgresJobStore
from app.store.postgres_status import derived
from app.worker_node import REFUSED
from bench import harness
from testbed.cluster import FAKE_SOLVER, WorkerNode, api_server
from testbed.service import ROOT, wait_final, wait_for

PREVIOUS = "cc6413d253d370cb21901fbd112973ef527ff98f"
"""The previous version: the commit before the database derived each job's status from
its engine job's; its nodes write the status themselves, as the database derives it."""
SETTINGS = {"UNDERTOW_SOLVE_FUNCTION": FAKE_SOLVER, "UNDERTOW_LEASE": "20",
            "UNDERTOW_MAX_QUEUED": "64", "UNDERTOW_DRAIN": "30"}


EARLIER = "cac726093098fa8591abbde1b1980f4472c7188e"
"""A release before da7fea7, whose nodes claim only jobs whose status reads queued."""


def checkout(rev: str) -> Iterator[Path]:
    """A checkout of `rev` (skipped in a shallow clone, which may lack it)."""
    shallow = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"],
                             capture_output=True, text=True, check=True).stdout.strip()
    if shallow == "true":
        pytest.skip(f"a shallow clone: commit {rev[:7]} may not be in it")
    with harness.checkout(rev) as path:
        yield path


@pytest.fixture
def previous() -> Iterator[Path]:
    yield from checkout(PREVIOUS)


@pytest.fixture
def earlier() -> Iterator[Path]:
    yield from checkout(EARLIER)


def _solving_two(store: PostgresJobStore, node: WorkerNode) -> list[str] | None:
    """The ids of the plans `node` solves, once it solves two."""
    ids = [r.id for r in store.list(status="running", limit=10)
           if node.owns(r.worker) and (r.progress or {}).get("phase") == "solving"]
    return ids if len(ids) == 2 else None


def test_a_node_of_the_previous_version_is_replaced_with_no_plan_run_twice(
        tmp_path, postgres_url, previous):
    url = postgres_url
    with contextlib.ExitStack() as stack:
        old = stack.enter_context(WorkerNode(tmp_path, "old", 2, UNDERTOW_DB_URL=url,
                                             **SETTINGS).of_version(previous))
        old.wait_up(url)
        store = PostgresJobStore(url, timeout=2.0)
        stack.callback(store.close)
        api = stack.enter_context(api_server(tmp_path, url, "api", **SETTINGS))
        http = stack.enter_context(httpx.Client(base_url=api.url, timeout=30))
        ids = [http.post("/v1/plans", json=two_link_scene(iterations=150)).json()["id"]
               for _ in range(6)]  # 3 s each
        solving = wait_for(lambda: _solving_two(store, old), 60, "the old node solving two")
        stack.enter_context(WorkerNode(tmp_path, "new", 2, UNDERTOW_DB_URL=url, **SETTINGS))
        old.proc.send_signal(signal.SIGTERM)
        assert old.proc.wait(30) == 0
        jobs = [wait_final(http, job_id, timeout=60) for job_id in ids]
    assert [(j["status"], j["dead_letter"]) for j in jobs] == [("succeeded", False)] * 6
    assert [sum(e["event"] == "claimed" for e in j["history"]) for j in jobs] == [1] * 6
    ended_on = {j["id"]: j["history"][0]["worker"] for j in jobs}
    assert all(old.owns(ended_on[job_id]) for job_id in solving)
    assert any(not old.owns(worker) for worker in ended_on.values())  # the new node took some


def test_a_node_does_not_start_beside_a_node_of_a_release_before_da7fea7(tmp_path, postgres_url,
                                                                         earlier):
    url = postgres_url
    with WorkerNode(tmp_path, "old", 1, UNDERTOW_DB_URL=url, **SETTINGS).of_version(earlier) \
            as old:
        old.wait_up(url)
        new = WorkerNode(tmp_path, "new", 1, UNDERTOW_DB_URL=url, **SETTINGS).start()
        assert new.proc is not None and new.proc.wait(60) == REFUSED
        said = new.log.read_text()
        assert "node(s) old:worker:" in said and "Traceback" not in said, said
        old.check()  # it runs on
    with contextlib.closing(PostgresJobStore(url, timeout=2.0)) as store:  # once it stopped
        assert derived(store._rows)
