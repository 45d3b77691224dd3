"""Warm replanning through the service: a plan names an earlier plan job to start from."""

from __future__ import annotations

import pytest
from service_fixtures import client

from planner.examples import example


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("warm"), max_wait=60.0) as c:  # the real planner
        yield c


def test_a_moved_goal_starts_from_the_earlier_plans_solution(api):
    request = example("two-link-plan").request
    first = api.post("/v1/plans?wait=60", json=request).json()
    assert first["status"] == "succeeded", first
    moved = {**request, "task": {**request["task"], "final": {
        **request["task"]["final"], "q": [0.0, request["task"]["final"]["q"][1] + 0.02]}},
        "solver": {**request["solver"], "warm_start": first["id"]}}
    warm = api.post("/v1/plans?wait=60", json=moved).json()
    assert warm["status"] == "succeeded", warm
    plan = warm["plan"]
    assert plan["solver"]["strategy"] == "warm start"
    assert plan["solver"]["iterations"] <= 5 < first["plan"]["solver"]["iterations"]
    assert "solution" not in plan


def test_a_warm_start_names_a_job_with_a_plan(api):
    request = example("two-link-plan").request
    bad = {**request, "solver": {**request["solver"], "warm_start": "no-such-job"}}
    answer = api.post("/v1/plans", json=bad)
    assert answer.status_code == 422
    assert [(e["loc"], e["msg"]) for e in answer.json()["errors"]] == [
        (["body", "solver", "warm_start"], "there is no plan job 'no-such-job'")]


def test_nearest_starts_from_the_closest_succeeded_plan_and_says_which(api):
    request = example("two-link-plan").request
    base = api.post("/v1/plans?wait=60", json=request).json()
    assert base["status"] == "succeeded", base
    final = request["task"]["final"]
    moved = {**request, "task": {**request["task"], "final": {
        **final, "q": [final["q"][0], final["q"][1] - 0.03]}},
        "solver": {**request["solver"], "warm_start": "nearest"}}
    warm = api.post("/v1/plans?wait=60", json=moved).json()
    assert warm["status"] == "succeeded", warm
    solver = warm["plan"]["solver"]
    assert solver["warm_start"] is not None and solver["strategy"] == "warm start"
    assert solver["warm_start_distance"] == pytest.approx(0.03, abs=0.031)
    assert solver["iterations"] <= 5 < base["plan"]["solver"]["iterations"]


def test_nearest_without_a_plan_within_reach_is_a_cold_start(api):
    request = example("two-link-plan").request
    slower = {**request, "task": {**request["task"], "duration": 2 * request["task"]["duration"]},
              "solver": {**request["solver"], "warm_start": "nearest"}}  # log 2 > REACH
    cold = api.post("/v1/plans?wait=60", json=slower).json()
    assert cold["status"] == "succeeded", cold
    assert cold["plan"]["solver"]["warm_start"] is None
    assert cold["plan"]["solver"]["initial_guess"] != "warm start"
