"""A solve's multipliers carried to a refinement of its mesh (`planner.ocp.carried`),
against the multipliers of the refined NLP's own optimum."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from planner.ocp import attempt as attempt_module
from planner.ocp import plan
from planner.ocp.carried import Point, carried
from planner.ocp.guess import hermite_guess, interpolant_guess
from planner.ocp.instance import Instance, initial_point, instance
from planner.ocp.mesh import Mesh
from planner.ocp.outcome import outcome_of
from planner.ocp.row_kinds import row_kinds
from planner.ocp.solve import Budget, Solution, solve
from planner.scene import Scene
from testbed.suites.ordinary import tasks

TWO: dict = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 9.81}
T = 1.5  # [s]
PIECES = [1, 1, 1, 2, 2, 2, 2, 1, 1, 3, 1, 1]
"""How the refinement cuts each of the 12 coarse intervals: some in two, one in three."""


def _scene(method: str) -> Scene:
    return Scene.model_validate({
        "robot": TWO, "solver": {"jit": False},
        "transcription": {"method": method, "intervals": len(PIECES)},
        "task": {"initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                 "final": {"q": [0.6, -0.4], "dq": [0.0, 0.0]},
                 "duration": T, "torque_limit": 30.0}})


def _solved(inst: Instance, x0: np.ndarray) -> Solution:
    solution = solve(inst, x0, Budget.of(3000, 60.0), None, 0)
    assert solution.success
    return solution


@pytest.mark.parametrize("method", ["legendre", "radau"])
def test_carried_multipliers_approach_the_refined_optimum_s(method):
    # Scaled by the fine interval's share of the coarse one, a stage's dynamics rows'
    # multipliers land within 15 % of the refined optimum's, copied unscaled they miss by
    # more than twice as much; the continuity rows' (the costate at a stage's end) are
    # interpolated over time.
    scene = _scene(method)
    coarse = instance(scene, scene.robot, Mesh.uniform(len(PIECES)), T)
    solution = _solved(coarse, initial_point(coarse, hermite_guess(scene, scene.robot, T),
                                             T, scene.robot))
    interp = outcome_of(scene, coarse, scene.robot, T, solution, "coarse", 0.0).interp
    fine = instance(scene, scene.robot, coarse.mesh.split(np.array(PIECES)), T)
    x0 = initial_point(fine, interpolant_guess(interp, T), T, scene.robot)
    point = carried(coarse, solution, fine, x0)
    optimum = _solved(fine, x0)
    kinds, per_stage = row_kinds(fine.problem)

    def error(lam: np.ndarray, kind: str) -> float:
        rows = kinds == kind
        return float(np.linalg.norm(lam[rows] - optimum.lam_g[rows])
                     / np.linalg.norm(optimum.lam_g[rows]))
    assert point is not None and np.array_equal(point.x, x0)
    assert point.lam_g.shape == optimum.lam_g.shape
    assert point.lam_x.shape == optimum.lam_x.shape
    assert error(point.lam_g, "dynamics") < 0.15
    within = np.searchsorted(coarse.mesh.breaks, fine.mesh.breaks[1:] - 1e-12) - 1
    ratio = np.repeat(fine.mesh.widths / coarse.mesh.widths[within], per_stage)
    unscaled = point.lam_g.copy()
    unscaled[:ratio.size] /= ratio  # the coarse multipliers copied as they were
    assert error(unscaled, "dynamics") > 2 * error(point.lam_g, "dynamics")
    assert error(point.lam_g, "continuity") < 0.3
    assert np.linalg.norm(point.lam_x - optimum.lam_x) \
        < 0.15 * np.linalg.norm(optimum.lam_x)


def test_the_same_mesh_carries_the_multipliers_unchanged_and_another_carries_none():
    scene = _scene("legendre")
    coarse = instance(scene, scene.robot, Mesh.uniform(len(PIECES)), T)
    solution = _solved(coarse, initial_point(coarse, hermite_guess(scene, scene.robot, T),
                                             T, scene.robot))
    again = instance(scene, scene.robot, Mesh(coarse.mesh.breaks.copy()), T)
    point = carried(coarse, solution, again, solution.x)
    assert point is not None
    assert np.allclose(point.lam_g, solution.lam_g, rtol=1e-14, atol=0)
    assert np.allclose(point.lam_x, solution.lam_x, rtol=1e-14, atol=0)
    other = instance(scene, scene.robot, Mesh.uniform(len(PIECES) + 1), T)  # not a refinement
    assert carried(coarse, solution, other, np.zeros(other.lbx.size)) is None


def test_a_refined_solve_whose_carried_start_fails_is_solved_again_cold(monkeypatch):
    # The suite's task 2-PA-g0-x30 is refined from 50 to 60 intervals from a plan within
    # CARRY_WITHIN times the tolerance: from its multipliers. Were that solve to fail, the
    # same refined NLP is solved again from the interpolated plan alone; both solves are
    # among the plan's passes, the failed one first, and the plan is the cold solve's.
    real = attempt_module.solve_on
    starts: list[str] = []

    def failing(*args, **kwargs):
        outcome = real(*args, **kwargs)
        point = args[9] if len(args) > 9 else kwargs.get("point")
        starts.append(type(point).__name__)
        if not isinstance(point, Point):
            return outcome
        failed = replace(outcome.solution, success=False, status="Maximum_Iterations_Exceeded")
        record = outcome.record.model_copy(update={"status": failed.status})
        return replace(outcome, solution=failed, record=record)
    monkeypatch.setattr(attempt_module, "solve_on", failing)
    scene = dict(tasks())["2-PA-g0-x30"]
    result = plan(scene)
    statuses = [(p.intervals, p.status) for p in result.mesh_passes]
    assert "Point" in starts
    assert (60, "Maximum_Iterations_Exceeded") in statuses
    failed = statuses.index((60, "Maximum_Iterations_Exceeded"))
    assert statuses[failed + 1] == (60, "Solve_Succeeded")
    assert result.solver.success and result.verification.verified
    assert len(result.t) == 61


def test_the_globals_copies_end_equal_and_their_rows_multipliers_are_carried():
    # A free duration (weighted in the objective, so that its optimum lies inside its
    # bounds): every stage holds a copy of T, kept equal by copy rows ("continuity"). At
    # the optimum the copies agree, and the copy rows' multipliers (the sensitivity of
    # the cost to T accumulated up to each node) carried to the refined mesh land within
    # 5 % of its optimum's.
    data = _scene("legendre").model_dump(mode="json")
    data["task"].update(torque_limit=None, duration={"min": 0.8, "max": 3.0},
                        objective={"effort": 1.0, "time": 10.0, "smoothness": 0.0})
    scene = Scene.model_validate(data)
    coarse = instance(scene, scene.robot, Mesh.uniform(len(PIECES)), T)
    solution = _solved(coarse, initial_point(coarse, hermite_guess(scene, scene.robot, T),
                                             T, scene.robot))
    copies = coarse.problem.layout.view(solution.x, "T")
    assert copies.shape == (1, len(PIECES) + 1)
    assert np.ptp(copies) < 1e-9 and 0.8 < copies[0, 0] < 3.0
    kinds, _ = row_kinds(coarse.problem)
    assert list(kinds[-len(PIECES):]) == ["continuity"] * len(PIECES)
    interp = outcome_of(scene, coarse, scene.robot, T, solution, "coarse", 0.0).interp
    fine = instance(scene, scene.robot, coarse.mesh.split(np.array(PIECES)), T)
    x0 = initial_point(fine, interpolant_guess(interp, T), T, scene.robot)
    point = carried(coarse, solution, fine, x0)
    optimum = _solved(fine, x0)
    rows = slice(optimum.lam_g.size - fine.mesh.intervals, None)
    assert point is not None and point.lam_g.shape == optimum.lam_g.shape
    assert np.linalg.norm(point.lam_g[rows] - optimum.lam_g[rows]) \
        < 0.05 * np.linalg.norm(optimum.lam_g[rows])
