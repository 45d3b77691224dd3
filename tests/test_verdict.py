"""A plan's verdict: "verified" only when the delivered plan does the task, one status
word for what happened to the plan (planner.ocp.verdict), and every requirement of the
task checked on the delivered polynomials (planner.ocp.task_checks)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.ocp.evidence import Infeasibility
from planner.ocp.planner import plan
from planner.ocp.task_checks import MARGIN_RTOL, requirements
from planner.ocp.verdict import unverified_reason, verdict
from planner.ocp.verification import Verification
from planner.ocp.verify import verify
from planner.scene import Scene
from testbed.robots import chain_scene, tip_of


def with_task(scene: Scene, solver: dict | None = None, **task) -> Scene:
    data = scene.model_dump(exclude_unset=True)
    data["task"].update(task)
    data["solver"] = {**data.get("solver", {}), **(solver or {})}
    return Scene.model_validate(data)


@pytest.fixture(scope="module")
def done() -> tuple[Scene, object]:
    """A verified plan of the two-link chain (0.5 rad rest to rest in 1 s, gravity)."""
    scene = chain_scene(2, intervals=20)
    result = plan(scene)
    assert result.status == "verified" and result.verification.verified
    return scene, result


def test_a_plan_stopped_before_it_converged_is_never_verified_and_shows_its_tip_error():
    # a 6-link arm with a tip target and one iteration: the plan is the stand-still guess
    scene = with_task(chain_scene(6, intervals=20), solver={"max_iter": 1, "retries": 0},
                      final={"q": [None] * 6, "dq": [0.0] * 6},
                      tip_target={"x": 0.5, "y": 1.8})
    result = plan(scene)
    v = result.verification
    assert not result.solver.success and v.converged is False and v.verified is False
    assert result.status == "out-of-budget"
    assert result.message.startswith("out of budget: no converged plan before the iteration "
                                     "limit was reached (Maximum_Iterations_Exceeded)")
    end = np.asarray(result.q[-1])
    expected = float(np.linalg.norm(tip_of(scene.robot, end) - [0.5, 1.8]))
    assert v.tip_error == pytest.approx(expected, rel=1e-9) and v.tip_error > 0.1
    assert any(s.startswith("the plan's final tip is at") for s in v.task_violations)


def test_a_converged_plan_that_fails_its_checks_says_unverified_at_the_top():
    # the refinement cannot reach 1e-12 rad in one pass: the last solve converged, the
    # plan is not verified, and the plan's own status says so above the solver's
    scene = chain_scene(2, intervals=10, refinement={"max_passes": 1},
                        solver={"resimulation_tolerance": 1e-9, "retries": 0})
    result = plan(scene)
    assert result.solver.status == "Solve_Succeeded" and result.solver.success
    assert result.verification.converged is True and result.verification.verified is False
    assert result.status == "unverified"
    assert result.message.startswith("unverified: re-integrated interval by interval, the "
                                     "delivered torque departs from the plan by")


def test_the_final_state_initial_state_and_tip_are_checked_on_the_delivered_plan(done):
    scene, result = done
    interp, robot = result.interpolant(), scene.robot
    t = np.asarray(result.dense.t)
    sigma = np.asarray(result.verification.sigma_min, float)
    own = requirements(robot, interp, t, scene.task, sigma, None, 1e-3)
    assert own.violations == [] and own.initial_error < 1e-8 and own.final_error < 1e-8
    moved = with_task(scene, final={"q": [0.51, 0.6], "dq": [0.0, 0.0]},
                      initial={"q": [0.0, 0.1], "dq": [0.0, 0.02]}).task
    found = requirements(robot, interp, t, moved, sigma, None, 1e-3)
    assert found.final_error == pytest.approx(0.01, abs=1e-8)
    assert found.initial_error == pytest.approx(0.02, abs=1e-8)
    assert found.violations[0].startswith("the plan's initial dq of joint 1 is ")
    assert found.violations[1].startswith("the plan's final q of joint 0 is 0.5 rad where the "
                                          "task asks 0.51 rad (off by 0.01 rad")
    end = tip_of(robot, np.asarray(result.q[-1]))
    aimed = with_task(scene, tip_target={"x": float(end[0]) + 0.03, "y": float(end[1])}).task
    found = requirements(robot, interp, t, aimed, sigma, None, 1e-3)
    assert found.tip_error == pytest.approx(0.03, abs=1e-9)
    assert found.violations == [found.violations[0]] and "0.03 m from the task's target" \
        in found.violations[0]


def test_the_duration_and_the_coupling_margin_are_checked_on_the_delivered_plan(done):
    scene, result = done
    interp, robot = result.interpolant(), scene.robot
    t = np.asarray(result.dense.t)
    sigma = np.asarray(result.verification.sigma_min, float)
    longer = with_task(scene, duration={"min": 1.2, "max": 2.0}).task
    found = requirements(robot, interp, t, longer, sigma, None, 1e-3)
    assert found.duration_excess == pytest.approx(0.2)
    assert found.violations == ["the plan lasts 1 s, outside the task's [1.2, 2] s"]
    least = float(np.nanmin(sigma))
    kept = requirements(robot, interp, t, with_task(scene, coupling_margin=least).task,
                        sigma, None, 1e-3)
    assert kept.margin_shortfall == 0.0 and kept.violations == []
    above = least * (1 + 10 * MARGIN_RTOL)
    found = requirements(robot, interp, t, with_task(scene, coupling_margin=above).task,
                         sigma, None, 1e-3)
    assert found.margin_shortfall == pytest.approx(above - least)
    assert found.violations[0].startswith(f"sigma_min(M_pa) falls to {least:.6g} at t = ")


def _verification(**fields) -> Verification:
    base = {"resimulation_error": 0.0, "resimulation_status": "completed", "defect": 0.0,
            "min_sigma": None, "waveless_min_sigma": None, "waveless_singular_crossings": [],
            "verified": True, "converged": True, "local_error": 1e-6, "tolerance": 1e-3}
    return Verification.model_validate({**base, **fields})


@pytest.mark.parametrize(("converged", "status", "checks", "infeasible", "word"), [
    (True, "Solve_Succeeded", {}, None, "verified"),
    (True, "Solve_Succeeded", {"verified": False, "local_error": 0.2}, None, "unverified"),
    (False, "Maximum_WallTime_Exceeded", {"verified": False, "converged": False}, None,
     "out-of-budget"),
    (False, "Maximum_Iterations_Exceeded", {"verified": False, "converged": False}, None,
     "out-of-budget"),
    (False, "Restoration_Failed", {"verified": False, "converged": False}, None,
     "solver-failure"),
    (False, "User_Requested_Stop", {"verified": False, "converged": False}, None, "cancelled"),
    (False, "Maximum_WallTime_Exceeded", {"verified": False, "converged": False},
     "duration", "infeasible"),
    (False, "Restoration_Failed", {"verified": False, "converged": False}, "checks",
     "infeasible"),
    (False, "Infeasible_Problem_Detected", {"verified": False, "converged": False},
     "solver", "solver-failure"),
])
def test_one_word_says_what_happened_to_the_plan(converged, status, checks, infeasible, word):
    # agreeing starts that end locally infeasible prove nothing: a solver failure
    found = None if infeasible is None else Infeasibility(
        source=infeasible, summary="the task cannot be done in 0.4 s")
    said, message = verdict(converged, status, "said", _verification(**checks), found)
    assert said == word
    if word == "infeasible":
        assert message == "infeasible: the task cannot be done in 0.4 s"
    if infeasible == "solver":
        assert message == "solver failure: the task cannot be done in 0.4 s"
    if word == "unverified":
        assert message.startswith("unverified: re-integrated interval by interval")


def test_a_plan_whose_solve_did_not_converge_is_not_verified_however_good_it_looks(done):
    scene, result = done
    v0 = result.verification
    errors = np.asarray(v0.interval_errors, float)
    checks = (scene.robot, result.interpolant(), np.asarray(result.dense.t), errors,
              "completed", scene.task, scene.solver)
    v, _ = verify(*checks, converged=True)
    assert v.verified is True
    v, _ = verify(*checks, converged=False)
    assert v.verified is False and v.task_violations == [] and v.limit_violations == []
    assert unverified_reason(v) == ("its last solve did not converge, so the returned iterate "
                                    "is no solution of the task's NLP")


@pytest.fixture(scope="module")
def two_link() -> tuple[dict, float]:
    """The two-link example's request and the peak of its delivered torque [N m]."""
    import copy

    from planner.examples import example

    request = copy.deepcopy(example("two-link-plan").request)
    own = plan(Scene.model_validate(request))
    assert own.status == "verified"
    return request, float(np.abs(np.asarray(own.dense.tau)).max())


