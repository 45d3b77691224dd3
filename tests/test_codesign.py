"""The co-design's first design: the arm's own waves where they fit, else half the bound."""

from __future__ import annotations

import pytest

from planner.examples import SEED_WAVES
from planner.ocp.codesign import design_robot
from testbed.suites.hard import hard_task


@pytest.fixture(scope="module")
def crossing():
    """A hard-suite co-design task: the seed arm, its waves' frequencies, bound 0.06 m."""
    return hard_task(8)[1]


def with_co_design(scene, amplitude_max: float, frequency: list[float]):
    co = scene.task.co_design.model_copy(update={"amplitude_max": amplitude_max,
                                                 "frequency": frequency})
    return scene.model_copy(update={"task": scene.task.model_copy(update={"co_design": co})})


def test_the_arms_own_waves_are_the_first_design(crossing):
    robot = design_robot(crossing)
    for joint, wave in SEED_WAVES.items():
        assert robot.links[joint].wave == wave


def test_an_own_wave_is_cut_to_the_bound(crossing):
    robot = design_robot(with_co_design(crossing, 0.04, [4.0, 4.0]))
    assert [robot.links[j].wave.amplitude for j in (1, 3)] == [0.04, 0.04]
    assert [robot.links[j].wave.phase for j in (1, 3)] == [SEED_WAVES[1].phase,
                                                           SEED_WAVES[3].phase]


def test_another_frequency_starts_from_half_the_bound(crossing):
    robot = design_robot(with_co_design(crossing, 0.06, [3.0, 4.0]))
    assert (robot.links[1].wave.amplitude, robot.links[1].wave.frequency) == (0.03, 3.0)
    assert robot.links[3].wave == SEED_WAVES[3]


def test_an_arm_without_waves_starts_from_half_the_bound_at_phase_0(crossing):
    bare = crossing.model_copy(update={"robot": crossing.robot.with_waves({1: None, 3: None})})
    robot = design_robot(bare)
    assert [(w.amplitude, w.frequency, w.phase) for w in
            (robot.links[1].wave, robot.links[3].wave)] == [(0.03, 4.0, 0.0), (0.03, 4.0, 0.0)]
