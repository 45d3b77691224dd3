"""One place per decision: a plan job's scene is checked, and its warm start resolved, once,
when the job is submitted (`app.admission`); its worker's plan neither checks again nor
rewrites where it started from (`planner.service.plan` writes that itself)."""

from __future__ import annotations

import time

import pytest
from service_fixtures import client, two_link_scene

from app.admission import admit_members, admit_plan, given, stored
from app.errors import ApiError
from app.job_run import run_job
from app.store import JobStore, SqliteJobStore
from planner import feasibility, service
from planner.service import Scene
from testbed.fake_solvers import fake_plan
from testbed.service import wait_final


def scene(goal: float = 1.0, warm_start: str | None = None) -> Scene:
    """The two-link scene to `goal` [rad] on its first joint, enough iterations to plan."""
    data = two_link_scene(iterations=300)
    data["task"]["final"]["q"][0] = goal
    data["solver"]["warm_start"] = warm_start
    return Scene.model_validate(data)


def run(store: JobStore, job_id: str, task: Scene, admitted: bool = True) -> dict:
    """Store the job as the route does (admitted) or as an earlier version did, claim it and
    run it in this process with the planner; its plan's solver report."""
    admission = admit_plan(store, task).model_dump(mode="json") if admitted else None
    store.create(job_id, task.model_dump(mode="json"), "host", admission=admission)
    record = store.claim("host", "w", time.time() + 60)
    assert record is not None and record.id == job_id
    run_job(store, job_id, task, service.plan, worker="w", admission=stored(record))
    done = store.get(job_id)
    assert done is not None and done.status == "succeeded", done
    return (done.plan or {})["solver"]


@pytest.fixture
def counted(monkeypatch) -> list[Scene]:
    """Every scene `planner.feasibility.check` is called on from now."""
    calls: list[Scene] = []
    check = feasibility.check

    def counting(task: Scene) -> list[feasibility.Issue]:
        calls.append(task)
        return check(task)

    monkeypatch.setattr(feasibility, "check", counting)
    return calls


def test_a_jobs_plan_neither_checks_nor_resolves_again(tmp_path, counted):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    try:
        cold = run(store, "first", scene())
        assert len(counted) == 1  # at admission; the job's plan did not check again
        assert (cold["warm_start"], cold["warm_start_distance"]) == (None, None)
        near = scene(goal=1.01, warm_start="nearest")
        start = admit_plan(store, near).warm_start
        assert start is not None and start.job_id == "first"
        assert start.distance == pytest.approx(0.01)
        warm = run(store, "second", near)
        assert len(counted) == 3  # admitted twice (above, and as the job); the plan: none
        assert warm["strategy"] == "warm start"  # from the job resolved at admission
        assert (warm["warm_start"], warm["warm_start_distance"]) == ("first",
                                                                     pytest.approx(0.01))
        # a job stored without an admission (an earlier version's) is decided when it runs
        legacy = run(store, "legacy", near, admitted=False)
        assert len(counted) == 4 and counted[-1] == near  # the plan checked it
        assert (legacy["warm_start"], legacy["warm_start_distance"]) == ("second", 0.0)
    finally:
        store.close()


def test_a_batch_checks_its_members_once_and_leaves_nearest_to_their_claim(tmp_path):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    try:
        with pytest.raises(ApiError) as refused:
            admit_members(store, scene(warm_start="missing"), [scene(warm_start="missing")])
        assert [e.loc for e in refused.value.errors or []] == [
            ["body", "base", "solver", "warm_start"]]
        base = scene(warm_start="nearest")
        beyond = base.model_dump(mode="json")
        beyond["task"]["position_bounds"] = {"lower": [None, None], "upper": [0.5, None]}
        ok, bad = admit_members(store, base, [base, Scene.model_validate(beyond)])
        assert (ok.issues, ok.warm_start, ok.nearest_at_claim) == ([], None, True)
        assert [i.field for i in bad.issues] == ["task.final.q.0"] and not bad.nearest_at_claim
        assert given(store, base, ok) == {"issues": []}  # nothing succeeded yet: cold
        store.create("done", base.model_dump(mode="json"), "host")
        assert store.claim("host", "w", time.time() + 60) is not None
        store.finish("done", "succeeded", fake_plan(base).model_dump(mode="json"), None,
                     worker="w")
        start = given(store, base, ok)["warm_start"]  # resolved at the claim
        assert (start.job_id, start.distance) == ("done", 0.0)
        assert given(store, base, bad) == {"issues": bad.issues}
    finally:
        store.close()


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("admission"), solve=fake_plan, workers=1) as c:
        yield c


def refused_at_once(job: dict) -> None:
    """The job failed by what its admission found, before any solve."""
    assert job["status"] == "failed" and job["error"].startswith(
        "infeasible: the task is infeasible before any solve: task.final.q.0: ")
    assert job["plan"]["infeasibility"]["source"] == "checks"


def test_an_infeasible_scene_is_refused_at_every_entry(api):
    bounded = two_link_scene()
    bounded["task"]["position_bounds"] = {"lower": [None, None], "upper": [1.5, None]}
    beyond = {**bounded, "task": {**bounded["task"], "final": {"q": [2.0, None],
                                                                "dq": [0.0, 0.0]}}}
    r = api.post("/v1/plans", json=beyond)
    assert r.status_code == 422
    assert [(e["loc"], e["type"]) for e in r.json()["errors"]] == [
        (["body", "task", "final", "q", 0], "infeasible")]
    batch = api.post("/v1/batches", json={"base": bounded, "overrides": [
        {"final.q.0": 1.0}, {"final.q.0": 2.0}]})
    assert batch.status_code == 202, batch.text
    good, bad = (m["job_id"] for m in batch.json()["members"])
    assert wait_final(api, good)["status"] == "succeeded"
    refused_at_once(wait_final(api, bad))
    assert api.post(f"/v1/plans/{bad}/retry").status_code == 202  # retried by id: the same
    refused_at_once(wait_final(api, bad))
    record = api.app.state.store.get(bad)
    assert [i["field"] for i in record.admission["issues"]] == ["task.final.q.0"]


def test_a_plan_requests_warm_start_is_resolved_and_stored_when_submitted(api):
    first = wait_final(api, api.post("/v1/plans", json=two_link_scene()).json()["id"])
    assert first["status"] == "succeeded"
    nearest = two_link_scene()
    nearest["solver"]["warm_start"] = "nearest"
    job = api.post("/v1/plans", json=nearest).json()
    record = api.app.state.store.get(job["id"])
    assert record.admission["warm_start"] == {"job_id": first["id"], "distance": 0.0}
    assert record.scene["solver"]["warm_start"] == "nearest"  # the request as it came
