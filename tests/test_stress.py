"""Stress: near-singular configurations, badly scaled and random robots, the service under
faults (`python -m bench stress` runs the full sweeps and writes docs/stability.md).

Fast checks run by default; the sweeps, the 1000 random robots and the live-server faults
are slow-marked.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from service_fixtures import client

from planner import coupling_block
from planner.dynamics import Dynamics
from planner.examples import seed_crossing
from planner.inverse import RESOLUTION
from planner.model import Robot
from testbed.edges import (
    SIGMAS,
    invariants,
    inverse_case,
    non_finite,
    plan_case,
    scaled_case,
    scaled_cases,
    seed_at,
    two_link_at,
    waveless_seed,
    waveless_two_link,
)
from testbed.probes import malformed_bodies

STRUCTURED = {"Infeasible_Task", "Infeasible_Problem_Detected", "Restoration_Failed",
              "Local_Infeasibility",
              "Maximum_Iterations_Exceeded", "Maximum_WallTime_Exceeded",
              "Search_Direction_Becomes_Too_Small", "Error_In_Step_Computation",
              "Invalid_Number_Detected", "Solved_To_Acceptable_Level"}


def test_non_finite_names_the_path_of_every_nan_and_inf():
    found = non_finite({"a": [1.0, math.nan, {"b": (math.inf, -math.inf)}], "c": None, "d": "nan"})
    assert found == [".a[1]", ".a[2].b[0]", ".a[2].b[1]"]


def seed_near(sigma: float) -> np.ndarray:
    """A configuration of the waveless seed arm with sigma_min(M_pa) = sigma, on the
    segment of `planner.examples.seed_crossing` stretched threefold about its middle (so
    that it reaches sigma_min = 1e-2)."""
    a, b = (np.array(q) for q in seed_crossing())
    middle = (a + b) / 2
    return seed_at(sigma, (middle + 3 * (a - middle)).tolist(),
                   (middle + 3 * (b - middle)).tolist())


@pytest.mark.parametrize("arm, at", [("2-link", two_link_at), ("seed 4-link", seed_near)])
def test_near_singular_configurations_have_the_asked_sigma_min(arm, at):
    robot = waveless_two_link() if arm == "2-link" else waveless_seed()
    for sigma in SIGMAS:
        assert coupling_block.at(robot, at(sigma)).sigma_min == pytest.approx(sigma, rel=1e-3)


@pytest.mark.parametrize("sigma", SIGMAS)
def test_inverse_dynamics_reports_a_singular_start(sigma):
    robot = waveless_two_link()
    out = inverse_case(robot, two_link_at(sigma), threshold=1e-3)
    assert out["status"] == "singular" and out["non_finite"] == 0
    if sigma < 1e-3:
        assert out["stop_time"] == 0.0 and out["samples"] == 0
        assert out["message"] == f"sigma_min(M_pa) = {out['stop_sigma']:.3g} < 0.001 at the start"
    else:  # the active joints turning at 1 rad/s drive the arm into the singularity
        assert 0.0 < out["stop_time"] < 0.1
        assert out["stop_sigma"] == pytest.approx(1e-3, rel=1e-6)


@pytest.mark.parametrize("sigma", [1e-2, 1e-4, 1e-6])
def test_inverse_dynamics_below_the_threshold_stops_at_it_with_finite_torques(sigma):
    out = inverse_case(waveless_two_link(), two_link_at(sigma), threshold=sigma / 10)
    assert out["status"] == "singular" and out["non_finite"] == 0
    assert out["stop_sigma"] == pytest.approx(sigma / 10, rel=1e-6)
    assert out["message"].startswith("sigma_min(M_pa) fell to the threshold at t = ")
    assert out["max_tau"] * sigma / 10 < 10.0  # torques grow like 1 / sigma_min, no faster


def _floor(robot: Robot, q: np.ndarray) -> float:
    return RESOLUTION * float(np.diag(Dynamics(robot).mass_matrix(q)).max())


def test_a_threshold_below_the_resolution_floor_stops_at_the_floor():
    robot, q = waveless_two_link(), two_link_at(1e-8)
    out = inverse_case(robot, q, threshold=1e-9)
    assert 1e-9 < _floor(robot, q) < 1e-8  # the floor binds, the start lies above it
    assert out["status"] == "singular" and out["non_finite"] == 0 and out["stop_time"] > 0
    assert out["message"].startswith("sigma_min(M_pa) fell to the resolution floor at t = ")
    assert out["message"].endswith(
        "; the floor is 1e-08 of the largest diagonal entry of M, above sigma_threshold = "
        "1e-09: closer to the singularity rounding swamps the accelerations")
    assert out["stop_sigma"] == pytest.approx(_floor(robot, out["stop_q"]), rel=1e-6)


@pytest.mark.parametrize("sigma", [1e-10, 1e-12])
def test_a_start_below_the_resolution_floor_is_singular_at_once(sigma):
    robot, q = waveless_two_link(), two_link_at(sigma)
    out = inverse_case(robot, q, threshold=sigma / 10)
    assert out["status"] == "singular" and out["samples"] == 0 and out["stop_time"] == 0.0
    assert out["message"] == (
        f"sigma_min(M_pa) = {out['stop_sigma']:.3g} < {_floor(robot, q):.3g} at the start; the "
        f"floor is 1e-08 of the largest diagonal entry of M, above sigma_threshold = "
        f"{sigma / 10:.3g}: closer to the singularity rounding swamps the accelerations")


def test_planner_from_a_singular_start_is_finite_or_a_structured_failure():
    q = two_link_at(1e-12).tolist()
    robot = waveless_two_link().model_dump()
    free = plan_case(robot, q, [q[0] + 0.3, q[1] - 0.5], duration=2.0, margin=None, N=15)
    assert free["non_finite"] == 0 and free["status"] != "raised"
    assert free["success"] or free["status"] in STRUCTURED
    kept = plan_case(robot, q, [q[0] + 0.3, q[1] - 0.5], duration=2.0, margin=1e-3, N=15)
    assert kept["non_finite"] == 0 and not kept["success"]
    assert kept["status"] in STRUCTURED, kept  # the start breaks the margin


@pytest.mark.parametrize("sweep, value", [("mass ratio m2/m1", "1000"),
                                          ("lengths l1, l2 [m]", "0.01, 10")])
def test_badly_scaled_robots_give_finite_plans(sweep, value):
    case = next(c for c in scaled_cases() if c[:2] == (sweep, value))
    out = scaled_case(*case, under=True, N=10)
    assert out["status"] != "raised" and out["non_finite"] == 0, out
    assert out["success"] or out["status"] in STRUCTURED, out


@st.composite
def robots(draw) -> Robot:
    """1..8 links, lengths 1e-2..10 m, masses 1e-3..1e3 kg, inertia 0..m l^2, waves up to
    0.9 l and frequency 20 on active joints, g 0..20, both rotational conventions."""
    n = draw(st.integers(1, 8))
    links = []
    for _ in range(n):
        length = 10 ** draw(st.floats(-2, 1))
        mass = 10 ** draw(st.floats(-3, 3))
        link = {"length": length, "mass": mass,
                "joint": draw(st.sampled_from(["passive", "active"])),
                "inertia": mass * length**2 * draw(st.sampled_from([0.0, 0.01, 0.3, 1.0]))}
        if link["joint"] == "active" and draw(st.booleans()):
            link["wave"] = {"amplitude": length * draw(st.floats(0.0, 0.9)),
                            "frequency": draw(st.floats(0.0, 20.0)),
                            "phase": draw(st.floats(-math.pi, math.pi))}
        links.append(link)
    if all(link["joint"] == "passive" for link in links):
        links[draw(st.integers(0, n - 1))]["joint"] = "active"
    return Robot.model_validate({"links": links,
                                 "gravity": draw(st.sampled_from([0.0, 9.81, 20.0])),
                                 "rotational_inertia":
                                     draw(st.sampled_from(["cumulative", "absolute"]))})


def _state(draw, n: int, bound: float) -> np.ndarray:
    return np.array(draw(st.lists(st.floats(-bound, bound), min_size=n, max_size=n)))


def check_invariants(data) -> None:
    robot = data.draw(robots())
    q, dq, ddq = (_state(data.draw, robot.n, b) for b in (math.pi, 3.0, 3.0))
    res = invariants(robot, q, dq, ddq)
    assert res["asymmetry"] <= 1e-12, res
    assert res["definiteness"] > 0.0, res
    assert res["kinetic"] <= 1e-9, res
    assert res["power"] <= 1e-7, res


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_random_robots_keep_the_dynamics_invariants_quick(data):
    check_invariants(data)


@pytest.mark.slow
@settings(max_examples=1000, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_random_robots_keep_the_dynamics_invariants(data):
    check_invariants(data)


def test_malformed_bodies_get_a_problem_answer_not_a_server_error(tmp_path):
    with client(tmp_path) as http:
        for name, body, ctype in malformed_bodies():
            for path in ("/v1/plans", "/v1/dynamics"):
                r = http.post(path, content=body, headers={"Content-Type": ctype})
                assert 400 <= r.status_code < 500, (name, path, r.status_code, r.text[:300])
                ctype = r.headers["content-type"]
                assert ctype.startswith("application/problem+json"), (name, path)


@pytest.mark.slow
def test_seed_arm_inverse_dynamics_near_its_singularity_stops_with_a_report():
    robot = waveless_seed()
    for sigma in SIGMAS:
        out = inverse_case(robot, seed_near(sigma), threshold=1e-3)
        assert out["status"] == "singular" and out["non_finite"] == 0, (sigma, out)


@pytest.mark.slow
@pytest.mark.parametrize("case", scaled_cases(), ids=lambda c: f"{c[0]}={c[1]}")
def test_every_badly_scaled_robot_plans_to_finite_numbers(case):
    for under in (False, True):
        if under and case[2].get("n") == 1:
            continue
        out = scaled_case(*case, under=under)
        assert out["status"] != "raised" and out["non_finite"] == 0, out


@pytest.mark.slow
def test_a_killed_worker_requeues_its_job_and_the_server_recovers(tmp_path):
    import httpx

    from testbed.probes import kill_worker_case
    from testbed.service import LiveServer

    with LiveServer(tmp_path / "jobs.sqlite3") as live, \
            httpx.Client(base_url=live.url, timeout=60) as http:
        out = kill_worker_case(live, http)
    assert out["workers killed"] >= 1
    assert out["infrastructure failures"] == 1  # requeued, then run to the solver's verdict
    assert out["job status"] in ("succeeded", "failed") and "dead letter" not in str(
        out["job error"]) and "worker process died" not in str(out["job error"])
    assert out["healthz"] == 200 and out["next plan"] == "succeeded"


@pytest.mark.slow
def test_clients_that_disconnect_leave_the_server_healthy(tmp_path):
    import httpx

    from testbed.probes import disconnect_cases
    from testbed.service import LiveServer

    with LiveServer(tmp_path / "jobs.sqlite3") as live, \
            httpx.Client(base_url=live.url, timeout=60) as http:
        rows = disconnect_cases(live, http)
    assert all(row["ok"] for row in rows), rows
