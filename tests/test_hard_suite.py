"""The hard suite (planner.hard_suite): reproducible, every category, feasible by
construction as far as can be checked without a solve. No solves here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.coupling_block import along
from planner.dynamics import Dynamics
from planner.examples import seed_arm
from planner.hard_suite import (
    BOUND_MARGIN,
    CATEGORIES,
    COUNT,
    HELD_OUT,
    MOVE,
    ROOM,
    SEED,
    SWING,
    category,
    check,
    crosses,
    crossing_zeros,
    design_start,
    guess_peak,
    hard_tasks,
    segment,
)
from planner.scene import DurationRange


@pytest.fixture(scope="module", params=[SEED, *HELD_OUT])
def suite(request):
    return hard_tasks(COUNT, request.param)


def _dumped(tasks):
    return [(name, scene.model_dump(mode="json")) for name, scene in tasks]


def test_a_seed_gives_the_same_tasks_and_a_shorter_suite_is_a_prefix(suite):
    assert _dumped(hard_tasks(COUNT, SEED)) == _dumped(hard_tasks(COUNT, SEED))
    assert _dumped(hard_tasks(12, SEED)) == _dumped(hard_tasks(COUNT, SEED)[:12])
    assert _dumped(hard_tasks(12, SEED)) != _dumped(hard_tasks(12, HELD_OUT[0]))


def test_every_category_is_present_and_names_its_tasks(suite):
    names = [name for name, _ in suite]
    assert len(set(names)) == len(names) == COUNT
    assert {category(name) for name in names} == set(CATEGORIES)
    assert {category(name) for name, _ in hard_tasks(len(CATEGORIES), SEED)} == set(CATEGORIES)


def test_every_task_passes_the_checks_before_a_solve(suite):
    for name, scene in suite:
        assert check(scene) == [], name


def _seed_like(scene, gravity=None) -> bool:
    arm = seed_arm(True)
    same = [link.model_dump() for link in scene.robot.links] == \
        [link.model_dump() for link in arm.links]
    return same and (gravity is None or scene.robot.gravity == gravity)


def test_seed_arm_crossings_cross_a_waveless_singularity(suite):
    for name, scene in suite:
        kind = category(name)
        if kind in ("seed-g0-cross", "seed-g9.81-cross", "torque-limit", "bounds", "co-design"):
            assert _seed_like(scene, 0.0 if kind == "seed-g0-cross" else None), name
            if kind == "seed-g9.81-cross":
                assert scene.robot.gravity == 9.81
            start, goal = scene.task.initial.q, scene.task.final.q
            assert crosses(scene.robot, start, goal), name
            assert crossing_zeros(scene).size % 2 == 1, name  # odd: a sign change
            assert np.abs(np.subtract(goal, start)).max() <= MOVE + 1e-9, name


def test_random_arms_with_a_square_block_cross_a_waveless_singularity(suite):
    square = 0
    for name, scene in suite:
        robot = scene.robot
        if category(name) in ("links-5to8", "free-time") \
                and len(robot.passive) == len(robot.active):
            square += 1
            assert crosses(robot, scene.task.initial.q, scene.task.final.q), name
    assert square > 0


def test_swings_move_an_active_joint_by_two_radians_in_gravity(suite):
    for name, scene in suite:
        if category(name) == "seed-swing":
            assert _seed_like(scene, 9.81), name
            move = np.abs(np.subtract(scene.task.final.q, scene.task.initial.q))
            assert math.isclose(move[scene.robot.active].max(), SWING, abs_tol=1e-5), name


def test_many_link_arms_are_mixed_and_underactuated(suite):
    for name, scene in suite:
        if category(name) == "links-5to8":
            robot = scene.robot
            assert 5 <= robot.n <= 8, name
            assert 1 <= len(robot.passive) <= len(robot.active), name


def test_bounds_hold_at_start_and_goal_with_margin(suite):
    for name, scene in suite:
        task = scene.task
        if category(name) != "bounds":
            continue
        assert task.position_bounds is not None and task.velocity_bounds is not None
        for q in (task.initial.q, task.final.q):
            for k, (lo, hi) in enumerate(zip(task.position_bounds.lower,
                                             task.position_bounds.upper, strict=True)):
                assert lo is None or q[k] >= lo + BOUND_MARGIN - 1e-3, name
                assert hi is None or q[k] <= hi - BOUND_MARGIN + 1e-3, name
        assert any(v is not None for v in task.position_bounds.lower), name
        for lo, hi in zip(task.velocity_bounds.lower, task.velocity_bounds.upper, strict=True):
            assert (lo is None or lo < 0.0) and (hi is None or hi > 0.0), name


def test_tip_targets_are_a_reachable_configurations_tip(suite):
    for name, scene in suite:
        task = scene.task
        if category(name) != "tip-target":
            continue
        assert task.tip_target is not None and all(v is None for v in task.final.q)
        assert all(v == 0.0 for v in task.final.dq)
        reach = sum(link.length + (link.wave.amplitude if link.wave else 0.0)
                    for link in scene.robot.links)
        assert math.hypot(task.tip_target.x, task.tip_target.y) <= reach, name
        # not where the arm starts: the tip has to move
        start = Dynamics(scene.robot).tips(task.initial.q)[-1]
        assert math.dist(start, (task.tip_target.x, task.tip_target.y)) > 1e-3, name


def test_free_time_and_torque_limits(suite):
    for name, scene in suite:
        task, kind = scene.task, category(name)
        if kind == "free-time":
            assert isinstance(task.duration, DurationRange) and task.objective.time > 0.0
        if kind == "torque-limit":
            assert isinstance(task.duration, DurationRange) and task.objective.time > 0.0
            assert isinstance(task.torque_limit, float) and task.torque_limit > 0.0
            # the slowest straight move fits, the fastest allowed would exceed the limit
            assert task.torque_limit >= ROOM * guess_peak(scene, task.duration.max), name
            assert guess_peak(scene, task.duration.min) >= ROOM * task.torque_limit, name


def test_co_design_keeps_the_margin_at_start_and_goal_and_has_a_witness(suite):
    for name, scene in suite:
        task = scene.task
        if category(name) != "co-design":
            continue
        assert task.co_design is not None and task.coupling_margin is not None
        robot = scene.robot
        ends = np.array([task.initial.q, task.final.q])
        assert along(robot, ends).sigma_min.min() >= task.coupling_margin, name
        witness = along(robot, segment(task.initial.q, task.final.q))
        assert witness.sigma_min.min() >= task.coupling_margin, name
        first = along(design_start(robot, task.co_design.amplitude_max), ends[:1]).det
        assert witness.det is not None and first is not None
        assert np.all(np.sign(witness.det) == np.sign(first[0])), name
        # the waveless arm is singular in between: only waves keep the margin
        assert crosses(robot, task.initial.q, task.final.q), name


def test_scenes_keep_the_default_transcription_and_solver(suite):
    for name, scene in suite:
        assert scene.transcription.model_dump() == type(scene.transcription)().model_dump(), name
        assert scene.solver.model_dump() == type(scene.solver)().model_dump(), name


IPOPT_LOG = """\
iter    objective    inf_pr   inf_du lg(mu)  ||d||  lg(rg) alpha_du alpha_pr  ls
Least square estimates max(y_c) = 6.684418e+04, max(y_d) = 1.104530e+00
   0  2.5221651e-02 1.23e-01 1.00e+00   0.0 0.00e+00    -  0.00e+00 0.00e+00   0
Number of trial factorizations performed: 1
   1  2.5212587e-02 1.23e-01 2.61e+00   0.3 1.01e+03    -  1.60e-01 4.82e-05h 12
Number of trial factorizations performed: 3
  44r 2.5319039e+00 1.09e+01 9.99e+02   1.0 0.00e+00  -4.1 0.00e+00 8.32e-11R  2
Number of trial factorizations performed: 2
  45r 2.5675835e+00 1.04e+01 9.99e+02  -5.0 5.35e+04    -  1.71e-04 2.56e-05f  1
"""


def test_the_bench_counts_restoration_iterations_and_factorizations_in_ipopts_log():
    from bench.suite import log_counts, supported

    assert log_counts(IPOPT_LOG, 3) == {"restoration": 2, "factorizations": 7}
    assert all(math.isnan(v) for v in log_counts("no log here", 10).values())
    assert log_counts("", 0) == {"restoration": 0, "factorizations": 0}
    kinds = {category(name) for name, scene in hard_tasks(12, SEED) if supported(scene)}
    assert kinds == {"seed-g0-cross", "seed-g9.81-cross", "seed-swing", "links-5to8"}
