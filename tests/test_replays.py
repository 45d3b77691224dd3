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
                         K: np.ndarray | None, limit: np.ndarray | None
                         ) -> tuple[float, np.ndarray, float]:
    """One replay as the planner ran it before it batched them: its largest angle error
    [rad] at the comparison points, its final state and the largest torque commanded."""
    s = Structure.of(robot)
    breaks = interp.q.breaks
    one = flow(s, interp.tau.coeffs.shape[1] - 1, REPLAY_SAMPLES, 1, REPLAY_TOL)
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


@pytest.mark.parametrize("chunk", [replays.CHUNK, 7])
def test_batched_replays_agree_with_each_replay_interval_by_interval(unstable, chunk,
                                                                    monkeypatch):
    """Lanes with and without the feedback, from the planned and a perturbed start, with
    a torque limit the feedback reaches, in whole chunks and in ragged ones."""
    monkeypatch.setattr(replays, "CHUNK", chunk)
    scene, interp, K = unstable
    robot, breaks = scene.robot, interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    starts = np.stack([start, start + PERTURBATION, start + 50 * PERTURBATION])
    limit = np.full(len(robot.active), 0.9 * np.abs(interp.tau(breaks)).max())
    for gains in (K, None):
        done = replay(robot, interp, starts, gains, ends=True, limit=limit)
        for x0, (error, status, end, peak) in zip(starts, done, strict=True):
            worst, final, most = interval_by_interval(robot, interp, x0, gains, limit)
            assert status == "completed"
            assert error == pytest.approx(worst, rel=1e-9, abs=1e-12)
            assert np.allclose(end, final, rtol=1e-9, atol=1e-12)
            assert peak == pytest.approx(most, rel=1e-9)  # from the states, held to 1e-9


def test_the_robustness_replays_agree_with_each_model_interval_by_interval(unstable):
    scene, interp, K = unstable
    robot, breaks = scene.robot, interp.q.breaks
    start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
    goal = np.concatenate([interp.q(breaks[-1:])[0], interp.dq(breaks[-1:])[0]])
    report = robustness(robot, interp, K, UNCERTAINTY, None)
    closed = [interval_by_interval(model, interp, start, K, None)
              for _, model in models(robot, UNCERTAINTY)]
    alone = [interval_by_interval(model, interp, start, None, None)
             for _, model in models(robot, UNCERTAINTY)]
    assert report.models == len(closed) == 4
    assert report.worst_tracking_error == pytest.approx(max(c[0] for c in closed), rel=1e-9)
    assert report.worst_final_error == pytest.approx(
        max(np.abs(c[1] - goal).max() for c in closed), rel=1e-9)
    assert report.open_loop_final_error == pytest.approx(
        max(np.abs(a[1] - goal).max() for a in alone), rel=1e-9)
    assert report.largest_torque == pytest.approx(max(c[2] for c in closed), rel=1e-12)