@pytest.mark.parametrize("factor", [1.02, 1.5, 10.0])
def test_a_limit_the_unlimited_plan_keeps_never_makes_the_task_infeasible(two_link, factor):
    # under a limit above its own plan's peak torque the example had been held infeasible
    # by two starts that agreed (after 17 to 31 s); it is verified now
    request, peak = two_link
    request = {**request, "task": {**request["task"], "torque_limit": factor * peak}}
    result = plan(Scene.model_validate(request))
    assert result.status == "verified", result.message


@pytest.mark.parametrize("margin", [1e-4, 1e-6])
def test_a_looser_coupling_margin_never_makes_the_task_infeasible(two_link, margin):
    request, _ = two_link
    assert request["task"]["coupling_margin"] > margin
    request = {**request, "task": {**request["task"], "coupling_margin": margin},
               "solver": {**request.get("solver", {}), "max_wall_time": 600.0}}
    result = plan(Scene.model_validate(request))  # a budget no busy machine runs out of
    assert result.status == "verified", result.message


def test_a_duration_probe_at_a_local_minimum_is_refuted_by_a_second_start(monkeypatch):
    # a suite's task whose probe is made to say the duration too short (a time-optimal
    # solve that ends at a local minimum above the task's duration; which solve ends where
    # depends on Ipopt's path), after a first start given no time at all (so the probe
    # runs whatever path that start would take), while the classical inverse dynamics as
    # the guess converges at the task's own duration. A budget long enough that every
    # other solve ends by its iterations, not by the clock
    from dataclasses import replace

    from planner.ocp import shortest
    from testbed.suites.ordinary import tasks

    own = shortest.probe
    monkeypatch.setattr(shortest, "probe",
                        lambda *args: replace(own(*args), too_short=True))
    monkeypatch.setattr(shortest, "FIRST_SHARE", 1e-9)
    scene = dict(tasks())["3-AAP-g9.81-r19"]
    scene = scene.model_copy(update={
        "solver": scene.solver.model_copy(update={"max_wall_time": 600.0})})
    result = plan(scene)
    strategies = [p.strategy for p in result.mesh_passes]
    assert result.mesh_passes[1].status == "Maximum_WallTime_Exceeded"
    assert any(s.startswith("shortest-duration probe, time-optimal") for s in strategies)
    assert result.status == "verified" and result.infeasibility is None, result.message
    assert result.solver.strategy.startswith("inverse-dynamics start")
