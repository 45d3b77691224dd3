"""Roles: an API-only server and a worker node sharing a SQLite store on one machine;
and beyond one machine, on loopback: two API-only servers and two worker nodes sharing one
PostgreSQL job store (the fake solver, 20 ms per iteration). Plans submitted to either
server run on either node; a cancel sent to one server stops the solve a node runs for a
plan submitted to the other; a node killed with SIGKILL mid-solve loses no plan: its job's
lease runs out, the job is requeued once and the other node finishes it."""

from __future__ import annotations

import contextlib
import signal
import time

import httpx
import pytest
from service_fixtures import two_link_scene

from app.store.postgres import PostgresJobStore
from testbed.cluster import FAKE_SOLVER, WorkerNode, api_server, solving_on
from testbed.service import LiveServer, free_port, wait_final, wait_for

LEASE = 3.0  # [s] short, so that a lost node's job is requeued quickly
PLANS = 40
SETTINGS = {"UNDERTOW_SOLVE_FUNCTION": FAKE_SOLVER, "UNDERTOW_LEASE": str(LEASE),
            "UNDERTOW_MAX_QUEUED": "64"}


@pytest.fixture
def cluster(tmp_path, postgres_url):
    """(API a, API b, node 1, node 2, the store) on one new database."""
    store = PostgresJobStore(postgres_url)  # migrates before the servers start
    with contextlib.ExitStack() as stack:
        apis = [stack.enter_context(api_server(tmp_path, postgres_url, name, **SETTINGS))
                for name in ("api-a", "api-b")]
        nodes = [stack.enter_context(WorkerNode(tmp_path, name, UNDERTOW_DB_URL=postgres_url,
                                                **SETTINGS))
                 for name in ("node-1", "node-2")]
        yield (*apis, *nodes, store)
    store.close()


def test_two_apis_and_two_workers_lose_no_plan_when_a_worker_is_killed(cluster):
    api_a, api_b, node_1, node_2, store = cluster
    a = httpx.Client(base_url=api_a.url, timeout=10)
    b = httpx.Client(base_url=api_b.url, timeout=10)

    # a cancel sent to one server stops a solve running for a plan sent to the other
    long = a.post("/v1/plans", json=two_link_scene(iterations=3000)).json()["id"]

    def iterating() -> bool:
        node_1.check()
        node_2.check()
        return (b.get(f"/v1/plans/{long}").json()["progress"] or {}).get("iteration", 0) > 2

    wait_for(iterating, 60, "progress of the long plan, read through the other server")
    holder = store.get(long).worker
    assert node_1.owns(holder) or node_2.owns(holder)
    asked = time.monotonic()
    assert b.delete(f"/v1/plans/{long}").status_code == 202
    cancelled = wait_final(a, long, timeout=10)
    assert (cancelled["status"], cancelled["plan"]["solver"]["status"]) == (
        "cancelled", "User_Requested_Stop")
    assert time.monotonic() - asked < 5.0  # the next iteration, not the budget's end

    # 40 plans across both servers; node 1 is killed while it solves one of them
    ids = [(a if k % 2 else b).post("/v1/plans", json=two_link_scene(iterations=25)).json()["id"]
           for k in range(PLANS)]
    lost = wait_for(lambda: solving_on(store, node_1), 60, "node 1 solving a plan")
    node_1.kill()
    jobs = [wait_final(a if k % 2 else b, job_id, timeout=120) for k, job_id in enumerate(ids)]
    assert [job["status"] for job in jobs] == ["succeeded"] * PLANS
    finished_by = {job_id: store.get(job_id).worker for job_id in ids}
    assert node_2.owns(finished_by[lost])  # requeued, then solved by the node still up
    attempts = dict(store._rows("SELECT id, attempts FROM jobs WHERE id = ANY(%s)", (ids,)))
    assert attempts[lost] == 2 and sum(attempts.values()) == PLANS + 1  # one requeue only
    counts = store.count_by_status()
    assert (counts["queued"], counts["running"]) == (0, 0)  # none stuck
    assert node_2.proc.poll() is None
    for api in (a, b):
        assert api.get("/healthz").status_code == 200
    def node_1_gone() -> dict | None:  # node 1 stopped beating with its death
        live = a.get("/v1/workers").json()
        names = [w["name"].split(":")[0] for w in live["items"]]
        return live if names == ["node-2"] else None

    live = wait_for(node_1_gone, 20, "node 1 leaving the list of live workers")
    assert live["processes"] == 1 and live["busy"] <= 1  # as of its last heartbeat


def test_an_api_only_server_queues_and_a_worker_node_solves(tmp_path):
    db = tmp_path / "jobs.sqlite3"
    with LiveServer(db, UNDERTOW_WORKERS="0", UNDERTOW_SOLVE_FUNCTION=FAKE_SOLVER) as api:
        http = httpx.Client(base_url=api.url, timeout=10)
        job = http.post("/v1/plans", json=two_link_scene()).json()["id"]
        time.sleep(1.0)
        assert http.get(f"/v1/plans/{job}").json()["status"] == "queued"  # no workers here
        port = free_port()
        node = WorkerNode(tmp_path, "node", UNDERTOW_DB_PATH=str(db),
                          UNDERTOW_SOLVE_FUNCTION=FAKE_SOLVER, UNDERTOW_LOG_LEVEL="INFO")
        node.args = ("--metrics-port", str(port))
        with node:
            assert wait_final(http, job, timeout=60)["status"] == "succeeded"
            metrics = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=10).text
            assert ('undertow_worker_solve_duration_seconds_count{status="succeeded"} 1.0'
                    in metrics)
            for line in ("undertow_worker_processes 1.0", "undertow_worker_busy_processes 0.0",
                         "undertow_worker_up 1.0"):
                assert line in metrics.splitlines(), metrics
            node.proc.send_signal(signal.SIGTERM)
            assert node.proc.wait(30) == 0
        assert http.get("/healthz").status_code == 200
    log = node.log.read_text()
    assert f"job {job} succeeded" in log and "stopping" in log
