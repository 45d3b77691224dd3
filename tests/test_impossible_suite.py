"""The impossible suite (testbed.suites.impossible): reproducible, every category, each task
impossible by construction: proven by a check before any solve, or a duration at most
SHORT[1] of its stored reference shortest duration. No solve: the references are stored."""

from __future__ import annotations

import numpy as np
import pytest

from planner import feasibility
from planner.scene import DurationRange
from testbed.suites import impossible as impossible_suite
from testbed.suites.hard import category
from testbed.suites.impossible import CATEGORIES, COUNT, HELD_OUT, SEED, SHORT, impossible_tasks

CHECKS = {"unreachable-tip": {"reach"}, "zero-torque": {"zero torque"},
          "contradictory-bounds": {"bounds", "velocity reach", "reach within bounds"}}
"""The kinds of check that prove the tasks of each category impossible."""


@pytest.fixture(scope="module", params=[SEED, *HELD_OUT])
def suite(request):
    return request.param, impossible_tasks(COUNT, request.param)


def _dumped(tasks):
    return [(name, scene.model_dump(mode="json")) for name, scene in tasks]


def test_a_seed_gives_the_same_tasks_and_a_shorter_suite_is_a_prefix(suite):
    seed, tasks = suite
    assert _dumped(impossible_tasks(COUNT, seed)) == _dumped(tasks)
    assert _dumped(impossible_tasks(10, seed)) == _dumped(tasks[:10])


def test_every_category_is_present_in_equal_shares(suite):
    _, tasks = suite
    names = [category(name) for name, _ in tasks]
    assert {c: names.count(c) for c in CATEGORIES} == {c: COUNT // 5 for c in CATEGORIES}


def test_every_task_without_a_short_duration_is_proven_impossible_before_a_solve(suite):
    _, tasks = suite
    found = set()
    for name, scene in tasks:
        kind = category(name)
        if kind in CHECKS:
            issues = feasibility.check(scene)
            assert {i.kind for i in issues} & CHECKS[kind], name
            found |= {i.kind for i in issues}
    assert found >= {"reach", "zero torque", "bounds", "velocity reach", "reach within bounds"}


def test_a_short_task_asks_for_at_most_its_share_of_a_stored_reference(suite):
    """Its longest duration is at most SHORT[1] of the least verified duration of the
    reference time-optimal solves of its move, which are stored; the checks before a solve
    do not see it (the duration probe must)."""
    seed, tasks = suite
    for name, scene in tasks:
        if not category(name).startswith("short"):
            continue
        task = scene.task
        ref = impossible_suite.stored_reference(
            (seed, int(name.rsplit("-", 1)[1])), np.array(task.initial.q),
            np.array(task.final.q), float(task.torque_limit))  # type: ignore[arg-type]
        assert ref is not None and ref.shortest is not None, name
        d = task.duration
        longest = d.max if isinstance(d, DurationRange) else d
        assert isinstance(d, DurationRange) == (category(name) == "short-range")
        assert SHORT[0] * ref.shortest - 1e-4 <= longest <= SHORT[1] * ref.shortest + 1e-4
        assert feasibility.check(scene) == [], name
