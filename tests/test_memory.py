"""Memory of motion: which stored scene a new one is nearest to, and when none is near."""

from __future__ import annotations

import copy
import math

import pytest

from planner.examples import example
from planner.memory import REACH, distance, nearest
from planner.scene import Scene

BASE = example("seed-arm-plan").request


def scene(change=None) -> Scene:
    """The seed-arm example with `change(request)` applied to a copy of its request."""
    request = copy.deepcopy(BASE)
    if change is not None:
        change(request)
    return Scene.model_validate(request)


def goal(joint: int, by: float):
    def change(request):
        request["task"]["final"]["q"][joint] += by
    return change


def test_the_distance_is_the_largest_change_of_a_boundary_angle():
    a = scene()
    assert distance(a, a) == 0.0
    b, c = scene(goal(1, 0.03)), scene(goal(3, -0.2))
    assert distance(a, b) == pytest.approx(0.03) == pytest.approx(distance(b, a))
    assert distance(a, c) == pytest.approx(0.2)
    assert distance(b, c) == pytest.approx(0.2)  # the largest change, not their sum


def test_rates_count_over_a_quarter_of_the_duration_and_numbers_relatively():
    T = BASE["task"]["duration"]

    def rate(request):
        request["task"]["initial"]["dq"][0] += 0.4

    def heavier(request):
        request["robot"]["links"][2]["mass"] *= 1.1

    assert distance(scene(), scene(rate)) == pytest.approx(0.1 * T)
    assert distance(scene(), scene(heavier)) == pytest.approx(math.log(1.1))


def test_a_task_stated_differently_is_a_radian_further():
    def limited(request):
        request["task"]["torque_limit"] = 50.0

    assert distance(scene(), scene(limited)) == pytest.approx(1.0)


def test_arms_of_other_joints_are_never_near():
    def passive(request):
        request["robot"]["links"][1] = {**request["robot"]["links"][1], "joint": "passive",
                                        "wave": None}

    def free(request):
        request["task"]["final"]["dq"][0] = None

    assert distance(scene(), scene(passive)) == math.inf
    assert distance(scene(), scene(free)) == math.inf


def test_the_nearest_within_reach_and_stored_scenes_that_no_longer_validate_are_passed_over():
    stored = [("far", scene(goal(1, 0.3)).model_dump(mode="json")),
              ("broken", {"robot": {}}),
              ("near", scene(goal(1, 0.02)).model_dump(mode="json")),
              ("beyond", scene(goal(0, 2 * REACH)).model_dump(mode="json"))]
    found = nearest(scene(), stored)
    assert found is not None and found[0] == "near" and found[1] == pytest.approx(0.02)
    assert nearest(scene(goal(0, 2 * REACH)), stored[:3]) is None
    assert nearest(scene(), []) is None


def test_a_tip_target_counts_over_the_arms_reach_and_needs_a_tip_target_to_compare():
    def target(x: float):
        def change(request):
            request["task"]["tip_target"] = {"x": x, "y": 0.5}
        return change

    reach = sum(link["length"] for link in BASE["robot"]["links"])
    assert distance(scene(target(1.0)), scene(target(1.2))) == pytest.approx(0.2 / reach)
    assert distance(scene(), scene(target(1.0))) == math.inf
