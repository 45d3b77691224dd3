"""A diverging re-integration raises without writing CasADi's dump of its inputs, and a
plan whose verification overflows is reported, not raised."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.model import Robot, Structure, parameters
from planner.ocp import plan
from planner.ocp.flow import flow
from planner.scene import Scene

ROBOT = Robot.model_validate({"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active"}], "gravity": 9.81})


def inputs(batch: int, rate: float, torque: float) -> tuple[np.ndarray, ...]:
    """Starts, parameters (a constant torque over intervals of 1 s, no saturation) and zero
    offsets."""
    s = Structure.of(ROBOT)
    x0 = np.tile(np.array([[0.0], [0.5], [rate], [rate]]), (1, batch))
    p = np.vstack([np.repeat(parameters(ROBOT, s)[:, None], batch, 1),
                   np.full((1, batch), torque), np.ones((1, batch)),
                   np.full((1, batch), np.inf)])
    return x0, p, np.zeros((1, 4 * batch))


@pytest.mark.parametrize("batch", [1, 3])
def test_a_diverging_flow_raises_without_printing_its_inputs(capfd, batch):
    f = flow(Structure.of(ROBOT), 0, 4, batch)
    with pytest.raises(RuntimeError) as failed:
        f(*inputs(batch, 1e150, 1e200))
    out, err = capfd.readouterr()
    assert (out, err) == ("", "")
    if batch == 1:
        return  # the integrator itself prints nothing; the stacked flow prints its inputs
    # kept with the exception (Adams' failure is the context of BDF's), not shown
    chain = [failed.value, failed.value.__context__]
    assert any("Input 0 (x0)" in note for exc in chain if exc is not None
               for note in getattr(exc, "__notes__", []))


def test_a_flow_that_succeeds_still_answers_and_prints_nothing(capfd):
    f = flow(Structure.of(ROBOT), 0, 4, 2)
    xf = f(*inputs(2, 0.1, 0.2))
    assert xf.shape == (4, 8) and np.all(np.isfinite(xf))
    assert capfd.readouterr() == ("", "")


def test_a_plan_far_too_fast_for_its_duration_is_reported_not_raised():
    """The fastest start a scene may ask (1e6 rad/s): the linearisation's transition
    matrices overflow across the intervals. The plan comes back failed and unverified,
    without feedback or growth factor, instead of plan() raising (the SVD of an infinite
    matrix does not converge)."""
    sc = Scene.model_validate({
        "robot": {"links": [
            {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
            {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
             "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 0.0},
        "task": {"duration": 2.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 1e6]},
                 "final": {"q": [0.3, 1.0], "dq": [0.0, 0.0]}},
        "transcription": {"method": "legendre", "intervals": 20},
        "solver": {"max_iter": 3, "retries": 0}})
    result = plan(sc)
    assert not result.solver.success and result.verification.verified is False
    assert result.feedback is None and result.verification.growth_factor is None
    json.dumps(result.model_dump(mode="json"), allow_nan=False)
