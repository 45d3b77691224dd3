"""A plan evaluated at any times: `Plan.sample` and GET /v1/plans/{id}/sample."""

from __future__ import annotations

import numpy as np
import pytest
from service_fixtures import client

from planner.coupling_block import along
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.ocp import plan
from planner.ocp.result import MAX_SAMPLE_TIMES, Plan
from planner.scene import Scene

ROBOT = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 0.0}
SCENE = Scene.model_validate({
    "robot": ROBOT,
    "task": {"duration": 1.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
             "final": {"q": [0.3, 1.0], "dq": [0.0, 0.0]}},
    "transcription": {"method": "legendre", "degree": 3, "intervals": 12,
                      "refinement": {"enabled": False}}})


@pytest.fixture(scope="module")
def planned() -> Plan:
    result = plan(SCENE)
    assert result.solver.success and result.states is not None
    return result


def test_at_its_own_times_a_sample_is_the_plan(planned):
    at_nodes = planned.sample(SCENE.robot, planned.t)
    np.testing.assert_allclose(at_nodes.q, planned.q, atol=1e-12)
    np.testing.assert_allclose(at_nodes.dq, planned.dq, atol=1e-12)
    np.testing.assert_allclose(at_nodes.tau, planned.tau, atol=1e-12)
    dense = planned.sample(SCENE.robot, planned.dense.t[::7])
    np.testing.assert_allclose(dense.q, planned.dense.q[::7], atol=1e-12)
    np.testing.assert_allclose(dense.tau, planned.dense.tau[::7], atol=1e-12)
    np.testing.assert_allclose(dense.sigma_min, planned.verification.sigma_min[::7],
                               rtol=1e-10)


def test_between_its_times_a_sample_follows_the_polynomials_and_the_dynamics(planned, rng):
    times = np.sort(rng.uniform(0.0, planned.duration, 25))
    s = planned.sample(SCENE.robot, times.tolist())
    assert s.t == times.tolist()
    q, dq = (np.asarray(v) for v in (s.q, s.dq))
    # the plan's own polynomials, evaluated by hand on the interval holding each time
    assert planned.states is not None and planned.torque is not None
    breaks = np.asarray(planned.states.breaks)
    k = np.clip(np.searchsorted(breaks, times, side="right") - 1, 0, len(breaks) - 2)
    u = (times - breaks[k]) / (breaks[k + 1] - breaks[k])
    for got, coeffs in ((q, planned.states.q), (dq, planned.states.dq)):
        c = np.asarray(coeffs)
        by_hand = np.einsum("tm,tmn->tn", u[:, None] ** np.arange(c.shape[1]), c[k])
        np.testing.assert_allclose(got, by_hand, atol=1e-12)
    np.testing.assert_allclose(s.tau, planned.torque.evaluate(times), atol=1e-12)
    # tip and sigma_min of the robot at those angles (planner.dynamics, coupling_block)
    dyn = Dynamics(SCENE.robot)
    np.testing.assert_allclose(s.tip, [dyn.tips(row)[-1] for row in q], atol=1e-14)
    np.testing.assert_allclose(s.sigma_min, along(SCENE.robot, q).least, rtol=1e-12)


@pytest.mark.parametrize("times, where", [
    ([0.5, -0.1], "t.1"), ([1.0 + 1e-9], "t.0"), ([float("nan")], "t.0"),
    ([float("inf")], "t.0")])
def test_a_time_outside_the_plan_is_refused(planned, times, where):
    with pytest.raises(InputError, match=rf"^{where}: .* is outside the plan, \[0, 1\] s"):
        planned.sample(SCENE.robot, times)


def test_too_many_times_are_refused(planned):
    with pytest.raises(InputError, match=f"^t: {MAX_SAMPLE_TIMES + 1} times exceed"):
        planned.sample(SCENE.robot, [0.5] * (MAX_SAMPLE_TIMES + 1))


def test_a_plan_stored_without_states_cannot_be_sampled(planned):
    old = planned.model_copy(update={"states": None})
    with pytest.raises(ValueError, match="stored before its states"):
        old.sample(SCENE.robot, [0.5])


@pytest.fixture(scope="module")
def served(tmp_path_factory, planned):
    """A server without workers whose store holds the plan as job "done" and a job
    "waiting" without one."""
    with client(tmp_path_factory.mktemp("sampling"), workers=0) as c:
        store = c.app.state.store  # type: ignore[attr-defined]
        scene = SCENE.model_dump(mode="json")
        for job_id in ("done", "waiting"):
            store.create(job_id, scene, "test")
        assert store.claim(None, "w", 1e12).id == "done"
        store.finish("done", "succeeded", planned.model_dump(mode="json"), None)
        yield c


def test_the_route_answers_the_library_sample(served, planned):
    r = served.get("/v1/plans/done/sample?t=0&t=0.25&t=1")
    assert r.status_code == 200, r.text
    assert r.json() == planned.sample(SCENE.robot, [0.0, 0.25, 1.0]).model_dump(mode="json")


@pytest.mark.parametrize("query, loc", [
    ("t=0.5&t=2", ["query", "t", 1]), ("t=-1", ["query", "t", 0]),
    ("t=nan", ["query", "t", 0]), ("t=abc", ["query", "t", 0]), ("", ["query", "t"]),
    ("&".join(["t=0.5"] * (MAX_SAMPLE_TIMES + 1)), ["query", "t"])])
def test_the_route_refuses_bad_times_at_the_field(served, query, loc):
    r = served.get(f"/v1/plans/done/sample?{query}")
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert [e["loc"] for e in r.json()["errors"]] == [loc]


def test_the_route_needs_a_plan(served):
    assert served.get("/v1/plans/nothing/sample?t=0").status_code == 404
    r = served.get("/v1/plans/waiting/sample?t=0")
    assert r.status_code == 409 and "queued" in r.json()["detail"]
