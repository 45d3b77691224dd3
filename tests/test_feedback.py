"""Accuracy, open-loop sensitivity and the tracking feedback of a plan, each against an
independent computation."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from planner import compiled as compiled_code
from planner.dynamics import Dynamics
from planner.examples import example
from planner.model import Structure
from planner.ocp import flow as flow_module
from planner.ocp import plan
from planner.ocp.accuracy import SAMPLES, interval_errors
from planner.ocp.feedback import PERTURBATION, REPLAY_TOL, growth_factor, linearise, replay
from planner.ocp.flow import Flow, flow, inputs
from planner.ocp.replays import Lane, reference, replays
from planner.ocp.verify import RESIM_TOL
from planner.scene import Scene
from testbed.suites.ordinary import tasks


def planned(sc: Scene):
    """The plan of a scene and the interpolant its checks ran on."""
    result = plan(sc)
    return result, result.interpolant()


@pytest.fixture(scope="module")
def unstable():
    """A suite task whose plan is strongly unstable open loop (2 links, passive elbow,
    hanging in gravity)."""
    sc = dict(tasks())["2-AP-g9.81-x01"]
    return (sc, *planned(sc))


@pytest.fixture(scope="module")
def seed_arm():
    sc = Scene.model_validate(example("seed-arm-plan").request)
    return (sc, *planned(sc))


def test_interval_errors_agree_with_an_independent_integrator(seed_arm):
    sc, result, interp = seed_arm
    errors, status = interval_errors(sc.robot, interp)
    assert status == "completed" and result.verification.local_error == errors.max()
    dyn = Dynamics(sc.robot)
    breaks = interp.q.breaks
    for k in (0, 17, len(breaks) - 2):
        a, b = breaks[k], breaks[k + 1]
        x0 = np.concatenate([interp.q([a])[0], interp.dq([a])[0]])
        n = sc.robot.n

        def rhs(t, x, n=n):
            return np.concatenate([x[n:], dyn.forward(x[:n], x[n:], interp.tau([t])[0])])

        t = a + (b - a) * np.arange(1, SAMPLES + 1) / SAMPLES
        sol = solve_ivp(rhs, (a, b), x0, method="DOP853", t_eval=t, rtol=1e-12, atol=1e-12)
        q_err = np.abs(sol.y[:n].T - interp.q(t)).max()
        dq_err = (b - a) * np.abs(sol.y[n:].T - interp.dq(t)).max()
        assert errors[k] == pytest.approx(max(q_err, dq_err), rel=1e-3, abs=1e-9)


def test_stacked_intervals_agree_with_each_interval_integrated_alone(seed_arm):
    """One CVODES run over the plan's intervals stacked into one ODE, each with its own
    constant torque offset, against each interval integrated alone: both near a reference
    at 1e-12, the stacked run at least as near as the intervals alone."""
    sc, _, interp = seed_arm
    s = Structure.of(sc.robot)
    degree = interp.tau.coeffs.shape[1] - 1
    starts, params = inputs(sc.robot, interp)
    N, na = starts.shape[1], len(s.active_idx)
    u = np.repeat(0.2 * np.sin(np.arange(N)), SAMPLES)[None, :].repeat(na, axis=0)

    def alone(tol: float) -> np.ndarray:
        one = flow(s, degree, SAMPLES, 1, tol)
        return np.hstack([one(starts[:, k:k + 1], params[:, k:k + 1],
                              u[:, k * SAMPLES:(k + 1) * SAMPLES]) for k in range(N)])

    reference = alone(1e-12)
    stacked = flow(s, degree, SAMPLES, N)(starts, params, u)
    assert stacked.shape == reference.shape == (2 * s.n, SAMPLES * N)
    assert np.abs(stacked - reference).max() <= np.abs(alone(1e-10) - reference).max() < 1e-8


def test_where_adams_fails_bdf_integrates_the_intervals(seed_arm):
    sc, _, interp = seed_arm
    s = Structure.of(sc.robot)
    degree = interp.tau.coeffs.shape[1] - 1
    starts, params = inputs(sc.robot, interp)
    N = starts.shape[1]
    zero = np.zeros((len(s.active_idx), SAMPLES * N))
    grid = list(np.arange(1, SAMPLES + 1) / SAMPLES)
    one_step = ca.integrator("stalls", "cvodes", flow_module._dae(s, degree), 0.0, grid,
                             {**flow_module.METHODS["adams"], "max_num_steps": 1})
    with pytest.raises(RuntimeError):
        one_step.map(N)(x0=starts, p=params, u=zero)
    mapped = flow(s, degree, SAMPLES, N)
    fallen_back = Flow(one_step.map(N), mapped.bdf)(starts, params, zero)
    assert np.abs(fallen_back - mapped(starts, params, zero)).max() < 1e-8


def test_the_growth_factor_agrees_with_cvodes_sensitivities(unstable):
    sc, result, interp = unstable
    s = Structure.of(sc.robot)
    degree = interp.tau.coeffs.shape[1] - 1
    one = flow(s, degree, 1, 1, 1e-10).bdf
    jac = one.factory("flow_jacobian", ["x0", "p", "u"], ["jac:xf:x0"])
    starts, params = inputs(sc.robot, interp)
    phi, worst = np.eye(2 * s.n), 1.0
    for k in range(starts.shape[1]):
        A = np.array(jac(x0=starts[:, k], p=params[:, k], u=np.zeros(len(s.active_idx)))[
            "jac_xf_x0"])
        phi = A @ phi
        worst = max(worst, np.linalg.norm(phi, 2))
    assert result.verification.growth_factor == pytest.approx(worst, rel=1e-3)
    assert growth_factor(linearise(sc.robot, interp)) == result.verification.growth_factor
    assert worst > 1e3  # strongly unstable: an initial error grows a thousandfold


def test_the_feedback_holds_a_perturbed_start_near_the_plan_where_open_loop_departs(unstable):
    sc, result, interp = unstable
    v = result.verification
    start = np.concatenate([result.q[0], result.dq[0]])
    (open_loop, status), = replay(sc.robot, interp, (start + PERTURBATION)[None, :], None)
    assert status == "completed" and open_loop > 30 * PERTURBATION
    assert v.perturbed_closed_loop_error < 3 * PERTURBATION < open_loop / 10
    assert v.closed_loop_error <= v.resimulation_error + 1e-6
    gains = np.asarray(result.feedback.gains)
    assert gains.shape == (len(result.t) - 1, len(sc.robot.active), 2 * sc.robot.n)


def test_replays_from_several_starts_agree_with_each_alone(seed_arm):
    """Lanes stacked into one ODE (at REPLAY_TOL / sqrt(3)) against each lane alone (at
    REPLAY_TOL): the same errors within five times the tolerance; the verification's
    open-loop, closed-loop and perturbed errors are the lanes of its one stacked replay
    (the torque alone, then the feedback from the start and from it perturbed, at
    RESIM_TOL)."""
    sc, result, interp = seed_arm
    K = np.asarray(result.feedback.gains)
    start = np.concatenate([result.q[0], result.dq[0]])
    starts = np.stack([start, start + PERTURBATION, start - PERTURBATION])
    together = replay(sc.robot, interp, starts, K)
    alone = [replay(sc.robot, interp, x[None, :], K)[0] for x in starts]
    assert [status for _, status in together] == ["completed"] * 3
    assert np.allclose([e for e, _ in together], [e for e, _ in alone], rtol=0.0,
                       atol=5 * REPLAY_TOL)
    v, limit = result.verification, sc.task.torque_limit
    assert limit is None  # else the closed loop's lanes saturate at it
    lanes = [Lane(start, inputs(sc.robot, interp)[1], None),
             *(Lane(x, inputs(sc.robot, interp)[1], K) for x in starts[:2])]
    alone, closed, perturbed = replays(Structure.of(sc.robot), reference(interp), lanes,
                                       RESIM_TOL, sc.solver.jit)
    assert (alone.error, closed.error, perturbed.error) == \
        (v.resimulation_error, v.closed_loop_error, v.perturbed_closed_loop_error)


def test_a_start_that_diverges_leaves_the_other_replays_whole(seed_arm):
    sc, result, interp = seed_arm
    K = np.asarray(result.feedback.gains)
    start = np.concatenate([result.q[0], result.dq[0]])
    wild = start + np.concatenate([np.zeros(sc.robot.n), np.full(sc.robot.n, 1e4)])
    (planned, status), (error, why) = replay(sc.robot, interp, np.stack([start, wild]), K)
    assert status == "completed" and planned == replay(sc.robot, interp, start[None, :], K)[0][0]
    assert planned == pytest.approx(result.verification.closed_loop_error, abs=5 * REPLAY_TOL)
    assert error is None and why.startswith(("CVODES failed between t = 0 s",
                                             "the state became non-finite between t = 0 s"))


def test_the_compiled_dynamics_give_the_same_checks(unstable, tmp_path, monkeypatch):
    """On a two-link arm, whose flow gcc builds in seconds (the seed arm's took it minutes
    at the lowest priority on a busy machine)."""
    monkeypatch.setenv("UNDERTOW_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("UNDERTOW_BUILDS", "background")
    sc, result, interp = unstable
    interpreted, _ = interval_errors(sc.robot, interp)
    interval_errors(sc.robot, interp, compiled=True)  # interpreted while gcc builds the flow
    compiled_code.wait(300)
    compiled, status = interval_errors(sc.robot, interp, compiled=True)
    assert status == "completed" and list(tmp_path.glob("flow_*.so"))
    assert np.allclose(compiled, interpreted, rtol=1e-9, atol=1e-14)
    start = np.concatenate([result.q[0], result.dq[0]])[None, :]
    assert replay(sc.robot, interp, start, None, compiled=True)[0][0] == pytest.approx(
        replay(sc.robot, interp, start, None)[0][0], rel=1e-9)
