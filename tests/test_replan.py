"""Replanning from a measured state (`planner.ocp.replan`): from the plan's own state it
gives the plan back; from a pushed state it plans to the same goal; bad states are refused
by field."""

from __future__ import annotations

import copy
import threading

import numpy as np
import pytest

from planner.errors import InputError
from planner.examples import example
from planner.ocp import plan
from planner.ocp.instance import instance
from planner.ocp.mesh import Mesh
from planner.ocp.replan import ACCEPTED_VIOLATION, FINAL_STRETCH, HELD, Replan, Replanner
from planner.ocp.result import Plan
from planner.ocp.solve import BUSY, Budget, solve
from planner.scene import Scene, State
from planner.simulate import simulate


@pytest.fixture(scope="module")
def planned() -> tuple[Scene, Plan]:
    """The two-link example on its own uniform mesh (no refinement), and its plan."""
    request = copy.deepcopy(example("two-link-plan").request)
    request["transcription"]["refinement"] = {"enabled": False}
    scene = Scene.model_validate(request)
    result = plan(scene)
    assert result.solver.success
    return scene, result


def _times(T: float, start: float = 0.0) -> np.ndarray:
    return np.linspace(start, T, 41)


def test_a_replan_from_the_plans_own_state_at_time_zero_reproduces_it(planned):
    scene, earlier = planned
    replan = Replanner(scene, earlier).update(0.0, earlier.q[0], earlier.dq[0],
                                              mode="converged")
    assert replan.success and replan.within and not replan.fallback
    t = _times(earlier.duration)
    planned_tau = np.asarray(earlier.torque.evaluate(t.tolist()))
    scale = np.abs(planned_tau).max()
    assert np.abs(replan.torque(t) - planned_tau).max() <= 1e-5 * scale
    q_plan = np.asarray(earlier.states.polynomials()[0](t))
    assert np.abs(replan.interp.q(t) - q_plan).max() <= 1e-6


def test_a_replan_from_a_pushed_state_plans_to_the_same_goal(planned):
    scene, earlier = planned
    T = earlier.duration
    at = 0.25 * T
    q_p, dq_p = earlier.states.polynomials()
    q = np.asarray(q_p([at]))[0]
    dq = np.asarray(dq_p([at]))[0] + np.array([0.2, 0.0])  # a push on the passive shoulder
    replan = Replanner(scene, earlier).update(at, q.tolist(), dq.tolist(), mode="converged",
                                              verify=True)
    assert replan.success and replan.within, replan
    assert replan.interval_error is not None
    assert np.allclose(replan.interp.q([0.0])[0], q, atol=1e-9)
    assert np.allclose(replan.interp.dq([0.0])[0], dq, atol=1e-9)
    goal = np.asarray(scene.task.final.q, float)
    end = replan.end - replan.start
    assert np.allclose(replan.interp.q([end])[0], goal, atol=1e-6)
    assert np.allclose(replan.interp.dq([end])[0], 0.0, atol=1e-6)


def test_a_moved_goal_is_planned_to_from_then_on(planned):
    scene, earlier = planned
    goal = (np.asarray(scene.task.final.q, float) + 0.05).tolist()
    replanner = Replanner(scene, earlier)
    at = 0.2 * earlier.duration
    q_p, dq_p = earlier.states.polynomials()
    moved = replanner.update(at, q_p([at])[0].tolist(), dq_p([at])[0].tolist(),
                             mode="converged", goal=State(q=goal, dq=[0.0, 0.0]))
    assert moved.success and moved.within
    end = moved.end - moved.start
    assert np.allclose(moved.interp.q([end])[0], goal, atol=1e-6)
    later = 0.4 * earlier.duration
    kept = replanner.update(later, moved.interp.q([later - at])[0].tolist(),
                            moved.interp.dq([later - at])[0].tolist(), mode="converged")
    assert np.allclose(kept.interp.q([kept.end - kept.start])[0], goal, atol=1e-6)


def test_real_time_updates_along_a_pushed_motion_stay_near_the_constraints(planned):
    scene, earlier = planned
    replanner = Replanner(scene, earlier)
    T = earlier.duration
    q_p, dq_p = earlier.states.polynomials()
    violations = []
    for k, at in enumerate(np.linspace(0.1, 0.5, 5) * T):
        q = np.asarray(q_p([at]))[0]
        dq = np.asarray(dq_p([at]))[0] + (np.array([0.05, 0.0]) if k == 0 else 0.0)
        replan = replanner.update(float(at), q.tolist(), dq.tolist())
        assert not replan.fallback and (replan.iterations <= 3 or replan.escalated)
        assert "dynamics at the knots" in replan.checked[0]
        assert replan.violation <= ACCEPTED_VIOLATION
        violations.append(replan.violation)
    assert max(violations[1:]) <= 1e-6, violations


