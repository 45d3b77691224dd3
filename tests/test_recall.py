"""The planner's memory of the plan examples (`planner.ocp.recall`): kept current with the
examples, recalled only near one, and what rescues a moved goal that wanders without it."""

from __future__ import annotations

import copy

import pytest

from planner.examples import example, examples
from planner.memory import REACH
from planner.ocp import plan
from planner.ocp.recall import FOLDER, Motion, digest, motions, recall
from planner.scene import Scene


def _moved(name: str, offsets: list[float]) -> Scene:
    request = copy.deepcopy(example(name).request)
    final = request["task"]["final"]["q"]
    request["task"]["final"]["q"] = [q + d for q, d in zip(final, offsets, strict=True)]
    return Scene.model_validate(request)


def test_every_plan_example_has_its_motion_of_its_request_as_it_is():
    names = [e.name for e in examples() if e.kind == "plan"]
    for name in names:
        stored = Motion.model_validate_json((FOLDER / f"{name}.json").read_text())
        assert stored.digest == digest(example(name).request), (
            f"{name}: its request changed; run python -m planner.remember_examples")
    assert sorted(m.example for _, m in motions()) == sorted(names)


def test_an_example_is_recalled_near_it_only():
    assert recall(Scene.model_validate(example("two-link-plan").request)) is None
    near = recall(_moved("two-link-plan", [0.03, -0.02]))
    assert near is not None and near[0].example == "two-link-plan"
    assert near[1] == pytest.approx(0.03)
    assert recall(_moved("two-link-plan", [REACH + 0.01, 0.0])) is None


def test_a_moved_goal_that_wanders_from_scratch_starts_from_the_examples_motion():
    # From the interpolated guess this goal took 4,058 iterations and ended unverified
    # after 37 s (docs/benchmarks.md, "Built-in plan examples with their goals moved").
    request = copy.deepcopy(example("two-link-plan").request)
    request["task"]["final"]["q"] = [0.0305, 1.780794]
    request["transcription"]["intervals"] = 50
    result = plan(Scene.model_validate(request))
    assert result.solver.strategy.startswith("example two-link-plan as the guess")
    assert result.solver.initial_guess == "recalled example"
    assert result.verification.verified and result.solver.iterations < 200
