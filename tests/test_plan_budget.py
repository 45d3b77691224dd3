"""One budget for a whole plan: the solves stop early enough for the checks after them,
the optional checks are skipped once the budget is out, and a plan returns within
solver.max_wall_time plus the stated margin."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest

from app.settings import Settings
from planner.ocp.accuracy import CHUNK, interval_errors
from planner.ocp.feedback import growth_factor
from planner.ocp.planner import plan
from planner.ocp.result import Progress
from planner.ocp.solve import MARGIN, RESERVE_SHARE, Budget, checks_time
from planner.ocp.verify import SKIPPED_REPLAYS, open_loop
from testbed.robots import chain_scene


def test_the_reserve_is_the_checks_estimate_at_most_a_share_of_the_budget():
    budget = Budget.of(100, 60.0)
    budget.keep_for_checks(400, 6)
    assert budget.reserve == pytest.approx(checks_time(400, 6)) == pytest.approx(2.6)
    budget.measured = 2.0  # the latest solve's interval errors took 2 s: the final checks
    budget.keep_for_checks(400, 6)  # may take six times that
    assert budget.reserve == pytest.approx(12.0)
    short = Budget.of(100, 1.0)
    short.keep_for_checks(400, 6)
    assert short.reserve == pytest.approx(RESERVE_SHARE * 1.0)
    assert short.solves_until == pytest.approx(short.deadline - short.reserve)
    assert not short.spent
    short.deadline = time.perf_counter() + short.reserve / 2
    assert short.spent  # within the reserve: no further solve starts


def test_the_solves_stop_a_reserve_before_the_deadline():
    """A 4-link task with a coupling margin whose iterations are slowed to at least
    PACE s each, so that it cannot converge in 2 s on any machine: its last iteration comes
    at least the reserve (a quarter of the budget here) before the end."""
    wall, pace = 2.0, 0.08
    scene = chain_scene(4, extra="margin", intervals=100, solver={"max_wall_time": wall})
    last: list[float] = []

    def progress(report: Progress) -> bool:
        last[:] = [report.elapsed]
        time.sleep(pace)
        return True

    start = time.perf_counter()
    p = plan(scene, progress)
    elapsed = time.perf_counter() - start
    assert p.solver.status == "Maximum_WallTime_Exceeded", p.solver.status
    assert last[0] < wall - RESERVE_SHARE * wall + 0.25  # one iteration late at most
    assert elapsed < wall + MARGIN
    assert p.solver.total_time is not None and p.solver.total_time < wall + MARGIN


def test_a_tiny_budget_returns_within_it_plus_the_margin_and_says_what_it_skipped():
    scene = chain_scene(2, intervals=10, solver={"max_wall_time": 1e-3})
    start = time.perf_counter()
    p = plan(scene)
    assert time.perf_counter() - start < 1e-3 + MARGIN
    assert p.verification.skipped == [SKIPPED_REPLAYS]
    assert p.verification.closed_loop_error is None
    assert p.verification.growth_factor is not None  # the cheap checks still ran


def test_a_plan_within_its_budget_runs_every_check():
    p = plan(chain_scene(2, intervals=10))
    assert p.verification.verified and p.verification.skipped == []
    assert p.verification.closed_loop_error is not None


def test_the_service_grace_exceeds_the_plans_margin():
    """A job that keeps its budget returns within max_wall_time + MARGIN: the default grace
    before its worker is stopped is longer."""
    assert Settings.model_fields["wall_time_grace"].default > MARGIN


def test_the_interval_errors_and_the_replay_stop_at_the_deadline():
    """On 60 intervals (over CHUNK), a deadline already past leaves every interval
    unchecked and says where; a deadline ahead changes nothing."""
    scene = chain_scene(2, intervals=60, refinement={"enabled": False})
    interp, robot = plan(scene).interpolant(), scene.robot
    assert interp.tau.coeffs.shape[0] == 60 > CHUNK
    free, status = interval_errors(robot, interp)
    assert status == "completed"
    ahead, status = interval_errors(robot, interp, deadline=time.perf_counter() + 60)
    assert status == "completed" and np.array_equal(ahead, free)
    past, status = interval_errors(robot, interp, deadline=time.perf_counter() - 1)
    assert np.all(np.isinf(past))
    assert status == ("stopped at interval 0 of 60: the plan's wall-time budget "
                      "(solver.max_wall_time) ran out")
    error, status = open_loop(robot, interp, deadline=time.perf_counter() - 1)
    assert error is None and status.startswith("stopped at t = 0 s: ")
    assert open_loop(robot, interp, deadline=time.perf_counter() + 60) == open_loop(robot,
                                                                                   interp)


def test_an_overflowing_transition_matrix_has_no_growth_factor():
    huge = np.full((3, 2, 2), 1e200)
    assert growth_factor(SimpleNamespace(A=huge)) is None
    assert growth_factor(SimpleNamespace(A=np.stack([np.eye(2) * 2] * 3))) \
        == pytest.approx(8.0)
