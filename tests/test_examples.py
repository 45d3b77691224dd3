"""Built-in examples: every request validates, the starts are exactly singular without
waves, the seed arm is the seed's, and seed_crossing() straddles a singularity."""

from __future__ import annotations

import json

import numpy as np
import pytest
from service_fixtures import ROOT

from planner.coupling import CouplingRequest, analyse
from planner.coupling_block import along, at
from planner.examples import (
    MARGIN,
    example,
    examples,
    seed_arm,
    seed_crossing,
    seed_start,
    two_link,
    two_link_start,
)
from planner.inverse import InverseDynamicsRequest
from planner.scene import Scene
from planner.service import plan
from planner.waves import WaveDesignRequest
from testbed.suites.hard import crosses

MODELS = {"inverse-dynamics": InverseDynamicsRequest, "wave-design": WaveDesignRequest,
          "coupling": CouplingRequest}


def test_names_are_unique_and_found():
    names = [item.name for item in examples()]
    assert len(names) == len(set(names))
    for name in names:
        assert example(name).name == name
    with pytest.raises(KeyError, match="no example called 'nope'; known: "
                                       "seed-arm-horizontal-plan, seed-arm-plan"):
        example("nope")


def test_each_arm_has_the_three_inverse_dynamics_and_design_requests():
    names = {item.name: item.kind for item in examples()}
    for arm in ("two-link", "seed-arm"):
        assert names[f"{arm}-waveless"] == "inverse-dynamics"
        assert names[f"{arm}-wave-design"] == "wave-design"
        assert names[f"{arm}-waves"] == "inverse-dynamics"


@pytest.mark.parametrize("item", [item for item in examples() if item.kind in MODELS],
                         ids=lambda item: item.name)
def test_every_request_validates_and_is_plain_json(item):
    MODELS[item.kind].model_validate(item.request)
    assert json.loads(json.dumps(item.request, allow_nan=False)) == item.request


def test_the_seed_arm_is_the_seeds():
    robot = seed_arm(False)
    assert [link.length for link in robot.links] == [0.5, 0.4, 0.4, 0.3]
    assert [link.mass for link in robot.links] == [1.0, 0.8, 0.6, 0.4]
    assert [link.inertia for link in robot.links] == [0.01, 0.008, 0.006, 0.004]
    assert robot.passive == [0, 2] and robot.active == [1, 3]
    assert [link.wave is not None for link in seed_arm(True).links] == [False, True, False, True]


@pytest.mark.parametrize("arm, start", [(two_link, two_link_start), (seed_arm, seed_start)])
def test_the_motion_starts_exactly_singular_without_waves_and_regular_with(arm, start):
    q = start()
    assert abs(at(arm(False), q).det) < 1e-16
    assert at(arm(True), q).sigma_min > MARGIN


@pytest.mark.parametrize("name, arm", [("two-link-waves", two_link),
                                       ("seed-arm-waves", seed_arm)])
def test_the_wave_examples_carry_the_designed_waves_and_the_same_motion(name, arm):
    wavy, plain = example(name).request, example(name.replace("waves", "waveless")).request
    assert wavy["robot"] == arm(True).model_dump(mode="json")
    assert {k: v for k, v in wavy.items() if k != "robot"} == (
        {k: v for k, v in plain.items() if k != "robot"})


def test_seed_crossing_straddles_a_waveless_singularity():
    a, b = seed_crossing()
    assert at(seed_arm(False), a).det * at(seed_arm(False), b).det < 0.0
    report = analyse(CouplingRequest(robot=seed_arm(False), configurations=[a, b]))
    (point,) = report.singular_points
    assert abs(point.det) < 1e-15
    u = np.dot(np.subtract(point.q, a), np.subtract(b, a)) / np.sum(np.subtract(b, a) ** 2)
    assert np.allclose(point.q, np.add(a, u * np.subtract(b, a)), atol=1e-12)
    assert abs(at(seed_arm(True), point.q).sigma_min) > MARGIN


def test_the_headline_example_is_the_seed_arm_in_a_horizontal_plane_across_a_singularity():
    first = examples()[0]
    scene = Scene.model_validate(first.request)
    assert (first.name, first.kind, scene.robot.gravity) == ("seed-arm-horizontal-plan",
                                                             "plan", 0.0)
    assert crosses(scene.robot, scene.task.initial.q, [float(q) for q in scene.task.final.q
                                                       if q is not None])


def _waved_sign_changes(name: str) -> tuple[object, list[float]]:
    """The plan of example `name` and the times [s] where det M_pa of its waved arm changes
    sign, sampled 100 times finer than the plan's dense samples."""
    scene = Scene.model_validate(example(name).request)
    result = plan(scene)
    times = np.linspace(0.0, result.duration, 200_001)
    det = np.concatenate([
        along(result.robot_of(scene.robot), result.sample(scene.robot, part.tolist()).q).det
        for part in np.array_split(times, 250)])
    return result, [float(t) for t in times[1:][np.sign(det[1:]) != np.sign(det[:-1])]]


def test_the_headline_plan_passes_singular_configurations_as_the_docs_say():
    """README and docs/viewer.md: the first example's verified plan (no coupling margin)
    crosses the waveless singularity at 1.37 s, and its waved arm has singular
    configurations of its own near 0.05 s and 1.25 s."""
    result, changes = _waved_sign_changes("seed-arm-horizontal-plan")
    v = result.verification
    t, waved = np.array(result.dense.t), np.array(v.sigma_min)
    assert result.status == "verified" and example(
        "seed-arm-horizontal-plan").request["task"].get("coupling_margin") is None
    assert [round(c.time, 2) for c in v.waveless_singular_crossings] == [1.37]
    assert [round(c, 2) for c in changes] == [0.05, 1.25]  # det M_pa of the waved arm
    early, late = t < 0.5, (t > 1.0) & (t < 1.3)
    lows = [(float(f"{waved[m].min():.2g}"), round(float(t[m][np.argmin(waved[m])]), 3))
            for m in (early, late)]
    assert lows == [(0.00016, 0.047), (0.00011, 1.249)]
    readme, guide = (" ".join((ROOT / path).read_text().split())
                     for path in ("README.md", "docs/viewer.md"))
    assert ("waveless M_pa is singular at t = 1.37 s and the waved one, with that arm's "
            "waves, near t = 0.05 s and 1.25 s") in readme
    assert ("to 1.6e-4 at t = 0.047 s and to 1.1e-4 at t = 1.249 s on the 2,161 dense "
            "samples") in guide
    assert f"objective {result.objective:.3f} N²m²s" in guide


def test_the_two_link_plan_keeps_its_margin_as_the_docs_say():
    scene = Scene.model_validate(example("two-link-plan").request)
    result = plan(scene)
    v = result.verification
    assert result.status == "verified" and v.waveless_singular_crossings
    assert scene.task.coupling_margin == 0.01 and round(min(v.sigma_min), 3) == 0.021
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert "the `two-link-plan` example keeps σ_min ≥ 0.021, above its margin of 0.01" in readme
