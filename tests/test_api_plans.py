"""Plan job endpoints through the app, with the fake solver on a real worker process."""

from __future__ import annotations

import time

import pytest
from service_fixtures import client, two_link_scene

from testbed.fake_solvers import fake_plan
from testbed.service import wait_final


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("plans"), solve=fake_plan, workers=2,
                max_queued=1, max_wait=5.0, max_horizon=10.0, max_nodes=100,
                max_wall_time=30.0) as c:
        yield c


def errors_of(response) -> list[tuple[list, str]]:
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == "application/problem+json"
    return [(e["loc"], e["msg"]) for e in response.json()["errors"]]


def test_post_answers_202_with_a_location_then_the_plan_arrives(api):
    r = api.post("/v1/plans", json=two_link_scene(iterations=5))
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/plans/{job['id']}"
    assert job["status"] in ("queued", "running") and job["plan"] is None
    done = wait_final(api, job["id"])
    assert done["status"] == "succeeded" and done["error"] is None
    assert done["plan"]["solver"]["status"] == "Solve_Succeeded"
    assert done["progress"]["iteration"] == 4
    assert done["created"] <= done["started"] <= done["finished"]


def test_wait_returns_200_with_the_finished_job(api):
    r = api.post("/v1/plans?wait=5", json=two_link_scene(iterations=3))
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "succeeded" and r.json()["plan"]["duration"] == 1.0


def test_wait_gives_up_with_202_when_the_job_is_slower(api):
    start = time.monotonic()
    r = api.post("/v1/plans?wait=0.3", json=two_link_scene(iterations=50))
    assert r.status_code == 202 and 0.3 <= time.monotonic() - start < 3
    assert wait_final(api, r.json()["id"])["status"] == "succeeded"


def test_a_solver_failure_is_a_failed_job_that_keeps_its_plan(api):
    job = api.post("/v1/plans?wait=5", json=two_link_scene(tol=0.6)).json()
    assert job["status"] == "failed"
    assert job["error"] == "Maximum_Iterations_Exceeded: Maximum_Iterations_Exceeded"
    assert job["plan"]["solver"]["success"] is False


def test_delete_cancels_a_running_plan(api):
    job_id = api.post("/v1/plans", json=two_link_scene(iterations=1000)).json()["id"]
    deadline = time.monotonic() + 20
    while api.get(f"/v1/plans/{job_id}").json()["progress"] is None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    r = api.delete(f"/v1/plans/{job_id}")
    assert r.status_code == 202 and r.json()["cancel_requested"] is True
    done = wait_final(api, job_id, timeout=5)
    assert done["status"] == "cancelled"
    assert done["plan"]["solver"]["status"] == "User_Requested_Stop"
    again = api.delete(f"/v1/plans/{job_id}")
    assert again.status_code == 200 and again.json()["status"] == "cancelled"


