"""The coupling margin on whole intervals (planner.ocp.margin_proof): proven between the
samples in ball arithmetic, a plan whose margin fails between its samples is not verified,
and the mesh refinement cuts the intervals the proof does not cover."""

from __future__ import annotations

import time

import numpy as np
import pytest

from planner.coupling_block import along as sampled
from planner.examples import example
from planner.ocp import margin_proof
from planner.ocp.margin_proof import MARGIN_RTOL, prove
from planner.ocp.mesh import Mesh
from planner.ocp.planner import plan
from planner.ocp.refine import refined
from planner.ocp.task_checks import requirements
from planner.scene import Scene


@pytest.fixture(scope="module")
def done():
    """The seed arm's built-in plan (margin 0.005 kg m^2), verified."""
    scene = Scene.model_validate(example("seed-arm-plan").request)
    result = plan(scene)
    assert result.status == "verified"
    return scene, result


def _with_margin(scene: Scene, margin: float) -> Scene:
    data = scene.model_dump(exclude_unset=True)
    data["task"]["coupling_margin"] = margin
    return Scene.model_validate(data)


def test_a_verified_plan_has_its_margin_certified_on_every_interval(done):
    scene, result = done
    cert = result.verification.margin_certificate
    assert cert.status == "certified" and cert.unproven_intervals == []
    assert cert.target == pytest.approx(scene.task.coupling_margin * (1 - MARGIN_RTOL))
    t = np.linspace(0.0, result.duration, 20_001)
    least = sampled(result.robot_of(scene.robot), result.interpolant().q(t)).least.min()
    assert cert.target <= cert.bound <= least


def test_a_margin_that_fails_between_the_samples_is_not_verified(done):
    """Samples at the breakpoints only: sigma_min there keeps a margin that the motion
    between them breaks; the samples' check passes it, the proof refutes it."""
    scene, result = done
    robot, interp = result.robot_of(scene.robot), result.interpolant()
    breaks = interp.q.breaks
    at_breaks = sampled(robot, interp.q(breaks)).least
    between = sampled(robot, interp.q(np.linspace(0.0, breaks[-1], 20_001))).least
    assert between.min() < at_breaks.min() * (1 - 2 * MARGIN_RTOL)
    task = _with_margin(scene, float(at_breaks.min())).task
    proof = prove(robot, interp, task.coupling_margin)
    found = requirements(robot, interp, breaks, task, at_breaks, proof, 1e-3)
    assert found.margin_shortfall == 0.0
    assert found.margin_certificate.status == "refuted"
    assert found.margin_certificate.unproven_intervals
    assert len(found.violations) == 1
    assert found.violations[0].startswith("sigma_min(M_pa) falls to ")
    assert "between the plan's samples, below the task's coupling margin" in found.violations[0]


def test_an_undecided_interval_is_said_and_not_verified(done, monkeypatch):
    scene, result = done
    robot, interp = result.robot_of(scene.robot), result.interpolant()
    least = sampled(robot, interp.q(np.linspace(0.0, result.duration, 20_001))).least.min()
    monkeypatch.setattr(margin_proof, "BOXES", 1)
    proof = prove(robot, interp, least * (1 - 2 * MARGIN_RTOL))
    cert = proof.certificate()
    assert cert.status == "undecided" and cert.unproven_intervals
    assert proof.violation(interp.q.breaks).startswith(
        f"the coupling margin of {least * (1 - 2 * MARGIN_RTOL):g} is not proven on ")


def test_no_margin_or_no_passive_joint_needs_no_proof(done):
    scene, result = done
    assert prove(result.robot_of(scene.robot), result.interpolant(), None) is None


def test_the_refinement_halves_the_intervals_without_the_proof():
    mesh = Mesh.uniform(10)
    errors = np.full(10, 1e-6)
    assert refined(mesh, errors, 4, 1e-3, 200) is None
    cut = np.zeros(10, bool)
    cut[[2, 7]] = True
    finer = refined(mesh, errors, 4, 1e-3, 200, cut)
    assert finer is not None and finer.intervals >= 12
    widths = np.diff(finer.breaks)
    assert widths.min() <= 0.025 + 1e-12  # cut into 4


def test_a_proof_past_its_deadline_is_undecided_and_finite(done):
    scene, result = done
    proof = prove(result.robot_of(scene.robot), result.interpolant(),
                  scene.task.coupling_margin, deadline=time.perf_counter() - 1.0)
    cert = proof.certificate()
    assert cert.status == "undecided" and cert.boxes == 0 and cert.sampled_min is None
    assert "Infinity" not in cert.model_dump_json() and "NaN" not in cert.model_dump_json()
