"""Stored plans of another schema (`app.stored_plan`): one that validates against today's
`Plan` is served as today, one that does not is served as stored (`plan_schema: legacy`,
non-finite numbers as null), never a 500; figures, samples and warm starts refuse it."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest
from service_fixtures import client, two_link_scene

from app.store import SqliteJobStore

FIRST_SCHEMA: dict[str, Any] = {
    "t": [0.0, 1.0], "q": [[0.0, 0.0], [1.0, 0.0]], "dq": [[0.0, 0.0], [0.0, 0.0]],
    "ddq": [[0.0, 0.0], [0.0, 0.0]], "tau": [[0.0], [0.0]],
    "dense": {"t": [0.0, 1.0], "q": [[0.0, 0.0], [1.0, 0.0]], "tau": [[0.0], [0.0]]},
    "duration": 1.0, "objective": 1.5, "waves": [],
    "solver": {"status": "Solve_Succeeded", "success": True, "message": "", "iterations": 7,
               "build_time": 0.1, "solve_time": 0.2, "cache_hit": False},
    "verification": {"resimulation_error": 1e-5, "resimulation_status": "completed",
                     "defect": 0.0, "min_sigma": 0.1, "waveless_min_sigma": 0.0,
                     "waveless_singular_crossings": []}}
"""A plan with the fields of the planner's first Plan schema (commit 60b8ce4), and no
other: every field added since has a default."""


def without(plan: dict[str, Any], section: str, name: str) -> dict[str, Any]:
    changed = copy.deepcopy(plan)
    del changed[section][name]
    return changed


MISSING = without(FIRST_SCHEMA, "verification", "resimulation_status")
"""A plan missing a field today's schema requires."""
EXTRA = {**FIRST_SCHEMA, "future_figure": {"value": 3}}
"""A plan with a field today's schema does not know (ignored: the plan validates)."""
EXTRA_STRICT = {**FIRST_SCHEMA, "torque": {"breaks": [0.0, 1.0], "coefficients": [[[0.0]]],
                                           "basis": "bernstein"}}
"""A plan whose torque polynomial (a strict request model) has a field it does not know."""


def strict_json(text: str) -> Any:
    """Parse JSON refusing NaN and Infinity (which json.loads would accept)."""
    def refuse(token):
        raise AssertionError(f"non-finite number {token} in a response")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A server without workers whose store holds a finished job per stored plan."""
    with client(tmp_path_factory.mktemp("stored"), workers=0) as c:
        store: SqliteJobStore = c.app.state.store  # type: ignore[attr-defined]
        for job_id, plan in (("first", FIRST_SCHEMA), ("missing", MISSING), ("extra", EXTRA),
                             ("strict", EXTRA_STRICT), ("nan", MISSING)):
            store.create(job_id, two_link_scene(), "test")
            assert store.claim(None, "w", 1e12).id == job_id
            assert store.finish(job_id, "succeeded", plan, None)
        # an SQLite file written by a version that let NaN and Infinity into the JSON text
        text = json.dumps(MISSING).replace('"min_sigma": 0.1', '"min_sigma": NaN') \
            .replace('"defect": 0.0', '"defect": -Infinity')
        assert "NaN" in text and "Infinity" in text
        store._write("UPDATE jobs SET plan = ? WHERE id = 'nan'", (text,))
        yield c


def get(served, job_id: str) -> dict[str, Any]:
    r = served.get(f"/v1/plans/{job_id}")
    assert r.status_code == 200, r.text
    return strict_json(r.text)


def test_a_plan_of_the_first_schema_is_current_with_the_later_fields_defaulted(served):
    job = get(served, "first")
    assert job["plan_schema"] == "current"
    assert job["plan"]["solver"]["strategy"] == "not recorded"
    assert job["plan"]["verification"]["verified"] is None
    assert job["plan"]["torque"] is None and job["plan"]["mesh_passes"] == []


def test_a_plan_missing_a_required_field_is_served_as_stored(served):
    job = get(served, "missing")
    assert job["status"] == "succeeded" and job["plan_schema"] == "legacy"
    assert job["plan"] == MISSING


def test_an_unknown_field_is_dropped_where_the_schema_ignores_it(served):
    job = get(served, "extra")
    assert job["plan_schema"] == "current"
    assert "future_figure" not in job["plan"]
    assert job["plan"]["objective"] == 1.5


def test_an_unknown_field_of_a_strict_part_makes_the_plan_legacy(served):
    job = get(served, "strict")
    assert job["plan_schema"] == "legacy"
    assert job["plan"] == EXTRA_STRICT


def test_non_finite_numbers_of_a_stored_plan_are_served_as_null(served):
    job = get(served, "nan")
    assert job["plan_schema"] == "legacy"
    assert job["plan"]["verification"]["min_sigma"] is None
    assert job["plan"]["verification"]["defect"] is None
    assert job["plan"]["verification"]["resimulation_error"] == 1e-5


def test_the_list_and_a_cancel_answer_beside_legacy_plans(served):
    listed = {item["id"] for item in served.get("/v1/plans").json()["items"]}
    assert listed == {"first", "missing", "extra", "strict", "nan"}
    r = served.delete("/v1/plans/missing")
    assert r.status_code == 409 and r.json()["type"] == "urn:undertow:problem:already-finished"


@pytest.mark.parametrize("path, use", [("plot.png", "a plot"), ("plot.svg", "a plot"),
                                       ("sample?t=0.5", "sampling")])
def test_figures_and_samples_refuse_a_legacy_plan(served, path, use):
    r = served.get(f"/v1/plans/missing/{path}")
    assert r.status_code == 409, r.text
    assert r.headers["content-type"] == "application/problem+json"
    problem = r.json()
    assert problem["type"] == "urn:undertow:problem:legacy-plan"
    assert problem["detail"] == (
        "plan job 'missing' holds a plan stored by a version of the service whose schema "
        f"this one cannot read (plan_schema legacy); {use} needs a plan of today's schema: "
        "submit the scene again")


def test_a_legacy_plan_cannot_warm_start_a_plan(served):
    scene = two_link_scene()
    scene["solver"]["warm_start"] = "missing"
    r = served.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    assert r.json()["errors"] == [{
        "loc": ["body", "solver", "warm_start"],
        "msg": "the plan of job 'missing' was stored by a version of the service whose schema "
               "this one cannot read (plan_schema legacy)", "type": "value_error"}]
