"""Replanning sessions through the service: a session on a finished plan answers measured
states with the rest of the motion, is bounded in number, freed when deleted or left
idle, and refuses bad states at their field."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from service_fixtures import client

from app.sessions import Sessions
from planner.examples import example

IDLE = 5.0  # [s] UNDERTOW_SESSION_IDLE of these tests: longer than any gap between two
# requests of one test on a busy machine, so that only the abandoned session expires


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("sessions"), max_wait=60.0, max_sessions=2,
                session_idle=IDLE) as c:
        yield c


@pytest.fixture(scope="module")
def planned(api) -> dict:
    job = api.post("/v1/plans?wait=60", json=example("two-link-plan").request).json()
    assert job["status"] == "succeeded", job
    return job


def _open(api, job: dict) -> dict:
    answer = api.post("/v1/sessions", json={"plan": job["id"]})
    assert answer.status_code == 201, answer.json()
    assert answer.headers["Location"] == f"/v1/sessions/{answer.json()['id']}"
    return answer.json()


def test_a_session_answers_a_pushed_state_with_the_rest_of_the_motion(api, planned):
    session = _open(api, planned)
    plan = planned["plan"]
    T = plan["duration"]
    assert session["duration"] == T and session["warm_up"]["within"]
    at = 0.25 * T
    k = int(np.searchsorted(plan["t"], at))
    q, dq = plan["q"][k], list(plan["dq"][k])
    dq[0] += 0.05  # a push on the passive shoulder
    answer = api.post(f"/v1/sessions/{session['id']}/updates",
                      json={"t": plan["t"][k], "q": q, "dq": dq})
    assert answer.status_code == 200, answer.json()
    update = answer.json()
    assert not update["fallback"] and update["violation"] <= 1e-4
    assert update["torque"]["breaks"][0] == pytest.approx(plan["t"][k])
    assert update["torque"]["breaks"][-1] == pytest.approx(T)
    states = update["states"]
    assert states["breaks"] == update["torque"]["breaks"]
    assert states["dq"][0][0] == pytest.approx(dq, abs=1e-6)  # s = 0 of the first interval
    assert np.sum(states["q"][-1], axis=0) == pytest.approx(plan["q"][-1], abs=1e-6)  # s = 1
    N = len(update["torque"]["breaks"]) - 1
    assert np.asarray(update["gains"]).shape == (N, 1, 4)
    assert api.get(f"/v1/sessions/{session['id']}").json()["updates"] == 1
    assert api.delete(f"/v1/sessions/{session['id']}").status_code == 204


def test_two_sessions_of_one_plan_updated_at_once_both_answer(api, planned):
    """The server's threads run both updates against one cached NLP and its integrators
    (which used to end the server with a segmentation fault): each answers, verified,
    exactly what a third session's same first update answers alone."""
    plan = planned["plan"]
    k = 5
    body = {"t": plan["t"][k], "q": plan["q"][k], "mode": "converged", "verify": True,
            "dq": [plan["dq"][k][0] + 0.05, plan["dq"][k][1]]}

    def first_update(session: dict, into: list) -> None:
        try:
            into.append(api.post(f"/v1/sessions/{session['id']}/updates", json=body))
        finally:
            api.delete(f"/v1/sessions/{session['id']}")
    together: list = []
    threads = [threading.Thread(target=first_update, args=(_open(api, planned), together))
               for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    alone: list = []
    first_update(_open(api, planned), alone)
    assert alone[0].status_code == 200 and alone[0].json()["within"], alone[0].json()
    assert len(together) == 2
    for answer in together:
        assert answer.status_code == 200, answer.json()
        assert answer.json()["states"] == alone[0].json()["states"]


@pytest.mark.parametrize(("body", "loc", "msg"), [
    ({"t": 0.1, "q": [0.0, float("nan")], "dq": [0.0, 0.0]}, ["body"], None),
    ({"t": 0.1, "q": [0.0], "dq": [0.0, 0.0]}, ["body", "q"], "needs 2 entries, one per joint"),
    ({"t": 0.1, "q": [0.0, 0.0], "dq": [0.0, 0.0, 1.0]}, ["body", "dq"],
     "needs 2 entries, one per joint"),
    ({"t": 0.1, "q": [0.0, 2e6], "dq": [0.0, 0.0]}, ["body", "q", 1],
     "Input should be less than or equal to 1000000"),
    ({"t": 99.0, "q": [0.0, 0.0], "dq": [0.0, 0.0]}, ["body", "t"], None),
])
def test_a_bad_state_is_a_422_at_its_field(api, planned, body, loc, msg):
    session = _open(api, planned)
    try:
        if body["q"][-1] != body["q"][-1]:  # NaN is not JSON: sent as the literal
            answer = api.post(f"/v1/sessions/{session['id']}/updates",
                              content=b'{"t": 0.1, "q": [0.0, NaN], "dq": [0.0, 0.0]}',
                              headers={"Content-Type": "application/json"})
        else:
            answer = api.post(f"/v1/sessions/{session['id']}/updates", json=body)
        assert answer.status_code == 422, answer.json()
        assert answer.headers["Content-Type"] == "application/problem+json"
        errors = answer.json()["errors"]
        assert errors[0]["loc"][:len(loc)] == loc, errors
        if msg is not None:
            assert errors[0]["msg"] == msg
    finally:
        api.delete(f"/v1/sessions/{session['id']}")


def test_sessions_are_bounded_in_number(api, planned):
    first, second = _open(api, planned), _open(api, planned)
    try:
        third = api.post("/v1/sessions", json={"plan": planned["id"]})
        assert third.status_code == 503 and third.json()["type"].endswith("sessions-full")
        assert third.headers["Retry-After"]
    finally:
        for s in (first, second):
            api.delete(f"/v1/sessions/{s['id']}")


def test_an_abandoned_session_is_freed(api, planned):
    session = _open(api, planned)
    sessions: Sessions = api.app.state.sessions
    deadline = time.monotonic() + 20 * IDLE
    while len(sessions) and time.monotonic() < deadline:  # the app's sweeper, no request
        time.sleep(0.1)
    assert len(sessions) == 0
    gone = api.get(f"/v1/sessions/{session['id']}")
    assert gone.status_code == 404 and "UNDERTOW_SESSION_IDLE" in gone.json()["detail"]


def test_a_session_needs_a_job_with_a_plan(api):
    answer = api.post("/v1/sessions", json={"plan": "no-such-job"})
    assert answer.status_code == 422
    assert [(e["loc"], e["msg"]) for e in answer.json()["errors"]] == [
        (["body", "plan"], "there is no plan job 'no-such-job'")]


def test_an_unknown_session_is_a_404(api):
    for answer in (api.get("/v1/sessions/nope"), api.delete("/v1/sessions/nope"),
                   api.post("/v1/sessions/nope/updates",
                            json={"t": 0.0, "q": [0.0, 0.0], "dq": [0.0, 0.0]})):
        assert answer.status_code == 404


def test_the_example_client_follows_an_update_as_the_library_does(api, planned):
    from clients.session import Session
    from planner.ocp.replan import Replanner
    from planner.scene import Scene
    from planner.service import Plan

    session = Session(api, planned["id"])
    plan = planned["plan"]
    try:
        k = 7
        report = session.update(plan["t"][k], plan["q"][k], plan["dq"][k], mode="converged")
        assert report["within"] and session.current is report
    finally:
        session.close()
    earlier = Plan.model_validate(plan)
    library = Replanner(Scene.model_validate(example("two-link-plan").request), earlier).update(
        plan["t"][k], plan["q"][k], plan["dq"][k], mode="converged")
    x = np.concatenate([plan["q"][k], plan["dq"][k]]) + 0.01
    for t in np.linspace(plan["t"][k], 0.9 * plan["duration"], 17):
        ours = session.command(float(t), x)
        assert ours == pytest.approx(library.command(float(t), x), rel=1e-6, abs=1e-6)
