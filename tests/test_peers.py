"""The rockit peer of the task suite (bench/peers/rockit.py): its plan of a suite task
passes the planner's interval check, and a peer with the wrong dynamics does not."""

from __future__ import annotations

import importlib.util

import pytest

from bench import suite
from bench.peers import rockit
from planner.model import parameters
from planner.suite import tasks

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
