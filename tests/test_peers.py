"""The rockit peer of the task suite (bench/peers/rockit.py): its plan of a suite task
passes the planner's interval check, a peer with the wrong dynamics does not, and the
suite stops a peer's task at its cap."""

from __future__ import annotations

import importlib.util
import math

import pytest

from bench import suite
from bench.peers import rockit
from planner.model import parameters
from testbed.suites.ordinary import SEED, tasks

TASK = 1  # 2 links, active then passive, g = 9.81: a few seconds with either method


@pytest.fixture(scope="module")
def scene():
    name, scene = tasks(TASK + 1)[TASK]
    assert scene.robot.gravity > 0, name
    return scene


@pytest.mark.parametrize(("method", "solver"), list(suite.ROCKIT.values()))
def test_rockit_plan_verifies(scene, method: str, solver: str) -> None:
    out = rockit.solve(scene, method, solver, wall_time=suite.WALL_TIME)
    assert out["success"], out["status"]
    assert out["iterations"] > 0
    assert out["local_error"] <= scene.solver.resimulation_tolerance
    assert out["resimulation_error"] <= 10 * scene.solver.resimulation_tolerance
    assert 0 < out["objective"] < float("inf")


def test_rockit_with_gravity_reversed_fails_the_check(scene, monkeypatch) -> None:
    """A planted fault: the peer plans with gravity upside down; the check, run with the
    scene's robot, sees that the plan is not a motion of it."""
    def reversed_gravity(robot, s):
        return parameters(robot.model_copy(update={"gravity": -robot.gravity}), s)

    monkeypatch.setattr(rockit, "parameters", reversed_gravity)
    out = rockit.solve(scene, "collocation", "ipopt", wall_time=suite.WALL_TIME)
    assert out["success"], out["status"]  # it solves its own (wrong) problem ...
    assert out["local_error"] > 10 * scene.solver.resimulation_tolerance  # ... which fails


def test_suite_skips_a_missing_peer(monkeypatch) -> None:
    assert suite.missing("rockit") == ""
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "rockit" else real(name, *a))
    assert "rockit-meco is not installed" in suite.missing("rockit fatrop")
    assert suite.missing("undertow") == ""


def test_a_peer_task_past_its_cap_is_stopped_there(monkeypatch) -> None:
    """A task whose process still runs at the cap plus the grace (here a cap of 0.5 s, too
    short for the process to start) is stopped then: unverified, saying so, with the cap as
    its time."""
    monkeypatch.setattr(suite, "WALL_TIME", 0.5)
    monkeypatch.setattr(suite, "PEER_GRACE", 0.2)
    [row] = suite.run_peer("rockit fatrop", 1, SEED)
    assert row["status"] == "stopped at the 0.5 s cap"
    assert not row["verified"] and math.isnan(row["time_to_verified"])
    assert row["time"] == 0.5


@pytest.mark.slow
def test_a_peer_task_within_its_cap_is_judged_by_the_check() -> None:
    """The same task given the real cap: its own process returns a plan that the planner's
    interval check verifies, timed from the build through the check."""
    [row] = suite.run_peer("rockit fatrop", 1, SEED)
    assert row["verified"], row["status"]
    assert row["local_error"] <= 1e-3
    assert 0 < row["time"] == row["time_to_verified"] < suite.WALL_TIME
