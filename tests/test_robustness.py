"""A plan's feedback on perturbed models of its robot (task.uncertainty, solver.robustness)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from pydantic import ValidationError

from planner.examples import example
from planner.model import Robot
from planner.ocp import plan
from planner.ocp.feedback import replay
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.result import Plan
from planner.ocp.robustness import models, robustness
from planner.ocp.transcription import Interpolant
from planner.ocp.verdict import unverified_reason
from planner.scene import Scene, Uncertainty
from planner.simulate import SimulationRequest, run, simulate


def _scene(**changes) -> Scene:
    request = copy.deepcopy(example("two-link-plan").request)
    request["task"]["uncertainty"] = {"mass": 0.1}
    request["solver"].update(changes)
    return Scene.model_validate(request)


@pytest.fixture(scope="module")
def planned() -> tuple[Scene, Plan]:
    scene = _scene()
    return scene, plan(scene)


def _interp(result: Plan) -> Interpolant:
    """The plan's own polynomials (states, delivered torque) as one interpolant."""
    assert result.states is not None and result.torque is not None
    q, dq = result.states.polynomials()
    tau = PiecewisePolynomial(np.asarray(result.torque.breaks),
                              np.asarray(result.torque.coefficients))
    return Interpolant(q, dq, tau)


def test_the_models_are_the_corners_of_the_stated_kinds():
    robot = Robot.model_validate(example("seed-arm-plan").request["robot"])
    corners = models(robot, Uncertainty(mass=0.1, length=0.05))
    assert [label for label, _ in corners] == ["mass- length-", "mass- length+",
                                               "mass+ length-", "mass+ length+"]
    heavy_long = dict(corners)["mass+ length+"]
    for before, after in zip(robot.links, heavy_long.links, strict=True):
        assert after.mass == pytest.approx(1.1 * before.mass)
        assert after.length == pytest.approx(1.05 * before.length)
        assert after.inertia == before.inertia
        if before.wave is not None:
            assert after.wave is not None and after.wave.amplitude == before.wave.amplitude
    assert [label for label, _ in models(robot, Uncertainty())] == [""]


def test_the_feedback_holds_a_heavier_arm_near_the_plan_where_the_torque_alone_does_not(
        planned: tuple[Scene, Plan]):
    scene, result = planned
    report = result.verification.robustness
    assert report is not None and report.models == 2
    assert report.worst_tracking_error is not None and report.worst_final_error is not None
    # the perturbation is applied: on the planned arm the closed loop is exact
    assert result.verification.closed_loop_error < 1e-2 * report.worst_tracking_error
    interp = _interp(result)
    start = np.concatenate([interp.q(interp.q.breaks[:1])[0],
                            interp.dq(interp.q.breaks[:1])[0]])
    open_loop = [replay(model, interp, start[None, :], None)[0][0]
                 for _, model in models(scene.robot, Uncertainty(mass=0.1))]
    assert report.worst_tracking_error < 0.2 * max(e for e in open_loop if e is not None)
    # at the end too: the torque alone leaves the heavier arm farther from the goal
    assert report.open_loop_final_error is not None
    assert report.worst_final_error < 0.5 * report.open_loop_final_error
    # gains of the wrong sign push the arm away: the report sees it
    K = np.asarray(result.feedback.gains)
    wrong = robustness(scene.robot, interp, -K, Uncertainty(mass=0.1), None)
    assert wrong.worst_tracking_error is None or \
        wrong.worst_tracking_error > 5 * report.worst_tracking_error


def test_a_bound_the_closed_loop_misses_leaves_the_plan_unverified_and_says_why(
        planned: tuple[Scene, Plan]):
    _, result = planned
    worst = result.verification.robustness.worst_tracking_error
    tight = plan(_scene(robustness=worst / 2))
    assert tight.verification.robustness.within is False
    assert tight.verification.verified is False
    assert unverified_reason(tight.verification) == (
        f"with its feedback on the perturbed model "
        f"{tight.verification.robustness.worst_model!r} the arm departs from the plan by up "
        f"to {tight.verification.robustness.worst_tracking_error:.3g} rad "
        f"(solver.robustness {worst / 2:g} rad)")
    loose = plan(_scene(robustness=2 * worst))
    assert loose.verification.robustness.within is True and loose.verification.verified


