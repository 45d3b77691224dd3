"""End to end against a real uvicorn process on 127.0.0.1 with the real planner.

One fixture server runs for the module; the restart and crash tests start their own
servers on a temporary store.
"""

from __future__ import annotations

import os
import signal
import time

import httpx
import pytest
from service_fixtures import TWO_LINK

from app.routes.examples import ENDPOINTS
from testbed.service import LiveServer, wait_final

QUICK = {"robot": TWO_LINK,
         "task": {"duration": 2.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                  "final": {"q": [1.0, None], "dq": [0.0, 0.0]}},
         "transcription": {"intervals": 50}}  # 10 or 20: optimal, yet 0.3 rad off in re-simulation
# An unreachable tip under a torque limit: Ipopt iterates for seconds before it gives up.
LONG = {"robot": TWO_LINK,
        "task": {"duration": 2.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                 "final": {"q": [None, None], "dq": [0.0, 0.0]},
                 "tip_target": {"x": 0.6, "y": 0.6}, "torque_limit": 0.02},
        "transcription": {"intervals": 120}, "solver": {"max_iter": 100000, "max_wall_time": 60}}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with LiveServer(tmp_path_factory.mktemp("e2e") / "jobs.sqlite3") as live:
        yield live


def wait_running(http: httpx.Client, job_id: str, timeout: float = 60.0) -> dict:
    """Poll until the job reports Ipopt progress (past the NLP build)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/plans/{job_id}").json()
        if job["progress"] is not None and job["progress"]["phase"] == "solving":
            return job
        assert job["status"] in ("queued", "running"), job
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} reported no progress in {timeout} s")


def test_plan_then_fetch_it_again_after_a_restart(tmp_path):
    live = LiveServer(tmp_path / "jobs.sqlite3")
    with live, httpx.Client(base_url=live.url, timeout=60) as http:
        r = http.post("/v1/plans?wait=30", json=QUICK)
        assert r.status_code == 200, r.text
        job = r.json()
        assert job["status"] == "succeeded", job["error"]
        plan = job["plan"]
        assert plan["solver"]["success"] and plan["verification"]["verified"]
        assert len(plan["t"]) == 51 and plan["t"][-1] == 2.0
        assert plan["q"][0] == [0.0, 0.0] and plan["q"][-1][0] == pytest.approx(1.0, abs=1e-6)
        assert http.get(f"/v1/plans/{job['id']}").json() == job
    with live, httpx.Client(base_url=live.url, timeout=60) as http:
        assert http.get(f"/v1/plans/{job['id']}").json() == job


def test_cancel_stops_a_long_plan(server):
    with httpx.Client(base_url=server.url, timeout=60) as http:
        job_id = http.post("/v1/plans", json=LONG).json()["id"]
        running = wait_running(http, job_id)
        asked = time.monotonic()
        assert http.delete(f"/v1/plans/{job_id}").status_code == 202
        job = wait_final(http, job_id, timeout=20)
        took = time.monotonic() - asked
    assert job["status"] == "cancelled", job
    assert job["plan"]["solver"]["status"] == "User_Requested_Stop"
    assert job["plan"]["solver"]["iterations"] >= running["progress"]["iteration"]
    assert took < 3.0


def test_every_example_runs_on_its_endpoint(server):
    with httpx.Client(base_url=server.url, timeout=300) as http:
        listed = http.get("/v1/examples").json()
        assert listed
        for item in listed:
            path = ENDPOINTS[item["kind"]]
            r = http.post(path, json=item["request"])
            assert r.status_code in (200, 202), (item["name"], r.text)
            if item["kind"] == "plan":
                job = wait_final(http, r.json()["id"], timeout=300)
                assert job["status"] == "succeeded", (item["name"], job["error"])
                assert http.get(f"/v1/plans/{job['id']}").json()["plan"] == job["plan"]
            elif item["kind"] == "wave-design":
                assert r.json()["status"] == "certified", item["name"]
            elif item["kind"] == "inverse-dynamics":
                expected = "singular" if item["name"].endswith("waveless") else "completed"
                assert r.json()["status"] == expected, item["name"]


def _alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def test_kill_9_during_a_solve_requeues_the_job_and_a_restart_runs_it(tmp_path):
    live = LiveServer(tmp_path / "jobs.sqlite3")
    with live, httpx.Client(base_url=live.url, timeout=60) as http:
        job_id = http.post("/v1/plans", json=LONG).json()["id"]
        wait_running(http, job_id)
        old_group = live.proc.pid
        live.stop(signal.SIGKILL)
        deadline = time.monotonic() + 20  # the orphaned worker notices and exits
        while _alive(old_group):
            assert time.monotonic() < deadline, "an orphaned worker kept running"
            time.sleep(0.1)
    with live, httpx.Client(base_url=live.url, timeout=60) as http:
        deadline = time.monotonic() + 60  # claimed again by the restarted server's worker
        while (job := http.get(f"/v1/plans/{job_id}").json())["attempts"] < 2:
            assert time.monotonic() < deadline, job
            time.sleep(0.1)
        assert (job["status"], job["infra_failures"], job["error"]) == ("running", 1, None)
        assert "main process died" in job["history"][1]["reason"]
        http.delete(f"/v1/plans/{job_id}")  # the unreachable tip would take its whole budget
        assert wait_final(http, job_id)["status"] == "cancelled"
        assert http.post("/v1/plans?wait=30", json=QUICK).json()["status"] == "succeeded"
