"""Plan jobs through the app when things go wrong: plans too big for a worker, workers
that die, hang or ignore a cancel, a full queue, shutdown with queued jobs, a store that
is deleted, damaged or left with its write-ahead log. The fake solver (testbed/fake_solvers.py)
runs on real worker processes."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import httpx
import pytest
from service_fixtures import client, two_link_scene

from app.capacity import estimate_mb
from app.store import SqliteJobStore, StoreDamaged
from app.supervisor import CANCELLED_STOPPED, died, over_budget
from planner.scene import Scene
from testbed.fake_solvers import fake_plan
from testbed.service import LiveServer, wait_final


def chain(n: int) -> dict:
    """n links, even joints passive, odd ones active with a wave."""
    links = [{"length": 0.4, "mass": 1.0, "joint": "active" if k % 2 else "passive"}
             for k in range(n)]
    for link in links[1::2]:
        link["wave"] = {"amplitude": 0.04, "frequency": 3.0, "phase": 0.3}
    return {"links": links, "gravity": 9.81}


def wait_for(api, job_id: str, predicate, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        job = api.get(f"/v1/plans/{job_id}").json()
        if predicate(job):
            return job
        assert time.monotonic() < deadline, job
        time.sleep(0.05)


def post(api, **scene) -> str:
    r = api.post("/v1/plans", json=two_link_scene(**scene))
    assert r.status_code == 202, r.text
    return r.json()["id"]


def wait_idle(api, timeout: float = 30.0) -> None:
    """Until no job of the server is queued or running (earlier tests' jobs have ended)."""
    deadline = time.monotonic() + timeout
    while any(api.get(f"/v1/plans?status={s}").json()["items"] for s in ("queued", "running")):
        assert time.monotonic() < deadline, "jobs still unfinished"
        time.sleep(0.05)


def fake_server(folder: Path) -> LiveServer:
    """A live uvicorn with one worker running the fake solver."""
    return LiveServer(folder / "jobs.sqlite3", UNDERTOW_WORKERS="1",
                      UNDERTOW_SOLVE_FUNCTION="testbed.fake_solvers:fake_plan")


def wait_gone(group: int, timeout: float = 30.0) -> None:
    """Until no process of the process group is left."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return
        assert time.monotonic() < deadline, "a process of the server outlived it"
        time.sleep(0.05)


def solving(job: dict) -> bool:
    return job["progress"] is not None and job["progress"].get("phase") == "solving"


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("faults"), solve=fake_plan, workers=2, max_queued=2,
                wall_time_grace=1.0, max_retries=1, retry_backoff=0.1) as c:
        yield c


def test_a_plan_too_big_for_a_worker_is_refused_before_it_runs(api):
    scene = {"robot": chain(8), "task": {
        "duration": 1.0, "initial": {"q": [0.0] * 8, "dq": [0.0] * 8},
        "final": {"q": [0.5] * 8, "dq": [0.0] * 8}},
        "transcription": {"method": "multiple-shooting", "intervals": 10, "steps": 20}}
    needed = estimate_mb(Scene.model_validate(scene))
    assert needed > 4096
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    [error] = r.json()["errors"]
    assert error["loc"] == ["body", "transcription", "steps"] and error["type"] == "limit"
    assert error["msg"] == (f"this plan's NLP needs about {needed:.0f} MB, more than the 4096 MB "
                            "a solver worker may use on this server (UNDERTOW_WORKER_MEMORY_MB): "
                            "use fewer RK4 steps per interval, or fewer links")
    scene["transcription"] = {"method": "radau", "degree": 9, "intervals": 200}
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 202, r.text  # 1800 knots of 8 links fit
    api.delete(f"/v1/plans/{r.json()['id']}")


def test_a_dead_worker_requeues_only_its_own_job_then_dead_letters_it(api):
    wait_idle(api)
    neighbour = post(api, iterations=500)  # 10 s on one worker
    wait_for(api, neighbour, solving)
    crash = post(api, tol=0.95)  # kills every worker that takes it
    job = wait_final(api, crash)
    assert (job["status"], job["dead_letter"], job["infra_failures"]) == ("failed", True, 2)
    assert job["error"] == (f"dead letter: {died(3)}; it failed for infrastructure reasons "
                            "2 times (UNDERTOW_MAX_RETRIES=1)")
    assert [e["event"] for e in job["history"]] == ["claimed", "infrastructure-failure"] * 2
    dead = api.get("/v1/plans?dead_letter=true").json()["items"]
    assert [j["id"] for j in dead] == [crash]
    assert crash not in [j["id"] for j in api.get("/v1/plans?dead_letter=false").json()["items"]]
    assert api.get(f"/v1/plans/{neighbour}").json()["status"] == "running"
    assert wait_final(api, neighbour)["status"] == "succeeded"
    assert wait_final(api, post(api))["status"] == "succeeded"  # a worker took its place


def test_a_failed_job_is_queued_again_by_id(api):
    wait_idle(api)
    failing = post(api, tol=0.6)  # Maximum_Iterations_Exceeded, a solver failure
    first = wait_final(api, failing)
    assert (first["status"], first["dead_letter"]) == ("failed", False)
    r = api.post(f"/v1/plans/{failing}/retry")
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/v1/plans/{failing}"
    # the answer is the job as read back after it was queued: an idle worker may have
    # claimed it (or even ended it) by then, on a busy machine more often than not
    answered = r.json()
    assert answered["status"] in ("queued", "running") and answered["error"] is None \
        or answered["attempts"] == 2
    again = wait_final(api, failing)
    assert (again["status"], again["attempts"]) == ("failed", 2)
    assert [e["event"] for e in again["history"]] == [
        "claimed", "finished", "retried", "claimed", "finished"]
    done = post(api)
    wait_final(api, done)
    r = api.post(f"/v1/plans/{done}/retry")
    assert (r.status_code, r.json()["type"]) == (409, "urn:undertow:problem:not-finished")
    assert api.post("/v1/plans/nope/retry").status_code == 404


def test_a_build_that_outlasts_its_budget_is_stopped(api):
    stuck = post(api, tol=0.85, duration=60.0, wall_time=1.0)  # a 60 s "build", 1 s budget
    job = wait_final(api, stuck, timeout=20)
    assert (job["status"], job["error"], job["plan"]) == ("failed", over_budget(1.0, 1.0), None)
    assert wait_final(api, post(api))["status"] == "succeeded"


def test_progress_says_building_and_a_cancel_stops_the_build(api):
    job_id = post(api, tol=0.85, duration=60.0)
    running = wait_for(api, job_id, lambda j: j["status"] == "running")
    assert running["progress"] == {"phase": "building", "iteration": 0, "objective": None,
                                   "inf_pr": None, "inf_du": None, "elapsed": 0.0,
                                   "mesh_pass": 0}
    asked = time.monotonic()
    assert api.delete(f"/v1/plans/{job_id}").status_code == 202
    job = wait_final(api, job_id, timeout=20)
    assert (job["status"], job["error"]) == ("cancelled", CANCELLED_STOPPED)
    assert time.monotonic() - asked < 10  # not the build's 60 s


def test_cancelled_queued_plans_free_their_places(api):
    wait_idle(api)
    ids = [post(api, iterations=1000) for _ in range(4)]  # 2 workers + 2 queued places
    for job_id in ids[:2]:
        wait_for(api, job_id, lambda j: j["status"] == "running")
    refused = api.post("/v1/plans", json=two_link_scene())
    assert refused.status_code == 429
    queued = [j for j in ids if api.get(f"/v1/plans/{j}").json()["status"] == "queued"]
    for job_id in queued:
        assert api.delete(f"/v1/plans/{job_id}").json()["status"] == "cancelled"
    assert len(queued) == 2
    taken = api.post("/v1/plans", json=two_link_scene())
    assert taken.status_code == 202, taken.text
    for job_id in ids:
        api.delete(f"/v1/plans/{job_id}")
    assert wait_final(api, taken.json()["id"])["status"] == "succeeded"


def test_no_state_of_one_job_leaks_into_the_next(tmp_path):
    with client(tmp_path, solve=fake_plan, workers=1) as api:
        first, refused = post(api, iterations=15), post(api, tol=0.75)
        done, job = wait_final(api, first), wait_final(api, refused)
    assert (done["status"], done["progress"]["iteration"]) == ("succeeded", 14)
    assert (job["status"], job["error"]) == (
        "failed", "Invalid_Problem_Definition: Invalid_Problem_Definition")
    assert job["progress"]["phase"] == "building" and job["progress"]["iteration"] == 0
    assert (job["plan"]["solver"]["status"], job["plan"]["solver"]["iterations"]) == (
        "Invalid_Problem_Definition", 0)


def test_sigterm_releases_running_jobs_and_keeps_queued_ones_queued(tmp_path):
    live = fake_server(tmp_path)
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        running = post(api, iterations=100)
        queued = [post(api) for _ in range(3)]
        wait_for(api, running, solving)
        live.stop(signal.SIGTERM)
        wait_gone(live.proc.pid)  # the server and every worker it started
        store = SqliteJobStore(tmp_path / "jobs.sqlite3")
        released = store.get(running)
        assert (released.status, released.error, released.infra_failures) == (
            "queued", None, 0)
        assert [(store.get(j).status, store.get(j).started) for j in queued] == [
            ("queued", None)] * 3
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        assert [wait_final(api, j)["status"] for j in [running, *queued]] == ["succeeded"] * 4


@pytest.mark.parametrize("name", ["e2e", "other"])
def test_a_second_server_that_cannot_start_leaves_the_first_ones_job_alone(tmp_path, name):
    """`make serve` twice in one checkout: the second server, of the same name or another,
    on the same store and port, exits without touching the job the first one runs."""
    first = fake_server(tmp_path)
    with first, httpx.Client(base_url=first.url, timeout=30) as api:
        job_id = post(api, iterations=6000)  # 120 s: still running however slowly the
        wait_for(api, job_id, solving)  # second server starts, and then cancelled
        second = LiveServer(first.db_path, port=first.port, UNDERTOW_INSTANCE=name,
                            UNDERTOW_WORKERS="1",
                            UNDERTOW_SOLVE_FUNCTION="testbed.fake_solvers:fake_plan")
        second.log = tmp_path / "second.log"
        assert second.refused() != 0, second.log.read_text()
        said = second.log.read_text()
        assert "Traceback" not in said
        assert (name != "e2e" or "another server named 'e2e' runs on the job store" in said)
        during = api.get(f"/v1/plans/{job_id}").json()
        assert (during["status"], during["attempts"], during["infra_failures"]) == (
            "running", 1, 0), during
        assert [e["event"] for e in during["history"]] == ["claimed"]
        assert api.delete(f"/v1/plans/{job_id}").status_code == 202  # stopping
        done = wait_final(api, job_id)
        assert (done["status"], done["attempts"], done["infra_failures"]) == (
            "cancelled", 1, 0), done
        assert api.get("/healthz").status_code == 200


def test_ctrl_c_stops_server_and_workers_with_json_log_lines_only(tmp_path):
    live = fake_server(tmp_path)
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        running = post(api, iterations=1000)
        wait_for(api, running, solving)
        os.killpg(live.proc.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches every process
        live.proc.wait(30)
        wait_gone(live.proc.pid)
    store = SqliteJobStore(tmp_path / "jobs.sqlite3")
    assert (store.get(running).status, store.get(running).error) == ("queued", None)
    for line in live.log.read_text().splitlines():
        assert json.loads(line)["level"] in ("INFO", "WARNING"), line


def test_a_deleted_store_answers_503_everywhere(tmp_path):
    with client(tmp_path, solve=fake_plan) as api:
        done = post(api)
        wait_final(api, done)
        os.unlink(tmp_path / "jobs.sqlite3")
        for method, path, body in (("get", "/healthz", None), ("get", "/metrics", None),
                                   ("post", "/v1/plans", two_link_scene()),
                                   ("get", f"/v1/plans/{done}", None)):
            r = api.request(method, path, json=body)
            assert r.status_code == 503, (path, r.text)
            assert r.headers["content-type"] == "application/problem+json"
            problem = r.json()
            assert problem["type"] == "urn:undertow:problem:unavailable"
            assert "was deleted or replaced while the service ran" in problem["detail"]


def test_a_clean_shutdown_leaves_every_plan_in_the_main_file(tmp_path):
    with client(tmp_path, solve=fake_plan) as api:
        ids = [post(api) for _ in range(7)]
        for job_id in ids:
            wait_final(api, job_id)
    (tmp_path / "jobs.sqlite3-wal").unlink(missing_ok=True)
    store = SqliteJobStore(tmp_path / "jobs.sqlite3")
    assert [store.get(j).status for j in ids] == ["succeeded"] * 7


def test_a_store_that_fails_its_integrity_check_stops_the_start(tmp_path):
    (tmp_path / "jobs.sqlite3").write_bytes(b"\0garbage" * 1000)
    with (pytest.raises(StoreDamaged, match="failed its integrity check.*refusing to start"),
          client(tmp_path, solve=fake_plan)):
        pass


def test_workers_that_cannot_start_make_health_503(tmp_path, monkeypatch):
    from broken_solver import broken_plan

    monkeypatch.setenv("UNDERTOW_TEST_BREAK_WORKERS", "1")  # the workers' import fails
    with client(tmp_path, solve=broken_plan) as api:
        assert api.post("/v1/plans", json=two_link_scene()).status_code == 202  # workers start
        deadline = time.monotonic() + 60
        while (r := api.get("/healthz")).status_code == 200:
            assert time.monotonic() < deadline, "health stayed 200"
            time.sleep(0.1)
        assert r.status_code == 503 and r.json()["detail"].startswith(
            "no solver worker process could start (")
        assert api.get("/metrics").status_code == 503


def refused(api, what: str) -> None:
    """POST /v1/plans and /healthz answer 503 problems naming `what`."""
    for method, path, body in (("post", "/v1/plans", two_link_scene()),
                               ("get", "/healthz", None)):
        r = api.request(method, path, json=body)
        assert r.status_code == 503, (path, r.text)
        assert r.headers["content-type"] == "application/problem+json"
        assert what in r.json()["detail"], r.json()


def test_a_deleted_write_ahead_log_refuses_new_plans_and_loses_none(tmp_path):
    live = fake_server(tmp_path)
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        accepted = [post(api) for _ in range(3)] + [post(api, iterations=1000)]
        wait_for(api, accepted[0], lambda j: j["status"] == "succeeded")
        os.unlink(tmp_path / "jobs.sqlite3-wal")
        for _ in range(3):
            refused(api, "write-ahead log")
        os.killpg(live.proc.pid, signal.SIGKILL)  # the worst end: nothing shuts down cleanly
        live.proc.wait(30)
        wait_gone(live.proc.pid)
    with live, httpx.Client(base_url=live.url, timeout=30) as api:
        for job_id in accepted:  # every plan that was answered 202 is still known
            assert api.get(f"/v1/plans/{job_id}").status_code == 200
        assert [wait_final(api, j)["status"] for j in accepted[:3]] == ["succeeded"] * 3
        api.delete(f"/v1/plans/{accepted[3]}")


@pytest.mark.parametrize("damage", ["garbage", "pages"])
def test_a_store_overwritten_in_place_refuses_new_plans_and_health(tmp_path, damage):
    with client(tmp_path, solve=fake_plan) as api:
        done = [post(api) for _ in range(3)]
        for job_id in done:
            wait_final(api, job_id)
        path = tmp_path / "jobs.sqlite3"
        api.app.state.store.checkpoint(final=True)
        data = bytearray(path.read_bytes())
        start = 0 if damage == "garbage" else 4096  # the whole file, or all but its header
        data[start:] = b"\xa5" * (len(data) - start)
        with open(path, "r+b") as file:  # in place: the same inode
            file.write(bytes(data))
        refused(api, "job store")


def test_an_idempotency_key_makes_a_resubmission_answer_with_the_first_job(api):
    wait_idle(api)
    headers = {"Idempotency-Key": "sweep-7/point-3"}
    first = api.post("/v1/plans", json=two_link_scene(), headers=headers)
    assert first.status_code == 202, first.text
    again = api.post("/v1/plans", json=two_link_scene(), headers=headers)
    assert again.json()["id"] == first.json()["id"]
    assert again.headers["location"] == first.headers["location"]
    wait_final(api, first.json()["id"])
    done = api.post("/v1/plans", json=two_link_scene(), headers=headers)
    assert (done.status_code, done.json()["id"]) == (200, first.json()["id"])
    other = api.post("/v1/plans", json=two_link_scene(), headers={"Idempotency-Key": "x"})
    assert other.json()["id"] != first.json()["id"]
    api.delete(f"/v1/plans/{other.json()['id']}")