def _pushed_updates(replanner: Replanner, earlier: Plan, push: float) -> list[np.ndarray]:
    """Real-time updates along the plan, the first from a state pushed by `push` [rad/s]
    (verified: every interval re-integrated); each update's planned angles."""
    q_p, dq_p = earlier.states.polynomials()
    out = []
    for k, at in enumerate(np.linspace(0.1, 0.5, 5) * earlier.duration):
        dq = np.asarray(dq_p([at]))[0] + (np.array([push, 0.0]) if k == 0 else 0.0)
        replan = replanner.update(float(at), np.asarray(q_p([at]))[0].tolist(), dq.tolist(),
                                  verify=True)
        out.append(np.asarray(replan.interp.q(replan.interp.q.breaks)))
    return out


def test_replanners_of_one_structure_updating_in_two_threads_at_once_answer_as_alone(planned):
    """A server's replanning sessions on plans of one structure share its cached NLP and
    integrators from threads of their own (two at once used to end the process with a
    segmentation fault): each answers exactly what it answers alone."""
    scene, earlier = planned
    pushes = (0.05, -0.04)
    alone = [_pushed_updates(Replanner(scene, earlier), earlier, push) for push in pushes]
    together: dict[float, list[np.ndarray]] = {}
    threads = [threading.Thread(target=lambda push=push: together.__setitem__(
        push, _pushed_updates(Replanner(scene, earlier), earlier, push))) for push in pushes]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(600)
    for push, own in zip(pushes, alone, strict=True):
        assert len(together[push]) == len(own)
        for mine, theirs in zip(together[push], own, strict=True):
            np.testing.assert_array_equal(mine, theirs)


def test_a_solve_whose_solver_another_thread_holds_past_its_budget_ends_at_its_wall_time(
        planned):
    scene, earlier = planned
    inst = instance(scene, scene.robot, Mesh.uniform(scene.transcription.intervals),
                    earlier.duration)
    budget = Budget.of(50, 0.2)
    with inst.problem.lock:  # held elsewhere for longer than the solve may wait
        solution = solve(inst, np.zeros(inst.problem.layout.size), budget, None, 0)
    assert (solution.status, solution.success, solution.iterations, solution.message) == (
        "Maximum_WallTime_Exceeded", False, 0, BUSY)
    assert budget.used == 0 and budget.solved is not None


def test_an_update_may_wait_as_long_as_a_float_allows(planned):
    """A wall time beyond what a lock's wait takes (threading.TIMEOUT_MAX) is no error."""
    scene, earlier = planned
    replan = Replanner(scene, earlier).update(0.0, earlier.q[0], earlier.dq[0],
                                              mode="converged", wall_time=1e300)
    assert replan.success and not replan.fallback


def test_a_rest_too_short_for_the_goal_keeps_the_last_plan(planned):
    scene, earlier = planned
    request = scene.model_dump()
    request["task"]["torque_limit"] = 5.0  # 0.5 rad in 10 ms needs some 10^4 rad/s^2
    request["solver"]["max_iter"] = 30  # ends there: no solve time in the verdict
    limited = Scene.model_validate(request)
    end = earlier.duration
    q = np.asarray(scene.task.final.q, float) - np.array([0.0, 0.5])
    replan = Replanner(limited, earlier, final_stretch=0.0).update(
        end - 0.01, q.tolist(), [0.0, 0.0], mode="converged")
    assert replan.fallback and replan.interp is None and not replan.within
    assert replan.violation > ACCEPTED_VIOLATION
    assert replan.checked[-1].endswith("the last plan's remainder stands")
    with pytest.raises(ValueError, match="carries no plan"):
        replan.torque(np.array([end]))


def test_an_update_in_the_final_stretch_holds_the_last_plan_without_a_solve(planned):
    scene, earlier = planned
    T = earlier.duration
    at = T * (1 - FINAL_STRETCH / 2)
    q_p, dq_p = earlier.states.polynomials()
    held = Replanner(scene, earlier).update(at, q_p([at])[0].tolist(), dq_p([at])[0].tolist())
    assert held.status == HELD and held.fallback and held.iterations == 0
    assert held.violation is None and held.interp is None and held.gains is None
    assert held.checked[0].startswith("nothing: in the final")


