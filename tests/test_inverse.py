"""Classical inverse dynamics: singular stops, completion with waves, the equations of
motion at every sample, and torques that reproduce the passive motion when fed forward."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import point_mass_dynamics
from pydantic import ValidationError

from planner.examples import MARGIN, example
from planner.inverse import InverseDynamicsRequest, InverseDynamicsResult, solve
from planner.model import Robot
from planner.simulate import simulate, torque_coefficients


def request(name: str, **changes) -> InverseDynamicsRequest:
    return InverseDynamicsRequest.model_validate({**example(name).request, **changes})


def feed_forward_error(req: InverseDynamicsRequest, result: InverseDynamicsResult,
                       rtol: float = 1e-10) -> tuple[float, float]:
    """Largest passive and active angle error [rad] of a forward simulation under the
    not-a-knot cubic spline through the torque samples, from the same initial state."""
    t, q, dq = np.array(result.t), np.array(result.q), np.array(result.dq)
    coeffs = torque_coefficients(t, np.array(result.tau), "cubic")
    run = simulate(req.robot, t, coeffs, np.concatenate([q[0], dq[0]]), rtol=rtol, atol=rtol)
    assert run.status == "completed"
    error = np.abs(np.array(run.q) - q)
    return error[:, req.robot.passive].max(), error[:, req.robot.active].max()


def all_finite(result: InverseDynamicsResult) -> bool:
    json.dumps(result.model_dump(), allow_nan=False)
    return True


# --------------------------------------------------------------------------- the examples


@pytest.mark.parametrize("name", ["two-link-waveless", "seed-arm-waveless"])
def test_waveless_motion_stops_at_the_singular_start(name):
    req = request(name)
    result = solve(req)
    assert result.status == "singular"
    assert result.singularity.time <= 0.05 * req.duration
    assert result.singularity.sigma_min < 1e-15
    assert result.t == [] and result.tau == []
    assert "at the start" in result.message and all_finite(result)


@pytest.mark.parametrize("name", ["two-link-waves", "seed-arm-waves"])
def test_designed_waves_complete_above_the_margin(name):
    req = request(name)
    result = solve(req)
    assert result.status == "completed" and result.singularity is None
    assert len(result.t) == req.samples and result.t[-1] == req.duration
    assert min(result.sigma_min) >= MARGIN
    assert all_finite(result)


@pytest.mark.parametrize("name", ["two-link-waves", "seed-arm-waves"])
def test_torques_fed_forward_reproduce_the_passive_motion(name):
    req = request(name)
    passive, active = feed_forward_error(req, solve(req))
    assert passive < 1e-6
    assert active < 1e-6


def test_feed_forward_error_falls_at_fourth_order_with_the_sample_spacing():
    errors = []
    for samples in (101, 201):
        req = request("two-link-waves", samples=samples, rtol=1e-12, atol=1e-12)
        errors.append(feed_forward_error(req, solve(req), rtol=1e-12)[0])
    assert errors[0] / errors[1] > 8.0  # cubic spline: 2^4 = 16 asymptotically


@pytest.mark.parametrize("name", ["two-link-waves", "seed-arm-waves"])
def test_equations_of_motion_hold_at_every_sample(name):
    """Independent M and h (d'Alembert): passive rows vanish, active rows equal tau."""
    req = request(name, samples=41)
    result = solve(req)
    for q, dq, ddq, tau in zip(result.q, result.dq, result.ddq, result.tau, strict=True):
        M, h = point_mass_dynamics(req.robot, q, dq)
        forces = M @ ddq + h
        assert np.abs(forces[req.robot.passive]).max() < 1e-10
        assert np.allclose(forces[req.robot.active], tau, rtol=0.0, atol=1e-10)


@pytest.mark.parametrize("name", ["two-link-waves", "seed-arm-waves"])
def test_passive_joints_follow_the_profile_exactly(name):
    req = request(name, samples=21)
    result = solve(req)
    qp, dqp, ddqp = req.passive_motion.evaluate(np.array(result.t), req.duration)
    P = req.robot.passive
    assert np.array_equal(np.array(result.q)[:, P], qp)
    assert np.array_equal(np.array(result.dq)[:, P], dqp)
    assert np.array_equal(np.array(result.ddq)[:, P], ddqp)


# --------------------------------------------------------------------------- singular stop


def test_a_stop_during_the_motion_ends_at_the_threshold():
    """Starting 0.1 rad away from the singular angle, the waveless seed arm runs into it."""
    base = example("seed-arm-waveless").request
    q = list(base["active_initial"]["q"])
    q[1] -= 0.1
    req = request("seed-arm-waveless", active_initial={"q": q, "dq": [0.0, 0.0]})
    result = solve(req)
    stop = result.singularity
    assert result.status == "singular"
    assert 0.0 < stop.time < req.duration
    assert stop.sigma_min == pytest.approx(req.sigma_threshold, rel=1e-6)
    assert result.t[-1] == stop.time and result.q[-1] == stop.q
    assert min(result.sigma_min) == pytest.approx(req.sigma_threshold, rel=1e-6)
    grid = np.linspace(0.0, req.duration, req.samples)
    assert np.array_equal(result.t[:-1], grid[grid < stop.time])
    assert f"t = {stop.time:.6g} s" in result.message and all_finite(result)


# --------------------------------------------------------------------------- more active


def test_more_active_joints_take_the_minimum_norm_accelerations():
    robot = Robot.model_validate({"links": [
        {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": 0.4, "mass": 0.6, "inertia": 0.005, "joint": "active"},
        {"length": 0.3, "mass": 0.4, "inertia": 0.003, "joint": "active"}]})
    req = InverseDynamicsRequest(
        robot=robot, passive_motion={"profile": "beta", "start": [0.0], "end": [0.4]},
        duration=1.5, active_initial={"q": [0.5, 1.0], "dq": [0.0, 0.0]}, samples=31)
    result = solve(req)
    assert result.status == "completed"
    for q, dq, ddq in zip(result.q, result.dq, result.ddq, strict=True):
        M, h = point_mass_dynamics(robot, q, dq)
        mpa = M[0, 1:]
        assert abs(M[0] @ ddq + h[0]) < 1e-10
        null = np.array([-mpa[1], mpa[0]])  # M_pa null
        assert abs(null @ ddq[1:]) < 1e-10 * np.linalg.norm(ddq[1:]) + 1e-12
    passive, _ = feed_forward_error(req, solve(req.model_copy(update={"samples": 301})))
    assert passive < 1e-6


# --------------------------------------------------------------------------- bad requests


def message(doc: dict) -> str:
    with pytest.raises(ValidationError) as exc:
        InverseDynamicsRequest.model_validate(doc)
    (error,) = exc.value.errors()
    return error["msg"]


def edited(**changes) -> dict:
    return {**example("two-link-waves").request, **changes}


def test_messages_of_bad_requests():
    assert message(edited(duration=0.0)) == "Input should be greater than or equal to 0.01"
    assert message(edited(active_initial={"q": [0.0, 1.0], "dq": [0.0]})) == (
        "Value error, active_initial: q and dq need 1 entry each, one per active joint")
    assert message(edited(passive_motion={"profile": "beta", "start": [0, 0],
                                          "end": [1, 1]})) == (
        "Value error, passive_motion: needs 1 angle per time, one per passive joint")
    assert message(edited(passive_motion={"profile": "samples", "t": [0.0, 1.0],
                                          "q": [[0.0], [0.5]]})) == (
        "Value error, passive_motion.t: must end at duration (2 s)")
    assert message(edited(samples=1)) == "Input should be greater than or equal to 2"


def test_fewer_active_than_passive_joints_is_rejected():
    robot = {"links": [{"length": 0.5, "mass": 1.0, "joint": "passive"},
                       {"length": 0.5, "mass": 1.0, "joint": "passive"},
                       {"length": 0.5, "mass": 1.0, "joint": "active"}]}
    assert message(edited(robot=robot)) == (
        "Value error, robot: fewer active joints (1) than passive joints (2): M_pa never "
        "has full row rank, so the passive motion cannot be prescribed")
