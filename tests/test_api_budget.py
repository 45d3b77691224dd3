"""Synchronous endpoints within their bounds: output size and search size refused up
front, a wall-time budget answered as a problem, and quick requests answered while long
ones hold every compute thread."""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import pytest
from service_fixtures import TWO_LINK, client

from planner import simulate

SUFFIX = (": this server gives a synchronous computation 0.5 s (UNDERTOW_SYNC_WALL_TIME); "
          "ask for less (fewer points, samples or starts, a shorter motion)")


def simulation(intervals: int, samples: int = 1, duration: float = 1.0) -> dict:
    t = np.linspace(0.0, duration, intervals + 1).tolist()
    return {"robot": TWO_LINK, "t": t, "tau": [[0.2]] * len(t), "samples_per_interval": samples,
            "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]}, "rtol": 1e-12, "atol": 1e-12}


def fields(response) -> list[tuple[list, str]]:
    assert response.status_code == 422, response.text
    return [(e["loc"], e["msg"]) for e in response.json()["errors"]]


def test_the_simulation_output_is_limited_up_front(tmp_path):
    with client(tmp_path) as api:
        r = api.post("/v1/simulate", json=simulation(19_999, samples=100))
        assert fields(r) == [(["body", "samples_per_interval"],
                              "1999901 samples (intervals x samples_per_interval + 1) exceed "
                              "this server's limit of 20000 (UNDERTOW_MAX_POINTS)")]
        assert api.post("/v1/simulate", json=simulation(199, samples=100)).status_code == 200


def test_the_wave_screening_is_limited_up_front(tmp_path):
    robot = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.0, "joint": joint}
                       for joint in ("passive", "active", "active", "active")], "gravity": 0.0}
    request = {"robot": robot, "amplitude_max": 0.05, "frequency_max": 6, "margin": 0.01,
               "region": {"lower": [0.0, 0.0, 0.0, 0.0], "upper": [1.0, 1.0, 0.0, 0.0]}}
    with client(tmp_path) as api:
        r = api.post("/v1/waves/design", json=request)
    assert fields(r) == [(["body", "frequency_max"],
                          "the screening would evaluate 1685448 configurations, more than this "
                          "server's limit of 500000 (UNDERTOW_MAX_WAVE_SCREENING); lower "
                          "frequency_max or fix joints of the region (lower == upper)")]


def test_a_computation_past_its_budget_stops_and_answers_a_problem(tmp_path):
    with client(tmp_path, sync_wall_time=0.5) as api:
        r = api.post("/v1/simulate", json=simulation(4000, samples=4, duration=100.0))
        small = api.post("/v1/simulate", json=simulation(4))
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    problem = r.json()
    assert (problem["type"], problem["title"]) == ("urn:undertow:problem:budget-exceeded",
                                                   "The computation ran out of time")
    assert problem["detail"].startswith("the simulation (at t = ")
    assert problem["detail"].endswith(" ran past its deadline" + SUFFIX)
    assert "errors" not in problem
    assert small.status_code == 200


@pytest.fixture
def held(monkeypatch) -> tuple[threading.Event, threading.Event]:
    """`simulate.run` made to wait until released: it holds its compute thread."""
    started, release = threading.Event(), threading.Event()
    real = simulate.run

    def waiting(request, *, deadline=None):
        started.set()
        release.wait(30)
        return real(request, deadline=deadline)
    monkeypatch.setattr(simulate, "run", waiting)
    return started, release


def in_background(call: Callable[[], object]) -> tuple[threading.Thread, list]:
    out: list = []
    thread = threading.Thread(target=lambda: out.append(call()))
    thread.start()
    return thread, out


def test_busy_compute_threads_answer_503_and_quick_requests_still_pass(tmp_path, held):
    started, release = held
    with client(tmp_path, compute_threads=1, compute_wait=0.2) as api:
        thread, out = in_background(lambda: api.post("/v1/simulate", json=simulation(4)))
        assert started.wait(30)
        busy = api.post("/v1/inverse-dynamics", json={})  # invalid: refused before waiting
        assert busy.status_code == 422
        busy = api.post("/v1/simulate", json=simulation(4))
        one_state = api.post("/v1/dynamics", json={
            "robot": TWO_LINK, "states": [{"q": [0.1, 0.2], "dq": [0.0, 0.0]}]})
        release.set()
        thread.join(30)
    assert busy.status_code == 503 and busy.headers["retry-after"] == "5"
    problem = busy.json()
    assert (problem["type"], problem["detail"]) == (
        "urn:undertow:problem:busy",
        "no compute thread came free within 0.2 s (UNDERTOW_COMPUTE_WAIT); retry in 5 s")
    assert one_state.status_code == 200
    assert out[0].status_code == 200
