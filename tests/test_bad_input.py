"""Inputs that are valid JSON numbers but meaningless to the dynamics answer a field-level
422, not a 500 (an SVD that does not converge) or a 200 with overflowed numbers."""

from __future__ import annotations

import pytest
from pydantic import ValidationError
from service_fixtures import client, two_link_scene

from planner.schema import STATE_MAX, JointState
from testbed.fake_solvers import fake_plan

WAVED = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
                   {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
                    "wave": {"amplitude": 0.06, "frequency": 4.0, "phase": -2.85}},
                   {"length": 0.4, "mass": 0.6, "inertia": 0.006, "joint": "passive"},
                   {"length": 0.3, "mass": 0.4, "inertia": 0.004, "joint": "active",
                    "wave": {"amplitude": 0.06, "frequency": 4.0, "phase": 0.24}}],
         "gravity": 0.0}
MOTION = {"profile": "beta", "start": [0.2, -0.6], "end": [0.3, -0.5]}
ACTIVE = {"q": [0.8, -2.37], "dq": [0.0, 0.0]}


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("bad-input"), solve=fake_plan) as c:
        yield c


def only_error(response) -> dict:
    """The single field error of a 422 problem."""
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == "application/problem+json"
    body = response.json()
    assert body["type"] == "urn:undertow:problem:validation"
    [error] = body["errors"]
    return error


def coupling(configuration: list[float]) -> dict:
    return {"robot": WAVED, "configurations": [[0.1, 0.6, -0.7, -2.67], configuration]}


def inverse(active: dict = ACTIVE, motion: dict = MOTION) -> dict:
    return {"robot": WAVED, "passive_motion": motion, "duration": 2.0,
            "active_initial": active, "samples": 11}


def design(**what) -> dict:
    return {"robot": WAVED, "amplitude_max": 0.06, "frequency_max": 2, "margin": 0.02,
            "starts": 1, **what}


HUGE = 1e308
CASES = [
    ("/v1/coupling", coupling([0.1, HUGE, -0.7, -2.67]), ["body", "configurations", 1, 1]),
    ("/v1/coupling", coupling([0.1, 0.6, -0.7, -HUGE]), ["body", "configurations", 1, 3]),
    ("/v1/coupling", {"robot": WAVED, "grid": {"lower": [0.0, -HUGE, 0.0, 0.0],
                                               "upper": [0.0, 0.0, 0.0, 0.0]}},
     ["body", "grid", "lower", 1]),
    ("/v1/inverse-dynamics", inverse(active={"q": [HUGE, -2.37], "dq": [0.0, 0.0]}),
     ["body", "active_initial", "q", 0]),
    ("/v1/inverse-dynamics", inverse(active={"q": [0.8, -2.37], "dq": [0.0, -HUGE]}),
     ["body", "active_initial", "dq", 1]),
    ("/v1/inverse-dynamics", inverse(motion={**MOTION, "start": [HUGE, -0.6]}),
     ["body", "passive_motion", "beta", "start", 0]),
    ("/v1/inverse-dynamics", inverse(motion={"profile": "samples", "t": [0.0, 2.0],
                                             "q": [[0.2, -0.6], [0.3, -HUGE]]}),
     ["body", "passive_motion", "samples", "q", 1, 1]),
    ("/v1/waves/design", design(region={"lower": [0.0, -HUGE, 0.0, 0.0],
                                        "upper": [0.0, 0.0, 0.0, 0.0]}),
     ["body", "region", "lower", 1]),
    ("/v1/waves/design", design(motion={"passive_motion": MOTION, "duration": 2.0,
                                        "active_initial": {"q": [0.8, -HUGE],
                                                           "dq": [0.0, 0.0]}}),
     ["body", "motion", "active_initial", "q", 1]),
    ("/v1/dynamics", {"robot": WAVED, "states": [{"q": [0.0, -HUGE, 0.0, 0.0],
                                                  "dq": [0.0] * 4}]},
     ["body", "states", 0, "q", 1]),
]


@pytest.mark.parametrize("path, body, loc", CASES, ids=[
    f"{path.rsplit('/', 1)[-1]}-{'.'.join(map(str, loc[1:]))}" for path, _, loc in CASES])
def test_a_huge_angle_or_rate_is_a_422_at_its_field(api, path, body, loc):
    error = only_error(api.post(path, json=body))
    assert error["loc"] == loc
    assert error["type"] in ("less_than_equal", "greater_than_equal")
    assert "1000000" in error["msg"] or "1e+06" in error["msg"]


def test_a_plan_request_refuses_a_huge_start_or_goal(api):
    scene = {"robot": WAVED, "task": {"duration": 1.0,
                                      "initial": {"q": [0.0] * 4, "dq": [0.0] * 4},
                                      "final": {"q": [None, -HUGE, None, None],
                                                "dq": [0.0] * 4}}}
    error = only_error(api.post("/v1/plans", json=scene))
    assert error["loc"] == ["body", "task", "final", "q", 1]


def test_the_bound_is_inclusive_and_the_largest_angle_still_computes(api):
    JointState(q=[STATE_MAX, -STATE_MAX], dq=[STATE_MAX, -STATE_MAX])
    with pytest.raises(ValidationError):
        JointState(q=[STATE_MAX * (1 + 1e-15)], dq=[0.0])
    r = api.post("/v1/coupling", json=coupling([0.1, STATE_MAX, -0.7, -STATE_MAX]))
    assert r.status_code == 200, r.text


@pytest.mark.parametrize("value", ["2", True, "1e308", None, [2.0]])
@pytest.mark.parametrize("way", ["overrides", "grid"])
def test_a_batch_parameter_must_be_a_json_number(api, way, value):
    """Not read as 2.0, or as a duration of 1.0 s for true."""
    body = {"base": two_link_scene(), way: [{"duration": value}] if way == "overrides"
            else {"duration": [1.0, value]}}
    error = only_error(api.post("/v1/batches", json=body))
    loc = ["body", "overrides", 0, "duration"] if way == "overrides" \
        else ["body", "grid", "duration", 1]
    assert error["loc"] == loc, error
    assert error["type"] in ("float_type", "list_type"), error


def test_a_batch_parameter_may_be_an_integer(api):
    r = api.post("/v1/batches", json={"base": two_link_scene(), "overrides": [{"duration": 2}]})
    assert r.status_code == 202, r.text
    assert api.get(r.headers["location"]).json()["members"][0]["parameters"] == {"duration": 2.0}
