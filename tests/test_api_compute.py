"""POST /v1/dynamics, /v1/coupling, /v1/inverse-dynamics, /v1/simulate through the app."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from conftest import point_mass_dynamics
from service_fixtures import TWO_LINK, client

from planner import inverse
from planner.errors import InputError
from planner.model import Robot
from planner.profiles import BetaProfile
from planner.schema import JointState

WAVELESS = {**TWO_LINK, "links": [{**TWO_LINK["links"][0], "inertia": 0.0},
                                  {**TWO_LINK["links"][1], "inertia": 0.0, "wave": None}]}


def strict_json(text: str):
    """Parse JSON refusing NaN and Infinity (which json.loads would accept)."""
    def refuse(token):
        raise AssertionError(f"non-finite number {token} in a response")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("compute")) as c:
        yield c


def errors_of(response) -> list[tuple[list, str]]:
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == "application/problem+json"
    body = response.json()
    assert body["type"] == "urn:undertow:problem:validation" and body["status"] == 422
    return [(e["loc"], e["msg"]) for e in body["errors"]]


def test_dynamics_agree_with_an_independent_point_mass_model(api):
    states = [{"q": [0.3, -1.1], "dq": [0.7, -0.2], "ddq": [1.0, 2.0]},
              {"q": [2.0, 0.4], "dq": [0.0, 3.0]}]
    r = api.post("/v1/dynamics", json={"robot": TWO_LINK, "states": states})
    assert r.status_code == 200, r.text
    results = strict_json(r.text)["results"]
    robot = Robot.model_validate(TWO_LINK)
    for state, result in zip(states, results, strict=True):
        M, h = point_mass_dynamics(robot, state["q"], state["dq"])
        np.testing.assert_allclose(result["M"], M, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(result["h"], h, rtol=1e-12, atol=1e-14)
        assert result["coupling"]["det"] == pytest.approx(M[0, 1], rel=1e-12)
        assert result["kinetic_energy"] == pytest.approx(
            0.5 * np.dot(state["dq"], M @ state["dq"]), rel=1e-12)
    np.testing.assert_allclose(results[0]["generalized_forces"],
                               np.array(results[0]["M"]) @ [1.0, 2.0] + results[0]["h"],
                               rtol=1e-12)
    assert results[1]["generalized_forces"] is None
    assert results[1]["tips"][0] == pytest.approx([0.5 * math.cos(2.0), 0.5 * math.sin(2.0)])


def test_a_singular_state_gives_finite_or_null_measures(api):
    # Without wave or inertia, M_pa = m2 l1 l2 cos(q1 - q0) vanishes at q1 - q0 = pi/2.
    r = api.post("/v1/dynamics", json={"robot": WAVELESS,
                                       "states": [{"q": [0.0, math.pi / 2], "dq": [0.0, 0.0]}]})
    coupling = strict_json(r.text)["results"][0]["coupling"]
    assert abs(coupling["sigma_min"]) < 1e-15 and abs(coupling["det"]) < 1e-15
    assert coupling["condition"] is None or math.isfinite(coupling["condition"])


def test_a_fully_actuated_arm_has_no_coupling_measures(api):
    robot = {**WAVELESS, "links": [{**link, "joint": "active"} for link in WAVELESS["links"]]}
    r = api.post("/v1/dynamics", json={"robot": robot, "states": [{"q": [0, 0], "dq": [0, 0]}]})
    assert strict_json(r.text)["results"][0]["coupling"] == {
        "det": None, "sigma_min": None, "condition": 1.0}


def test_an_overflowing_state_is_refused_not_answered_with_infinity(api):
    # Angles and rates are bounded by the schema (tests/test_bad_input.py); accelerations
    # are not, and M ddq overflows.
    r = api.post("/v1/dynamics", json={"robot": TWO_LINK, "states": [
        {"q": [0, 0], "dq": [0, 0], "ddq": [1.7e308, 1.7e308]}]})
    assert errors_of(r) == [(["body", "states", 0],
                             "the dynamics overflow at this state (values too large)")]


@pytest.mark.parametrize("change, expected", [
    (lambda b: b["states"][0].update(q=[0.0]),
     [(["body", "states", 0, "q"], "needs 2 entries, one per joint")]),
    (lambda b: b["robot"]["links"][0].update(length=-1),
     [(["body", "robot", "links", 0, "length"],
       "Input should be greater than or equal to 0.0001")]),
    (lambda b: b["robot"]["links"][1]["wave"].update(amplitude=0.5),
     [(["body", "robot", "links", 1, "wave", "amplitude"],
       "must be smaller than the link length (0.5 >= 0.4)")]),
    (lambda b: b["robot"]["links"].__setitem__(slice(None), b["robot"]["links"] * 5),
     [(["body", "robot", "links"], "List should have at most 8 items after validation, not 10")]),
    (lambda b: b.pop("states"), [(["body", "states"], "Field required")]),
    (lambda b: b["robot"].update(colour="red"),
     [(["body", "robot", "colour"], "Extra inputs are not permitted")]),
])
def test_dynamics_field_errors_name_the_field(api, change, expected):
    body = {"robot": json.loads(json.dumps(TWO_LINK)), "states": [{"q": [0, 0], "dq": [0, 0]}]}
    change(body)
    assert errors_of(api.post("/v1/dynamics", json=body)) == expected


def _dynamics(q: list) -> tuple[str, dict]:
    return "/v1/dynamics", {"robot": TWO_LINK, "states": [{"q": q, "dq": [0.0, 0.0]}]}


def _coupling(q: list) -> tuple[str, dict]:
    return "/v1/coupling", {"robot": TWO_LINK, "configurations": [q]}


def _simulate(q: list) -> tuple[str, dict]:
    return "/v1/simulate", {"robot": TWO_LINK, "t": [0.0, 1.0], "tau": [[0.0], [0.0]],
                            "initial": {"q": q, "dq": [0.0, 0.0]}}


@pytest.mark.parametrize("body, loc", [
    (_dynamics, ["states", 0, "q"]), (_coupling, ["configurations", 0]),
    (_simulate, ["initial", "q"])])
@pytest.mark.parametrize("values", [["0.1", "0.2"], [True, False]])
def test_numbers_must_be_json_numbers(api, body, loc, values):
    path, request = body(values)
    assert errors_of(api.post(path, json=request)) == [
        (["body", *loc, 0], "Input should be a valid number"),
        (["body", *loc, 1], "Input should be a valid number")]


def test_grid_points_must_be_json_integers(api):
    grid = {"lower": [0, 0], "upper": [1, 1], "points": "5"}
    r = api.post("/v1/coupling", json={"robot": TWO_LINK, "grid": grid})
    assert errors_of(r) == [(["body", "grid", "points", "int"], "Input should be a valid integer"),
                            (["body", "grid", "points", "list[int]"],
                             "Input should be a valid list")]


def test_nan_in_the_body_is_refused(api):
    text = f'{{"robot": {json.dumps(TWO_LINK)}, "states": [{{"q": [NaN, 0], "dq": [0, 0]}}]}}'
    r = api.post("/v1/dynamics", content=text, headers={"content-type": "application/json"})
    assert errors_of(r) == [(["body", "states", 0, "q", 0], "Input should be a finite number")]


def test_the_links_limit_of_the_server(tmp_path):
    with client(tmp_path, max_links=1) as c:
        r = c.post("/v1/dynamics",
                   json={"robot": TWO_LINK, "states": [{"q": [0, 0], "dq": [0, 0]}]})
    assert errors_of(r) == [(["body", "robot", "links"],
                             "at most 1 links on this server (UNDERTOW_MAX_LINKS), got 2")]


def test_the_points_limit_covers_grids(tmp_path):
    grid = {"lower": [0, 0], "upper": [1, 1], "points": 11}
    with client(tmp_path, max_points=100) as c:
        r = c.post("/v1/coupling", json={"robot": TWO_LINK, "grid": grid})
    assert errors_of(r) == [(["body", "grid", "points"],
                             "121 points exceed this server's limit of 100 (UNDERTOW_MAX_POINTS)")]


@pytest.mark.parametrize("points", [10**8, 10**10, 10**12])
def test_a_huge_grid_is_refused_at_the_field_not_allocated(api, points):
    grid = {"lower": [0, 0], "upper": [1, 1], "points": points}
    r = api.post("/v1/coupling", json={"robot": TWO_LINK, "grid": grid})
    assert errors_of(r) == [(["body", "grid", "points"],
                             f"{points * points:,} points exceed the limit of 200,000; "
                             "use fewer points per axis")]


def test_coupling_finds_the_waveless_singularity(api):
    r = api.post("/v1/coupling", json={"robot": WAVELESS,
                                       "configurations": [[0.0, 1.0], [0.0, 2.0]]})
    assert r.status_code == 200, r.text
    report = strict_json(r.text)
    assert len(report["results"]) == 2
    (point,) = report["singular_points"]
    assert point["q"][1] - point["q"][0] == pytest.approx(math.pi / 2, abs=1e-8)


def test_coupling_needs_a_passive_joint(api):
    robot = {**WAVELESS, "links": [{**link, "joint": "active"} for link in WAVELESS["links"]]}
    r = api.post("/v1/coupling", json={"robot": robot, "configurations": [[0.0, 1.0]]})
    assert errors_of(r) == [(["body", "robot"], ("has no passive joint, so there is no "
                                                 "coupling block (the arm is fully actuated)"))]


def inverse_request(gravity: float) -> dict:
    return {"robot": {**TWO_LINK, "gravity": gravity}, "duration": 1.0, "samples": 11,
            "passive_motion": {"profile": "beta", "alpha": 3, "beta": 3,
                               "start": [0.0], "end": [0.3]},
            "active_initial": {"q": [0.2], "dq": [0.0]}}


def test_inverse_dynamics_torques_satisfy_the_equations_of_motion(api):
    request = inverse_request(gravity=0.0)
    r = api.post("/v1/inverse-dynamics", json=request)
    assert r.status_code == 200, r.text
    result = strict_json(r.text)
    assert result["status"] == "completed" and len(result["t"]) == 11
    states = [{"q": q, "dq": dq, "ddq": ddq}
              for q, dq, ddq in zip(result["q"], result["dq"], result["ddq"], strict=True)]
    forces = api.post("/v1/dynamics", json={"robot": request["robot"], "states": states}).json()
    Q = np.array([res["generalized_forces"] for res in forces["results"]])
    np.testing.assert_allclose(Q[:, 0], 0.0, atol=1e-6)  # the passive joint is unforced
    np.testing.assert_allclose(Q[:, 1], np.array(result["tau"])[:, 0], rtol=1e-6, atol=1e-6)


def test_an_overflowing_inverse_dynamics_is_refused_not_a_server_error():
    # The schema bounds angles and rates (tests/test_bad_input.py), so an overflow no longer
    # reaches the integration through the API; the library still refuses one from a caller
    # that builds its inputs without validation.
    request = inverse_request(gravity=0.0)
    motion = BetaProfile.model_construct(start=[0.0], end=[1e150], alpha=3.0, beta=3.0)
    with pytest.raises(InputError) as refused:
        inverse.integrate(Robot.model_validate(request["robot"]), motion, 1e-6,
                          JointState.model_construct(q=[0.2], dq=[1e150]), 11, 1e-3)
    assert str(refused.value) == ("the inverse dynamics of this motion overflow (values too "
                                  "large): scale down passive_motion, its rates over duration, "
                                  "or active_initial")


def test_an_inverse_dynamics_past_its_wall_time_is_refused(api, monkeypatch):
    # The largest rate the schema allows over the longest duration: 1e10 rad of turning
    # make DOP853 crawl, and the budget ends the request (at 0.5 s, a fast machine's
    # crawl reached a singular stop first: 0.05 s ends it well before)
    monkeypatch.setattr(inverse, "WALL_TIME", 0.05)
    request = inverse_request(gravity=0.0)
    request["active_initial"]["dq"] = [1e6]
    request["duration"] = 1e4
    request["sigma_threshold"] = 1e-300
    started = time.monotonic()
    r = api.post("/v1/inverse-dynamics", json=request)
    assert time.monotonic() - started < 30.0
    assert errors_of(r) == [(["body"], ("the inverse dynamics did not finish within 0.05 s: the "
                                        "motion is far too fast for its duration; scale down "
                                        "passive_motion, its rates over duration, or "
                                        "active_initial"))]


def test_inverse_dynamics_reports_where_it_meets_a_singularity(api):
    r = api.post("/v1/inverse-dynamics", json=inverse_request(gravity=9.81))
    result = strict_json(r.text)
    assert result["status"] == "singular"
    assert 0.0 < result["singularity"]["time"] < 1.0
    assert result["singularity"]["sigma_min"] == pytest.approx(1e-3, rel=1e-6)


def test_simulation_without_torque_conserves_energy(api):
    request = {"robot": TWO_LINK, "t": [0.0, 0.5, 1.0], "tau": [[0.0], [0.0], [0.0]],
               "initial": {"q": [0.4, -0.3], "dq": [1.0, -2.0]}}
    r = api.post("/v1/simulate", json=request)
    assert r.status_code == 200, r.text
    trajectory = strict_json(r.text)
    assert trajectory["status"] == "completed"
    ends = [{"q": trajectory["q"][k], "dq": trajectory["dq"][k]} for k in (0, -1)]
    energy = [res["kinetic_energy"] + res["potential_energy"] for res in
              api.post("/v1/dynamics", json={"robot": TWO_LINK, "states": ends}).json()["results"]]
    assert energy[1] == pytest.approx(energy[0], rel=1e-7)


def test_a_simulation_that_cannot_start_reports_failed_not_zeros(api):
    request = {"robot": TWO_LINK, "t": [0.0, 1.0], "tau": [[1e300], [1e300]],
               "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]}, "samples_per_interval": 1}
    trajectory = strict_json(api.post("/v1/simulate", json=request).text)
    assert trajectory["status"] == "failed"
    assert trajectory["message"].endswith("(values too large) (CVODES CV_BAD_T)")
    assert trajectory["t"] == [0.0]


def test_simulation_field_errors(api):
    request = {"robot": TWO_LINK, "t": [0.0, 1.0, 0.5], "tau": [[0.0]] * 3,
               "initial": {"q": [0, 0], "dq": [0, 0]}}
    assert errors_of(api.post("/v1/simulate", json=request)) == [
        (["body", "t"], "must be strictly increasing")]


def wave_request() -> dict:
    robot = {**WAVELESS, "gravity": 0.0, "links": [WAVELESS["links"][0],
                                                   {**WAVELESS["links"][1], "inertia": 0.005}]}
    return {"robot": robot, "amplitude_max": 0.06, "frequency_max": 3, "margin": 0.02,
            "region": {"lower": [0.0, 1.4], "upper": [0.2, 1.8]}, "starts": 4,
            "certification_points": 2000}


def test_designed_waves_keep_the_certified_margin_on_an_independent_grid(api):
    r = api.post("/v1/waves/design", json=wave_request())
    assert r.status_code == 200, r.text
    result = strict_json(r.text)
    assert result["status"] == "certified" and result["certified_sigma_min"] >= 0.02
    (wave,) = result["waves"]
    assert wave["joint"] == 1 and 0 < wave["amplitude"] <= 0.06
    grid = {"lower": [0.0, 1.4], "upper": [0.2, 1.8], "points": [7, 53]}
    report = api.post("/v1/coupling", json={"robot": result["robot"], "grid": grid}).json()
    assert report["min_sigma"]["sigma_min"] >= result["certified_sigma_min"]


def test_wave_design_needs_a_region_or_a_motion(api):
    request = wave_request()
    request.pop("region")
    assert errors_of(api.post("/v1/waves/design", json=request)) == [
        (["body", "region"], "give exactly one of region and motion")]


def test_the_examples_are_listed_and_fetched_by_name(api):
    from app.routes.examples import ENDPOINTS

    listed = api.get("/v1/examples").json()
    names = [e["name"] for e in listed]
    assert "seed-arm-waves" in names and len(set(names)) == len(names)
    assert {e["kind"] for e in listed} <= set(ENDPOINTS)
    assert api.get("/v1/examples/seed-arm-waves").json() == listed[names.index("seed-arm-waves")]
    r = api.get("/v1/examples/nope")
    assert r.status_code == 404 and r.json()["detail"].startswith("no example called 'nope'")


def test_the_seed_arm_examples_run(api):
    plain, wavy = (api.get(f"/v1/examples/seed-arm-{k}").json()["request"]
                   for k in ("waveless", "waves"))
    assert strict_json(api.post("/v1/inverse-dynamics", json=plain).text)["status"] == "singular"
    assert strict_json(api.post("/v1/inverse-dynamics", json=wavy).text)["status"] == "completed"


@pytest.mark.parametrize("path", ["/v1/dynamics", "/v1/simulate"])
def test_the_documented_examples_are_accepted(api, path):
    content = api.app.openapi()["paths"][path]["post"]["requestBody"]["content"]
    examples = content["application/json"]["examples"]
    assert examples
    for example in examples.values():
        r = api.post(path, json=example["value"])
        assert r.status_code == 200, r.text
        strict_json(r.text)


def test_the_wave_design_search_is_bounded_by_the_server(tmp_path):
    request = {**wave_request(), "starts": 9, "frequency_max": 7}
    with client(tmp_path) as c:
        r = c.post("/v1/waves/design", json=request)
    assert errors_of(r) == [
        (["body", "starts"], "at most 8 on this server (UNDERTOW_MAX_WAVE_STARTS), got 9"),
        (["body", "frequency_max"],
         "at most 6 on this server (UNDERTOW_MAX_WAVE_FREQUENCY), got 7")]


def test_inverse_dynamics_field_errors(api):
    request = inverse_request(gravity=0.0)
    request["passive_motion"] = {**request["passive_motion"], "start": [0.0, 0.1],
                                 "end": [0.3, 0.2]}
    request["active_initial"] = {"q": [0.2, 0.0], "dq": [0.0]}
    errors = errors_of(api.post("/v1/inverse-dynamics", json=request))
    assert errors == [(["body", "passive_motion"],
                       "needs 1 angle per time, one per passive joint")]
    request = inverse_request(gravity=0.0)
    request["duration"] = 0
    assert errors_of(api.post("/v1/inverse-dynamics", json=request)) == [
        (["body", "duration"], "Input should be greater than or equal to 0.01")]


def test_a_closed_loop_simulation_names_a_misshapen_feedback_at_its_field(api):
    request = {"robot": TWO_LINK, "t": [0.0, 1.0], "tau": [[0.0], [0.0]],
               "initial": {"q": [0, 0], "dq": [0, 0]},
               "feedback": {"gains": [[[0.0] * 4]], "q": [[0, 0]], "dq": [[0, 0], [0, 0]]}}
    assert errors_of(api.post("/v1/simulate", json=request)) == [
        (["body", "feedback", "q"], "needs 2 rows of 2 entries, one per breakpoint")]