def test_delete_cancels_a_queued_plan_before_it_starts(api):
    busy = [api.post("/v1/plans", json=two_link_scene(iterations=1000)).json()["id"]
            for _ in range(2)]  # both workers
    queued = api.post("/v1/plans", json=two_link_scene()).json()["id"]
    r = api.delete(f"/v1/plans/{queued}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    for job_id in busy:
        api.delete(f"/v1/plans/{job_id}")
    assert {wait_final(api, job_id)["status"] for job_id in busy} == {"cancelled"}
    time.sleep(0.3)  # the worker that takes the queued job up must skip it
    job = api.get(f"/v1/plans/{queued}").json()
    assert (job["status"], job["started"], job["plan"]) == ("cancelled", None, None)


def test_delete_of_a_finished_plan_is_a_conflict(api):
    job = api.post("/v1/plans?wait=5", json=two_link_scene()).json()
    r = api.delete(f"/v1/plans/{job['id']}")
    assert r.status_code == 409 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["detail"] == f"plan job '{job['id']}' ended as succeeded; nothing to cancel"


@pytest.mark.parametrize("method", ["get", "delete"])
def test_unknown_jobs_are_404_problems(api, method):
    r = getattr(api, method)("/v1/plans/no-such-job")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert (body["title"], body["detail"], body["instance"]) == (
        "No such plan job", "there is no plan job 'no-such-job'", "/v1/plans/no-such-job")


def test_a_full_queue_answers_429_with_retry_after(api):
    accepted, refused = [], []
    for _ in range(5):  # 2 workers + 1 queued slot
        r = api.post("/v1/plans", json=two_link_scene(iterations=40))
        (accepted if r.status_code == 202 else refused).append(r)
    assert len(accepted) == 3 and len(refused) == 2
    assert refused[0].status_code == 429 and refused[0].headers["retry-after"] == "5"
    assert refused[0].json()["type"] == "urn:undertow:problem:queue-full"
    for r in accepted:
        assert wait_final(api, r.json()["id"])["status"] == "succeeded"


def test_the_list_pages_newest_first_and_filters(api):
    api.post("/v1/plans?wait=5", json=two_link_scene(iterations=1, tol=0.6))  # it fails
    ids = [api.post("/v1/plans?wait=5", json=two_link_scene(iterations=1)).json()["id"]
           for _ in range(3)]
    page = api.get("/v1/plans?limit=2").json()
    assert [j["id"] for j in page["items"]] == ids[::-1][:2]
    assert page["next_offset"] == 2 and "plan" not in page["items"][0]
    nxt = api.get("/v1/plans?limit=2&offset=2").json()
    assert nxt["items"][0]["id"] == ids[0]
    failed = api.get("/v1/plans?status=failed&limit=100").json()["items"]
    assert failed and {j["status"] for j in failed} == {"failed"}


def test_scene_limits_are_field_errors(api):
    scene = two_link_scene(duration=20.0)
    scene["transcription"] = {"method": "legendre", "intervals": 30, "degree": 3}
    scene["solver"]["max_wall_time"] = 100.0
    assert errors_of(api.post("/v1/plans", json=scene)) == [
        (["body", "transcription", "intervals"],
         "120 nodes exceed this server's limit of 100 (UNDERTOW_MAX_NODES)"),
        (["body", "task", "duration"],
         "20 s exceeds this server's horizon limit of 10 s (UNDERTOW_MAX_HORIZON)"),
        (["body", "solver", "max_wall_time"],
         "100 s exceeds this server's limit of 30 s (UNDERTOW_MAX_WALL_TIME)")]


def test_an_unset_wall_time_is_capped_not_refused(api):
    scene = two_link_scene()
    job = api.post("/v1/plans?wait=5", json=scene).json()  # default 60 s > cap 30 s
    assert job["status"] == "succeeded"


def test_scene_and_query_validation(api):
    scene = two_link_scene()
    scene["task"]["initial"]["q"] = [0.0]
    assert errors_of(api.post("/v1/plans", json=scene)) == [
        (["body", "task", "initial", "q"], "needs 2 entries, one per joint")]
    assert errors_of(api.post("/v1/plans?wait=60", json=two_link_scene())) == [
        (["query", "wait"], "at most 5 s on this server (UNDERTOW_MAX_WAIT)")]
    assert errors_of(api.post("/v1/plans?wait=-1", json=two_link_scene())) == [
        (["query", "wait"], "Input should be greater than or equal to 0")]
    assert errors_of(api.get("/v1/plans?offset=100000000000000000000")) == [
        (["query", "offset"], "Input should be less than or equal to 1000000000")]
    assert errors_of(api.get("/v1/plans?status=done")) == [
        (["query", "status"],
         "Input should be 'queued', 'running', 'succeeded', 'failed' or 'cancelled'")]


def test_metrics_report_solve_durations_and_jobs_by_state(api):
    api.post("/v1/plans?wait=5", json=two_link_scene(iterations=2))
    deadline = time.monotonic() + 5  # the parent records the outcome right after the job
    while True:
        text = api.get("/metrics").text
        lines = [line for line in text.splitlines()
                 if line.startswith('undertow_solve_duration_seconds_count{status="succeeded"}')]
        if lines and float(lines[0].split()[-1]) >= 1 or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert lines and float(lines[0].split()[-1]) >= 1
    succeeded = api.get("/v1/plans?status=succeeded&limit=100").json()["items"]
    assert f'undertow_jobs{{state="succeeded"}} {float(len(succeeded))}' in text


def test_the_refinement_budget_is_bounded_by_the_node_limit(api):
    # max_nodes 100 here: Legendre degree 3 holds 4 nodes per interval, so at most 25
    scene = two_link_scene()
    scene["transcription"] = {"method": "legendre", "intervals": 10, "degree": 3,
                              "refinement": {"max_intervals": 30}}
    assert errors_of(api.post("/v1/plans", json=scene)) == [
        (["body", "transcription", "refinement", "max_intervals"],
         "30 intervals would hold 120 nodes, more than this server's limit of 100 "
         "(UNDERTOW_MAX_NODES): at most 25")]