def test_the_simulation_applies_the_plans_feedback_as_the_verification_does(
        planned: tuple[Scene, Plan]):
    # an independent integration of the closed loop (planner.simulate's own CVODES set-up)
    # on the worst model reproduces the verification's worst tracking error
    scene, result = planned
    report = result.verification.robustness
    model = dict(models(scene.robot, Uncertainty(mass=0.1)))[report.worst_model]
    request = SimulationRequest.model_validate({
        "robot": model.model_dump(mode="json"), "torque": result.torque.model_dump(),
        "initial": {"q": result.q[0], "dq": result.dq[0]}, "samples_per_interval": 4,
        "feedback": {"gains": result.feedback.gains, "q": result.q, "dq": result.dq}})
    closed = run(request)
    interp = _interp(result)
    error = float(np.abs(np.asarray(closed.q) - interp.q(np.asarray(closed.t))).max())
    assert closed.status == "completed"
    assert error == pytest.approx(report.worst_tracking_error, rel=1e-4)
    open_loop = run(request.model_copy(update={"feedback": None}))
    assert float(np.abs(np.asarray(open_loop.q) - interp.q(np.asarray(open_loop.t))).max()) \
        > 5 * error


def test_a_feedback_of_the_wrong_shape_is_refused_at_its_field(planned: tuple[Scene, Plan]):
    scene, result = planned
    with pytest.raises(ValidationError, match=r"feedback\.gains: needs 40 matrices, one per "
                                              r"interval \(got 39\)"):
        SimulationRequest.model_validate({
            "robot": scene.robot.model_dump(mode="json"), "torque": result.torque.model_dump(),
            "initial": {"q": result.q[0], "dq": result.dq[0]},
            "feedback": {"gains": result.feedback.gains[1:], "q": result.q, "dq": result.dq}})


def test_the_replays_saturate_at_the_torque_limit_and_say_what_the_feedback_asked(
        planned: tuple[Scene, Plan]):
    scene, result = planned
    interp, robot = _interp(result), scene.robot
    K = np.asarray(result.feedback.gains)
    start = np.concatenate([result.q[0], result.dq[0]])
    kicked = (start + 0.2)[None, :]  # far off the plan: the feedback asks for much
    (error, _, end, asked), = replay(robot, interp, kicked, K, ends=True)
    assert asked > np.abs(np.asarray(result.tau)).max()
    # a limit above what it asks changes nothing
    (same, _, end_same, _), = replay(robot, interp, kicked, K, ends=True,
                                     limit=np.full(len(robot.active), 2 * asked))
    assert same == error and np.array_equal(end_same, end)
    # a limit of 0 leaves the free motion, integrated here by planner.simulate on its own
    (_, _, stopped, _), = replay(robot, interp, kicked, K, ends=True,
                                 limit=np.zeros(len(robot.active)))
    breaks = np.asarray(result.t)
    free = simulate(robot, breaks, np.zeros((len(breaks) - 1, 1, len(robot.active))),
                    kicked[0])
    assert np.allclose(stopped, np.concatenate([free.q[-1], free.dq[-1]]), atol=1e-6)


def test_a_limited_plan_reports_the_largest_torque_its_feedback_commands_on_the_models():
    scene = _scene()
    data = scene.model_dump(exclude_unset=True)
    unlimited = plan(scene)
    data["task"]["torque_limit"] = 1.02 * float(np.abs(np.asarray(unlimited.tau)).max())
    limited = plan(Scene.model_validate(data))
    report = limited.verification.robustness
    assert limited.status == "verified" and report is not None
    assert report.largest_torque >= float(np.abs(np.asarray(limited.dense.tau)).max())
    assert report.saturated == (report.largest_torque > data["task"]["torque_limit"])


def test_the_closed_loop_and_the_models_replayed_together_answer_as_each_alone(
        planned: tuple[Scene, Plan]):
    """The verification replays the closed loop and the corner models as lanes of one
    stacked replay: each lane's figures are those of its replay on its own (planted: the
    report read from the wrong lanes, or the perturbed start left out, fails it)."""
    scene, result = planned
    interp, v = _interp(result), result.verification
    K = np.asarray(result.feedback.gains)
    start = np.concatenate([result.q[0], result.dq[0]])
    (closed, _), (perturbed, _) = replay(scene.robot, interp,
                                         np.stack([start, start + v.perturbation]), K)
    assert v.closed_loop_error == pytest.approx(closed, rel=1e-3)
    assert v.perturbed_closed_loop_error == pytest.approx(perturbed, rel=1e-3)
    alone = robustness(scene.robot, interp, K, Uncertainty(mass=0.1), None)
    assert v.robustness.worst_model == alone.worst_model
    for field in ("worst_tracking_error", "worst_final_error", "open_loop_final_error"):
        assert getattr(v.robustness, field) == pytest.approx(getattr(alone, field), rel=1e-3)
