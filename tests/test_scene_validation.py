"""A scene that cannot be planned is refused at the field (422) before it becomes a job."""

from __future__ import annotations

import pytest
from service_fixtures import client, two_link_scene

from testbed.fake_solvers import fake_plan


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("scenes"), solve=fake_plan) as c:
        yield c


def _bounds(lower: list, upper: list) -> dict:
    return {"lower": lower, "upper": upper}


@pytest.mark.parametrize("task, loc, msg", [
    ({"duration": 0}, ["duration"], "must be within [0.01, 10000] s (got 0)"),
    ({"duration": -1}, ["duration"], "must be within [0.01, 10000] s (got -1)"),
    ({"duration": 1e-100}, ["duration"], "must be within [0.01, 10000] s (got 1e-100)"),
    ({"duration": 1e-300}, ["duration"], "must be within [0.01, 10000] s (got 1e-300)"),
    ({"coupling_margin": 1e-300}, ["coupling_margin"],
     "Input should be greater than or equal to 0.000001"),
    ({"coupling_margin": 1e-12}, ["coupling_margin"],
     "Input should be greater than or equal to 0.000001"),
    ({"torque_limit": 1e300}, ["torque_limit"], "must be at most 1e+06 N m (got 1e+300 N m)"),
    ({"torque_limit": -2.5}, ["torque_limit"], "must not be negative (got -2.5 N m)"),
    ({"torque_limit": [-1.0]}, ["torque_limit", 0], "must not be negative (got -1 N m)"),
    ({"position_bounds": _bounds([0.0, 1.0], [1.0, 0.5])}, ["position_bounds", "lower", 1],
     "must not exceed upper.1 (1 > 0.5)"),
    ({"velocity_bounds": _bounds([2.0, None], [-2.0, None])}, ["velocity_bounds", "lower", 0],
     "must not exceed upper.0 (2 > -2)"),
])
def test_an_unplannable_task_is_a_field_error(api, task, loc, msg):
    # durations and margins beyond what the planner can carry are refused at their field
    # (a duration of 1e-100 s had killed its worker four times; a margin of 1e-300 had
    # turned the two-link plan infeasible)
    scene = two_link_scene()
    scene["task"].update(task)
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    assert [(e["loc"], e["msg"]) for e in r.json()["errors"]] == [(["body", "task", *loc], msg)]


def test_a_duration_range_below_the_shortest_duration_is_a_field_error(api):
    scene = two_link_scene()
    scene["task"]["duration"] = {"min": 1e-320, "max": 1.0}
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    errors = [(e["loc"][-1], e["msg"]) for e in r.json()["errors"]]
    assert ("min", "Input should be greater than or equal to 0.01") in errors


@pytest.mark.parametrize("task", [
    {"torque_limit": 0.0}, {"torque_limit": [3.0]},
    {"position_bounds": _bounds([None, -1.0], [None, -1.0])},
])
def test_edge_values_of_a_task_are_accepted(api, task):
    # the schema takes them; the task may still be infeasible before any solve (a zero
    # torque that cannot move the arm, bounds that its start leaves), which is another 422
    scene = two_link_scene()
    scene["task"].update(task)
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 202 or r.status_code == 422 and {
        e["type"] for e in r.json()["errors"]} == {"infeasible"}, r.text


@pytest.mark.parametrize("values", [["0.1", "0.2"], [True, False]])
def test_angles_must_be_json_numbers(api, values):
    scene = two_link_scene()
    scene["task"]["initial"]["q"] = values
    scene["task"]["position_bounds"] = {"lower": [None, values[0]], "upper": [None, 1.0]}
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    assert [(e["loc"], e["msg"]) for e in r.json()["errors"]] == [
        (["body", "task", "initial", "q", 0], "Input should be a valid number"),
        (["body", "task", "initial", "q", 1], "Input should be a valid number"),
        (["body", "task", "position_bounds", "lower", 1], "Input should be a valid number")]
