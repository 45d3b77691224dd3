"""The hard suite (testbed.suites.hard): reproducible, every category, feasible by
construction as far as can be checked without a solve, and a bounds task's bounds held by
a stored witness and left by the unbounded plan. One solve: a stored witness solved again
(about 2 s)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.coupling_block import along
from planner.dynamics import Dynamics
from planner.examples import seed_arm
from planner.ocp.verify import BOUND_TOL
from planner.scene import DurationRange
from testbed.suites import hard as hard_suite
from testbed.suites.hard import (
    BOUND_MARGIN,
    CATEGORIES,
    COUNT,
    HELD_OUT,
    MOVE,
    ROOM,
    SEED,
    SPEED_CUT,
    SWING,
    category,
    category_tasks,
    check,
    crosses,
    crossing_zeros,
    design_start,
    guess_peak,
    hard_tasks,
    segment,
)


@pytest.fixture(scope="module", params=[SEED, *HELD_OUT])
def suite(request):
    return hard_tasks(COUNT, request.param)


@pytest.fixture(scope="module", params=[SEED, *HELD_OUT])
def bounded(request):
    """The bounds tasks of a seed: the suite's and the extra category's of 5 links."""
    return [t for t in hard_tasks(COUNT, request.param) if category(t[0]) == "bounds"] + \
        category_tasks("bounds-5-links", seed=request.param)


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


def test_bounds_hold_at_start_and_goal_with_margin(bounded):
    for name, scene in bounded:
        task = scene.task
        assert task.position_bounds is not None and task.velocity_bounds is not None
        for q in (task.initial.q, task.final.q):
            for k, (lo, hi) in enumerate(zip(task.position_bounds.lower,
                                             task.position_bounds.upper, strict=True)):
                assert lo is None or q[k] >= lo + BOUND_MARGIN - 1e-3, name
                assert hi is None or q[k] <= hi - BOUND_MARGIN + 1e-3, name
        assert any(v is not None for v in task.position_bounds.lower), name
        for lo, hi in zip(task.velocity_bounds.lower, task.velocity_bounds.upper, strict=True):
            assert (lo is None or lo < 0.0) and (hi is None or hi > 0.0), name


def _bounds_tasks(bounded):
    """(name, scene, what its witness solves found) of bounds tasks."""
    out = []
    for name, scene in bounded:
        ends = np.array(scene.task.initial.q), np.array(scene.task.final.q)
        found = [w for seed in (SEED, *HELD_OUT)
                 if (w := hard_suite.stored_witness((seed, hard_suite.index_of(name)), *ends))
                 is not None]
        assert len(found) == 1, f"{name}: no stored witness"
        out.append((name, scene, found[0]))
    return out


def _limits(bounds):
    return (np.array([np.nan if v is None else v for v in bounds.lower]),
            np.array([np.nan if v is None else v for v in bounds.upper]))


def test_bounds_tasks_have_a_witness_within_their_bounds_that_touches_one(bounded):
    """Feasible by construction: a verified plan (the witness) keeps every bound, and
    touches one within 1 % (position: of its range, rate: of the bound)."""
    for name, scene, found in _bounds_tasks(bounded):
        assert found.free is not None and found.witness is not None
        w = found.witness
        (q_lo, q_hi), (v_lo, v_hi) = (_limits(scene.task.position_bounds),
                                      _limits(scene.task.velocity_bounds))
        tol = BOUND_TOL * np.maximum(1.0, np.abs(np.nan_to_num(q_hi)))
        assert np.all(~(np.array(w.q_min) < q_lo - tol)), name
        assert np.all(~(np.array(w.q_max) > q_hi + tol)), name
        assert np.all(~(np.array(w.rate_max) > v_hi + BOUND_TOL * np.maximum(1.0, v_hi))), name
        assert np.array_equal(np.isnan(v_lo), np.isnan(q_lo)), name  # the same joints
        span = np.array(w.q_max) - np.array(w.q_min)
        gaps = np.concatenate([(np.array(w.q_min) - q_lo) / span, (q_hi - np.array(w.q_max)) / span,
                               (v_hi - np.array(w.rate_max)) / v_hi])
        assert np.nanmin(gaps) <= 0.01, name


def test_the_unbounded_plan_leaves_a_bounds_tasks_bounds(bounded):
    """The bounds bind: the unbounded plan of the move exceeds every bounded joint's rate
    bound by the cut (a task whose witness needed no cut, scale 0, has its bounds touch it
    instead, which the test above holds)."""
    cut = 0
    for name, scene, found in _bounds_tasks(bounded):
        assert found.free is not None
        _, v_hi = _limits(scene.task.velocity_bounds)
        rate = np.array(found.free.rate_max)
        bounded = ~np.isnan(v_hi)
        if found.scale > 0.0:
            cut += 1
            beyond = rate[bounded] / v_hi[bounded]
            assert np.all(beyond >= 1.0 + found.scale * SPEED_CUT[0] / 2), name
    assert cut > 0


def test_a_stored_witness_is_what_its_solves_find():
    """A bounds task drawn with its witness solved afresh (the cheapest of the stored ones:
    a vertical arm, 75 iterations) has the stored task's bounds, to their rounding."""
    seed, index = HELD_OUT[1], 19
    stored = dict(hard_tasks(index + 1, seed))[f"bounds-{index}"]
    fresh = hard_suite._task("bounds", np.random.default_rng([seed, index]),
                             stored.robot.gravity)
    assert fresh.task.initial == stored.task.initial and fresh.task.final == stored.task.final
    for field in ("position_bounds", "velocity_bounds"):
        a, b = getattr(fresh.task, field), getattr(stored.task, field)
        for x, y in zip([*a.lower, *a.upper], [*b.lower, *b.upper], strict=True):
            assert (x is None) == (y is None) and (x is None or abs(x - y) <= 2e-3), field


def test_the_extra_category_is_drawn_apart_from_the_suite_and_has_five_links():
    drawn = category_tasks("bounds-5-links", seed=SEED)
    assert [name for name, _ in drawn] == [f"bounds-5-links-{i:02d}" for i in range(8)]
    assert all(scene.robot.n == 5 and scene.robot.passive for _, scene in drawn)
    assert [s.robot.gravity for _, s in drawn] == [0.0, 9.81] * 4
    assert {category(name) for name, _ in hard_tasks(COUNT, SEED)} == set(CATEGORIES)
    assert all(check(scene) == [] for _, scene in drawn)


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
    from bench.suite import log_counts, per_iteration, supported

    assert log_counts(IPOPT_LOG, 3) == {"restoration": 2, "factorizations": 7,
                                        "logged_iterations": 3}
    assert all(math.isnan(v) for v in log_counts("no log here", 10).values())
    assert log_counts("", 0) == {"restoration": 0, "factorizations": 0, "logged_iterations": 0}
    rows = [{"factorizations": 7, "logged_iterations": 3},
            {"factorizations": math.nan, "logged_iterations": math.nan},
            {"factorizations": 5, "logged_iterations": ""}]
    assert per_iteration(rows) == pytest.approx(7 / 3)
    kinds = {category(name) for name, scene in hard_tasks(12, SEED) if supported(scene)}
    assert kinds == {"seed-g0-cross", "seed-g9.81-cross", "seed-swing", "links-5to8"}
