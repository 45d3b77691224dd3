"""Meshes and their refinement: non-uniform meshes for every transcription, where the
refinement cuts, and that a refined plan is accurate and stays at its optimum."""

from __future__ import annotations

import numpy as np
import pytest
from test_ocp import scene

from planner.examples import example
from planner.ocp import plan
from planner.ocp.mesh import Mesh
from planner.ocp.refine import INTERVAL_STEPS, MAX_SPLIT, SAFETY, refined
from planner.scene import Scene
from testbed.suites.ordinary import tasks


def non_uniform(N: int) -> list[float]:
    """Breakpoints of N intervals whose widths vary smoothly by a factor of 9."""
    widths = 1 + 0.8 * np.sin(np.linspace(0.0, 3.0, N))
    b = np.concatenate([[0.0], np.cumsum(widths)])
    return (b / b[-1]).tolist()


@pytest.mark.parametrize("method, grids, order", [
    ("trapezoidal", (64, 128), 3.0),
    ("hermite-simpson", (16, 32), 4.0),
    ("legendre", (16, 32), 4.0),
    ("radau", (16, 32), 4.0),
    ("multiple-shooting", (16, 32), 4.0),
])
def test_every_method_converges_at_its_order_on_a_non_uniform_mesh(method, grids, order):
    # The local error of an interval of width h falls as h^order (the refinement's model).
    errors, objectives = [], []
    for N in grids:
        result = plan(scene(method=method, N=N, refine=False,
                            transcription={"breaks": non_uniform(N)}))
        assert result.solver.success and np.isclose(result.t[1] / result.duration,
                                                    non_uniform(N)[1])
        errors.append(result.verification.local_error)
        objectives.append(result.objective)
    assert np.log2(errors[0] / errors[1]) == pytest.approx(order, abs=0.7)
    reference = plan(scene(N=80, refine=False)).objective
    assert objectives[1] == pytest.approx(reference, rel=0.02)


def test_refinement_cuts_the_intervals_above_the_tolerance_by_its_error_model():
    mesh = Mesh(np.array(non_uniform(10)))
    errors = np.full(10, 1e-4)
    errors[[2, 7]] = [3e-3, 2e-2]  # (e / (SAFETY tol))^(1/4): 1.57 -> 2, 2.5 -> 3 parts
    new = refined(mesh, errors, 4, 1e-3, 100)
    # 8 + 2 + 3 = 13 intervals, rounded up to 15: the two more cuts go where the predicted
    # error e / parts^4 is largest, interval 7 (2.5e-4) then interval 2 (1.9e-4)
    assert SAFETY == 0.5 and 15 in INTERVAL_STEPS and 13 not in INTERVAL_STEPS
    parts = [int(np.sum((new.breaks >= a - 1e-15) & (new.breaks < b - 1e-15)))
             for a, b in zip(mesh.breaks[:-1], mesh.breaks[1:], strict=True)]
    assert parts == [1, 1, 3, 1, 1, 1, 1, 4, 1, 1]
    inside = new.breaks[(new.breaks > mesh.breaks[7]) & (new.breaks < mesh.breaks[8])]
    assert np.allclose(np.diff(np.concatenate([[mesh.breaks[7]], inside, [mesh.breaks[8]]])),
                       mesh.widths[7] / 4)  # equal parts
    assert refined(mesh, np.full(10, 1e-4), 4, 1e-3, 100) is None  # accurate: no cut
    assert refined(mesh, errors, 4, 1e-3, 12) is None  # 13 intervals exceed the budget
    assert refined(mesh, errors, 4, 1e-3, 14).intervals == 14  # rounded up to the budget
    assert MAX_SPLIT == 4
    assert refined(mesh, np.where(errors > 1e-3, np.inf, errors), 4, 1e-3, 18).intervals == 18


def test_refinement_turns_the_unverified_two_link_plan_at_30_intervals_into_a_verified_one():
    # On 30 equal intervals Ipopt converges to an optimum of the NLP that is an artefact of
    # the grid (its torque departs from it by 3e-2 rad within an interval); the refinement
    # cuts where the error is until the plan is a motion of the robot, at the example's
    # own optimum (found directly on its 40 intervals): the refinement of the scene's own
    # start, or of the continuation where that one's refinement follows artefacts.
    request = example("two-link-plan").request
    reference = plan(Scene.model_validate(request))
    at_30 = {**request, "transcription": {**request["transcription"], "intervals": 30}}
    coarse = plan(Scene.model_validate({**at_30, "transcription": {
        **at_30["transcription"], "refinement": {"enabled": False}}, "solver": {
        **at_30["solver"], "retries": 0}}))
    assert coarse.solver.success and coarse.verification.verified is False
    assert coarse.verification.local_error > 10 * coarse.verification.tolerance
    refined_plan = plan(Scene.model_validate(at_30))
    start = refined_plan.solver.strategy.removesuffix(" + mesh refinement")
    passes = [p for p in refined_plan.mesh_passes if p.strategy == start]
    assert refined_plan.solver.success and refined_plan.verification.verified
    assert refined_plan.solver.strategy.endswith(" + mesh refinement")
    assert passes[0].intervals == 30 and passes[-1].intervals == len(refined_plan.t) - 1 > 30
    assert [p.intervals for p in passes] == sorted(p.intervals for p in passes)
    assert passes[-1].max_local_error == refined_plan.verification.local_error
    # only the reported pass is replayed open loop, and it carries the plan's replay error
    assert passes[-1].resimulation_error == refined_plan.verification.resimulation_error
    assert all(p.resimulation_error is None for p in refined_plan.mesh_passes[:-1])
    assert refined_plan.objective == pytest.approx(reference.objective, rel=0.01)


def test_a_refined_solve_starts_at_the_plan_before_and_stays_at_its_optimum():
    name, sc = next((n, s) for n, s in tasks() if n == "2-AP-g9.81-x31")
    result = plan(sc)
    # the task has a torque limit: its first pass solves it without (attempt.unlimited_solve)
    passes = [p for p in result.mesh_passes if not p.strategy.endswith("without its limits")]
    first, last = passes[0], passes[-1]
    assert first.max_local_error > 1e-3 >= result.verification.local_error
    assert len(passes) == 2 and last.iterations <= 10
    assert last.objective == pytest.approx(first.objective, rel=0.01)


def test_a_fine_mesh_is_solved_coarse_to_fine_and_lands_on_the_examples_optimum():
    # Solved from scratch on 80 equal intervals, Ipopt converges to an artefact of that
    # grid (objective about 1.3e3, interval errors of 3e-2 rad): a finer grid has more
    # such optima. Solved first on 50 intervals, the plan carried onto 80 stays at the
    # example's own optimum and needs a few iterations there.
    request = example("two-link-plan").request
    reference = plan(Scene.model_validate(request))
    fine = {**request, "transcription": {**request["transcription"], "intervals": 80}}
    result = plan(Scene.model_validate(fine))
    assert result.solver.success and result.verification.verified
    assert result.solver.strategy == "coarse to fine"
    assert [(p.intervals, p.strategy) for p in result.mesh_passes] == [
        (50, "coarse to fine"), (80, "coarse to fine")]
    assert result.mesh_passes[1].iterations <= 10 and len(result.t) == 81
    assert result.objective == pytest.approx(reference.objective, rel=0.01)
