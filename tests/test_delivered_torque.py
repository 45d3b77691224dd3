"""The delivered torque is the verified torque: a plan's piecewise polynomial, fed to
POST /v1/simulate, reproduces the plan's reported replay error."""

from __future__ import annotations

import numpy as np
import pytest
from service_fixtures import client

from planner.examples import example
from planner.ocp import plan
from planner.ocp.feedback import REPLAY_SAMPLES
from planner.scene import Scene


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("torque")) as c:
        yield c


@pytest.fixture(scope="module")
def two_link():
    sc = Scene.model_validate(example("two-link-plan").request)
    return sc, plan(sc)


def _replay_error(api, sc: Scene, result, body: dict) -> float:
    """max |q_sim - q_plan| over a /v1/simulate answer, the plan taken at its dense samples."""
    answer = api.post("/v1/simulate", json={
        "robot": sc.robot.model_dump(mode="json"),
        "initial": {"q": result.q[0], "dq": result.dq[0]},
        "samples_per_interval": REPLAY_SAMPLES, **body})
    assert answer.status_code == 200, answer.text
    sim = answer.json()
    assert sim["status"] == "completed"
    dense_t, dense_q = np.asarray(result.dense.t), np.asarray(result.dense.q)
    at = [int(np.argmin(np.abs(dense_t - t))) for t in sim["t"]]
    assert np.allclose(dense_t[at], sim["t"], rtol=0.0, atol=1e-12)
    return float(np.abs(np.asarray(sim["q"]) - dense_q[at]).max())


def test_the_plans_torque_polynomial_reproduces_its_replay_error_through_simulate(api, two_link):
    sc, result = two_link
    reported = result.verification.resimulation_error
    error = _replay_error(api, sc, result, {"torque": result.torque.model_dump(mode="json")})
    # both integrate with CVODES at rtol = atol = 1e-10, each with its own steps
    assert error == pytest.approx(reported, rel=0.0, abs=1e-8)
    assert reported < result.verification.tolerance
    # the node torques, linearly interpolated, are another torque: they miss the plan
    nodes = _replay_error(api, sc, result, {"t": result.t, "tau": result.tau})
    assert nodes > 100 * reported


def test_the_polynomial_is_the_torque_at_the_nodes_and_between(two_link):
    _, result = two_link
    assert np.allclose(result.torque.evaluate(np.asarray(result.dense.t)), result.dense.tau,
                       rtol=0.0, atol=1e-12)
    # Legendre collocation of degree 3: a quadratic per interval
    assert np.asarray(result.torque.coefficients).shape == (len(result.t) - 1, 3, 1)


def test_simulate_takes_either_samples_or_a_polynomial(api, two_link):
    sc, result = two_link
    base = {"robot": sc.robot.model_dump(mode="json"),
            "initial": {"q": result.q[0], "dq": result.dq[0]}}
    torque = result.torque.model_dump(mode="json")
    both = api.post("/v1/simulate", json={**base, "torque": torque, "t": result.t,
                                           "tau": result.tau})
    assert both.status_code == 422
    assert "give either t and tau, or torque (got t, tau, torque)" in both.text
    wide = {**torque, "coefficients": [[[*row, 0.0] for row in interval]
                                       for interval in torque["coefficients"]]}
    answer = api.post("/v1/simulate", json={**base, "torque": wide})
    assert answer.status_code == 422
    assert ("coefficients: every power needs 1 entries, one per active joint (got 2)"
            in answer.text)