def _servo(scene: Scene, controller: Replan, x: np.ndarray, start: float, steps: int,
           step: float, feedback: bool) -> np.ndarray:
    """The nominal arm from x at `start` [s] through `steps` servo steps of `step` [s],
    each holding the controller's command (or its torque alone) for the state then."""
    for k in range(steps):
        ts = start + step * np.array([k, k + 1])
        tau = controller.command(ts[0], x) if feedback else controller.torque(ts[:1])[0]
        run = simulate(scene.robot, ts, tau[None, None, :], x)
        x = np.concatenate([run.q[-1], run.dq[-1]])
    return x


def test_an_updates_feedback_ends_a_pushed_arm_nearer_its_motion(planned):
    scene, earlier = planned
    T = earlier.duration
    at = 0.2 * T
    q_p, dq_p = earlier.states.polynomials()
    x = np.concatenate([q_p([at])[0], dq_p([at])[0]])
    replan = Replanner(scene, earlier).update(at, x[:2].tolist(), x[2:].tolist(),
                                              mode="converged")
    N = scene.transcription.intervals
    assert replan.gains is not None and replan.gains.shape == (N, 1, 4)
    assert np.allclose(replan.command(at, x), replan.torque([at])[0], atol=1e-9)
    pushed = x + np.array([0.0, 0.0, 0.05, 0.0])  # a push on the passive shoulder
    rest = 0.79 * T  # to just before the end, in 10 ms servo steps
    steps = int(rest / 0.01)
    planned_end = np.concatenate([replan.interp.q([rest])[0], replan.interp.dq([rest])[0]])
    errors = [np.abs(_servo(scene, replan, pushed, at, steps, rest / steps, fb)
                     - planned_end).max() for fb in (True, False)]
    assert errors[0] < 0.6 * errors[1], errors


def test_the_plan_itself_is_the_update_at_time_zero(planned):
    scene, earlier = planned
    own = Replan.of_plan(earlier)
    t = _times(earlier.duration)
    assert np.allclose(own.torque(t), earlier.torque.evaluate(t.tolist()), atol=1e-12)
    assert own.gains is not None and own.gains.shape == (len(earlier.torque.breaks) - 1, 1, 4)
    x = np.concatenate([earlier.q[3], earlier.dq[3]])
    assert np.allclose(own.command(earlier.t[3], x), own.torque([earlier.t[3]])[0], atol=1e-6)


@pytest.mark.parametrize(("q", "dq", "message"), [
    ([0.0, float("nan")], [0.0, 0.0], "q: every entry must be finite"),
    ([0.0], [0.0, 0.0], "q: needs 2 entries, one per joint"),
    ([0.0, 0.0], [0.0, 0.0, 0.0], "dq: needs 2 entries, one per joint"),
])
def test_a_bad_state_is_refused_by_its_field(planned, q, dq, message):
    scene, earlier = planned
    with pytest.raises(InputError) as raised:
        Replanner(scene, earlier).update(0.1, q, dq)
    assert str(raised.value) == message


def test_a_time_past_the_plan_is_refused(planned):
    scene, earlier = planned
    with pytest.raises(InputError, match=r"^t: must lie in \[0, "):
        Replanner(scene, earlier).update(earlier.duration, earlier.q[-1], earlier.dq[-1])


def test_a_state_beyond_the_tasks_bounds_is_refused(planned):
    scene, earlier = planned
    request = scene.model_dump()
    request["task"]["position_bounds"] = {"lower": [None, -0.5], "upper": [None, 0.5]}
    bounded = Scene.model_validate(request)
    with pytest.raises(InputError) as raised:
        Replanner(bounded, earlier).update(0.1, [0.0, 0.7], [0.0, 0.0])
    assert str(raised.value) == "q.1: 0.7 lies beyond the task's bounds"


def test_a_fallback_whose_point_was_not_finite_reports_no_number_that_json_refuses():
    import json
    import math

    from planner.ocp.replan_report import ReplanReport

    lost = Replan(0.5, 2.0, None, "Invalid_Number_Detected", False, 3, math.inf, ("rows",),
                  None, False, True, True, None, 0.01, 0.01)
    body = ReplanReport.of(lost).model_dump(mode="json")
    assert body["violation"] is None and body["torque"] is None
    json.dumps(body, allow_nan=False)
