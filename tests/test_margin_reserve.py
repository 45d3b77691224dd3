"""The reserve above the coupling margin (planner.ocp.margin_reserve): how large it is, what
caps it, that a plan whose margin dips between its knots is solved again with it and
verified against the task's own margin, and that the plan reported is an accurate one."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from planner.certify.boxes import Bound
from planner.coupling_block import along
from planner.examples import example
from planner.ocp.infeasibility import reported
from planner.ocp.margin_proof import MARGIN_RTOL, MarginProof
from planner.ocp.margin_reserve import (
    MAX_RESERVE,
    RESERVE,
    next_reserve,
    reserved_margin,
    with_margin,
)
from planner.ocp.planner import plan
from planner.ocp.report import best_of
from planner.scene import Scene
from testbed.suites.hard import hard_tasks


def _proof(margin: float, sampled: list[float]) -> MarginProof:
    """A proof whose intervals sampled these minima, refuted where below the target."""
    target = margin * (1 - MARGIN_RTOL)
    bounds = [Bound(min(s, target), s, np.array([0.5]),
                    "certified" if s >= margin else "refuted", 1, 0.0) for s in sampled]
    return MarginProof(margin, bounds, 0.0)


def test_the_reserve_is_twice_the_deepest_dip_at_least_the_least_and_grows():
    assert next_reserve(_proof(0.01, [0.02, 0.00999, 0.03]), 0.0) == RESERVE
    assert next_reserve(_proof(0.01, [0.02, 0.009, 0.0095]), 0.0) == pytest.approx(0.2)
    assert next_reserve(_proof(0.01, [0.02, 0.00999]), 0.04) == pytest.approx(0.08)
    assert next_reserve(_proof(0.01, [0.02, 0.007]), 0.0) is None  # 0.6 > MAX_RESERVE
    assert next_reserve(_proof(0.01, [0.02, 0.00999]), MAX_RESERVE) is None


@pytest.fixture(scope="module")
def seed_scene() -> Scene:
    return Scene.model_validate(example("seed-arm-plan").request)


def _ends_sigma(scene: Scene) -> float:
    task = scene.task
    return float(along(scene.robot, np.array([task.initial.q, task.final.q])).least.min())


def test_the_held_margin_is_capped_by_the_fixed_ends(seed_scene):
    ends = _ends_sigma(seed_scene)
    margin = seed_scene.task.coupling_margin
    assert reserved_margin(seed_scene.task, seed_scene.robot, 0.01) == pytest.approx(
        min(1.01 * margin, ends))
    near = with_margin(seed_scene, ends * 0.999).task
    held = reserved_margin(near, seed_scene.robot, 0.01)
    assert held is not None and ends * 0.999 < held < ends
    assert reserved_margin(with_margin(seed_scene, ends).task, seed_scene.robot, 0.01) is None
    unmargined = seed_scene.task.model_copy(update={"coupling_margin": None})
    assert reserved_margin(unmargined, seed_scene.robot, 0.01) is None


def test_co_design_holds_the_reserve_whatever_its_starting_ends():
    """Its waves move the ends' sigma_least, so they do not cap the margin held."""
    scene = dict(hard_tasks())["co-design-20"]
    ends = _ends_sigma(scene)
    at_ends = with_margin(scene, ends).task
    assert reserved_margin(at_ends, scene.robot, 0.01) == pytest.approx(1.01 * ends)


def test_a_plan_whose_margin_dips_between_knots_is_held_with_a_reserve_and_verified():
    """co-design-44 of the hard suite from its direct start: its first accurate plan (60
    intervals) rides the margin and dips below it between knots; solved again on that mesh
    with a reserve, its plan keeps the task's own margin on every interval."""
    scene = dict(hard_tasks())["co-design-44"]
    scene = scene.model_copy(update={"solver": scene.solver.model_copy(
        update={"max_wall_time": 600.0})})
    result = plan(scene, starts=["direct"])
    held = [p for p in result.mesh_passes if p.margin_reserve is not None]
    assert held and all(p.margin_reserve >= RESERVE for p in held)
    assert result.status == "verified"
    cert = result.verification.margin_certificate
    assert cert.status == "certified" and cert.target == pytest.approx(
        scene.task.coupling_margin * (1 - MARGIN_RTOL))
    robot = result.robot_of(scene.robot)
    t = np.linspace(0.0, result.duration, 20_001)
    assert along(robot, result.interpolant().q(t)).least.min() >= cert.target


def _outcome(success: bool, accurate: bool, error: float) -> SimpleNamespace:
    return SimpleNamespace(solution=SimpleNamespace(success=success, status="Solve_Succeeded"),
                           finite=True, accurate=lambda tolerance: accurate,
                           worst_error=lambda: error)


def test_the_plan_reported_is_an_accurate_one_before_a_smaller_error():
    """A pass whose margin is not proven may have the smaller interval error; the plan is
    the accurate pass's."""
    dipping, kept = _outcome(True, False, 1e-6), _outcome(True, True, 2e-6)
    attempt = SimpleNamespace(outcomes=[dipping, kept], start=SimpleNamespace(continues=False))
    assert best_of([attempt], 1e-3)[0] is kept
    failed = _outcome(False, True, 1e-9)
    attempt = SimpleNamespace(outcomes=[failed, dipping], start=SimpleNamespace(continues=False))
    assert best_of([attempt], 1e-3)[0] is dipping


def test_a_solve_that_held_a_reserve_is_no_witness_of_infeasibility():
    def solve(reserve: float | None) -> SimpleNamespace:
        return SimpleNamespace(finite=True,
                               solution=SimpleNamespace(status="Infeasible_Problem_Detected"),
                               record=SimpleNamespace(margin_reserve=reserve))

    assert reported(solve(None))
    assert not reported(solve(0.01))


def test_a_held_margin_the_task_leaves_no_more_room_for_is_not_solved_again(monkeypatch):
    """Where the ends cap the reserve at what a pass already held, the next pass cuts the
    mesh instead of solving the same NLP again."""
    from planner.ocp import attempt as attempt_module
    from planner.ocp.mesh import Mesh

    scene = Scene.model_validate(example("seed-arm-plan").request)
    mesh = Mesh.uniform(10)
    proof = _proof(0.005, [0.006] * 9 + [0.00499])

    def dipping() -> SimpleNamespace:
        return SimpleNamespace(
            solution=SimpleNamespace(success=True, objective=1.0), accurate=lambda tol: False,
            errors=np.full(10, 1e-6), margin=proof, robot=scene.robot, T=1.6,
            inst=SimpleNamespace(mesh=mesh,
                                 problem=SimpleNamespace(transcription=SimpleNamespace(order=4))),
            record=SimpleNamespace(strategy="direct"))

    solved: list[tuple[int, float | None]] = []

    def solve(scene, last, mesh, held, budget, progress, mesh_pass):
        solved.append((mesh.intervals, held))
        return [dipping()]

    monkeypatch.setattr(attempt_module, "reserved_margin", lambda task, robot, r: 0.00502)
    monkeypatch.setattr(attempt_module, "_refined_solve", solve)
    made = SimpleNamespace(start=SimpleNamespace(max_refinements=2), outcomes=[dipping()])
    made.add = made.outcomes.append
    made.passes = made.outcomes
    attempt_module.refine(scene, made, SimpleNamespace(spent=False), None, 0)
    assert solved[0] == (10, 0.00502)  # held on its own mesh
    assert solved[1][0] > 10 and solved[1][1] == 0.00502  # then cut, still held
