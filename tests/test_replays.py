"""The batched replays (`planner.ocp.replays`: lanes mapped, intervals accumulated in
chunks) against the computation they replace: each replay on its own, interval by
interval, one CVODES call each, its feedback offset computed in numpy."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model import Robot, Structure
from planner.ocp import plan, replays
from planner.ocp.feedback import PERTURBATION, REPLAY_TOL, replay
from planner.ocp.flow import flow, inputs
from planner.ocp.replays import REPLAY_SAMPLES
from planner.ocp.robustness import models, robustness
from planner.ocp.transcription import Interpolant
from planner.scene import Scene, Uncertainty
from testbed.suites.ordinary import tasks

UNCERTAINTY = Uncertainty(mass=0.1, length=0.05)


def interval_by_interval(robot: Robot, interp: Interpolant, x0: np.ndarray,
                         K: np.ndarray | None, limit: np.ndarray | None,
                         tol: float = REPLAY_TOL) -> tuple[float, np.ndarray, float]:
    """One replay as the planner ran it before it batched them (CVODES rtol = atol = tol):
    its largest angle error [rad] at the comparison points, its final state and the
    largest torque commanded."""
    s = Structure.of(robot)
    breaks = interp.q.breaks
    one = flow(s, interp.tau.coeffs.shape[1] - 1, REPLAY_SAMPLES, 1, tol)
    params = inputs(robot, interp, limit)[1]
    x, worst, peak = np.asarray(x0, float), 0.0, 0.0
    for k in range(len(breaks) - 1):
        a, b = breaks[k], breaks[k + 1]
        planned = np.concatenate([interp.q([a])[0], interp.dq([a])[0]])
        u = np.zeros(len(s.active_idx)) if K is None else -K[k] @ (x - planned)
        t = a + (b - a) * np.arange(REPLAY_SAMPLES + 1) / REPLAY_SAMPLES
        peak = max(peak, float(np.abs(interp.tau(t) + u).max()))
        states = one(x[:, None], params[:, k:k + 1], np.repeat(u[:, None], REPLAY_SAMPLES, 1))
        worst = max(worst, float(np.abs(states[:s.n].T - interp.q(t[1:])).max()))
        x = states[:, -1]
    return worst, x, peak


@pytest.fixture(scope="module")
def unstable():
    """A suite task whose plan departs fast open loop, with its feedback gains."""
    scene = Scene.model_validate(dict(tasks())["2-AP-g9.81-x01"].model_dump())
    result = plan(scene)
    return scene, result.interpolant(), np.asarray(result.feedback.gains)


def _starts_and_limit(scene: Scene, interp: Interpolant) -> tuple[np.ndarray, np.ndarray]:
    """The planned start, one perturbed a little and one fifty times more (3, 2n), and a
    torque limit the feedback reaches (na,) [N m]."""
    breaks = interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    limit = np.full(len(scene.robot.active), 0.9 * np.abs(interp.tau(breaks)).max())
    return np.stack([start, start + PERTURBATION, start + 50 * PERTURBATION]), limit


@pytest.mark.parametrize("chunk", [replays.CHUNK, 7])
def test_a_batched_replay_agrees_with_the_replay_interval_by_interval(unstable, chunk,
                                                                      monkeypatch):
    """One lane at a time, with and without the feedback, from the planned and perturbed
    starts, with a torque limit the feedback reaches, in whole chunks and in ragged ones:
    the same integrator, so the same numbers."""
    monkeypatch.setattr(replays, "CHUNK", chunk)
    scene, interp, K = unstable
    starts, limit = _starts_and_limit(scene, interp)
    for gains in (K, None):
        for x0 in starts:
            error, status, end, peak = replay(scene.robot, interp, x0[None], gains, ends=True,
                                              limit=limit)[0]
            worst, final, most = interval_by_interval(scene.robot, interp, x0, gains, limit)
            assert status == "completed"
            assert error == pytest.approx(worst, rel=1e-9, abs=1e-12)
            assert np.allclose(end, final, rtol=1e-9, atol=1e-12)
            assert peak == pytest.approx(most, rel=1e-9)  # from the states, held to 1e-9


@pytest.mark.parametrize("chunk", [replays.CHUNK, 7])
def test_replays_stacked_in_one_run_are_each_held_to_their_tolerance(unstable, chunk,
                                                                     monkeypatch):
    """The three lanes of one call share each CVODES run (their states stacked into one
    ODE, at the tolerance divided by sqrt(3)): against the same replay at rtol = atol =
    1e-12, each lane's error and final state are as close as the lane replayed alone at
    the replays' tolerance (within a factor 3), and its commanded torque agrees."""
    monkeypatch.setattr(replays, "CHUNK", chunk)
    scene, interp, K = unstable
    robot = scene.robot
    starts, limit = _starts_and_limit(scene, interp)
    for gains in (K, None):
        done = replay(robot, interp, starts, gains, ends=True, limit=limit)
        for x0, (error, status, end, peak) in zip(starts, done, strict=True):
            alone, alone_end, _ = interval_by_interval(robot, interp, x0, gains, limit)
            exact, exact_end, most = interval_by_interval(robot, interp, x0, gains, limit,
                                                          1e-12)
            assert status == "completed"
            assert abs(error - exact) <= 3 * abs(alone - exact) + 1e-10
            assert np.abs(end - exact_end).max() <= 3 * np.abs(alone_end - exact_end).max()
            assert peak == pytest.approx(most, rel=1e-6)


def test_the_robustness_replays_agree_with_each_model_interval_by_interval(unstable):
    """Every corner model with the feedback and without it, eight lanes in one call: the
    report's figures as close to each model's replay at rtol = atol = 1e-12 as the model
    replayed alone at the replays' tolerance (within a factor 3)."""
    scene, interp, K = unstable
    robot, breaks = scene.robot, interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    goal = np.concatenate([interp.q(breaks[-1:])[0], interp.dq(breaks[-1:])[0]])
    report = robustness(robot, interp, K, UNCERTAINTY, None)

    def figures(tol: float) -> tuple[float, float, float, float]:
        closed = [interval_by_interval(model, interp, start, K, None, tol)
                  for _, model in models(robot, UNCERTAINTY)]
        alone = [interval_by_interval(model, interp, start, None, None, tol)
                 for _, model in models(robot, UNCERTAINTY)]
        return (max(c[0] for c in closed), max(np.abs(c[1] - goal).max() for c in closed),
                max(np.abs(a[1] - goal).max() for a in alone), max(c[2] for c in closed))
    alone, exact = figures(REPLAY_TOL), figures(1e-12)
    got = (report.worst_tracking_error, report.worst_final_error,
           report.open_loop_final_error, report.largest_torque)
    assert report.models == 4
    for value, one, best in zip(got[:3], alone[:3], exact[:3], strict=True):
        assert abs(value - best) <= 3 * abs(one - best) + 1e-10
    assert report.largest_torque == pytest.approx(exact[3], rel=1e-6)
