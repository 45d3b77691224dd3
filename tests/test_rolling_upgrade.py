"""A rolling upgrade on one PostgreSQL database: a worker node of the previous version
(`PREVIOUS`, run from a checkout of it) runs on the store before any process of this
version opens it; then it solves plans submitted to an API server of this version (which
migrated the store), a node of this version starts beside it and the old node is stopped,
draining (`UNDERTOW_DRAIN`). Every plan succeeds, each claimed once, none a dead letter,
and the old node's running plans end on it (docs/deploy.md, "Upgrading a cluster")."""

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
from bench import harness
from testbed.cluster import FAKE_SOLVER, WorkerNode, api_server
from testbed.service import ROOT, wait_final, wait_for

PREVIOUS = "cac726093098fa8591abbde1b1980f4472c7188e"
"""The previous version: the commit before nodes held their claims by one engine
registration per node, whose nodes register one for each claim (both drain)."""
SETTINGS = {"UNDERTOW_SOLVE_FUNCTION": FAKE_SOLVER, "UNDERTOW_LEASE": "20",
            "UNDERTOW_MAX_QUEUED": "64", "UNDERTOW_DRAIN": "30"}


@pytest.fixture
def previous() -> Iterator[Path]:
    """A checkout of PREVIOUS (skipped in a shallow clone, which may lack it)."""
    shallow = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"],
                             capture_output=True, text=True, check=True).stdout.strip()
    if shallow == "true":
        pytest.skip(f"a shallow clone: commit {PREVIOUS[:7]} may not be in it")
    with harness.checkout(PREVIOUS) as path:
        yield path


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
