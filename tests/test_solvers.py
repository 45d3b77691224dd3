"""The NLP solvers a scene can name: Ipopt and fatrop reach the same optimum."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from planner.ocp import plan
from planner.ocp.problem import ProblemKey, problem
from planner.ocp.shortest import time_optimal
from planner.scene import Scene
from testbed.suites.ordinary import tasks


def test_fatrop_and_ipopt_reach_the_same_verified_optimum():
    # a task with one optimum near the guess (on 2-PA-g0-x00 Ipopt finds one of effort 1.76
    # where fatrop ends in one of 10.3, both verified)
    sc = dict(tasks())["2-PA-g9.81-x15"]
    results = {}
    for name in ("ipopt", "fatrop"):
        scene = sc.model_copy(update={"solver": sc.solver.model_copy(
            update={"name": name, "retries": 0})})
        results[name] = plan(scene)
    ipopt, fatrop = results["ipopt"], results["fatrop"]
    assert fatrop.solver.status == "Solve_Succeeded" and fatrop.verification.verified
    assert fatrop.solver.iterations > 0
    assert fatrop.objective == pytest.approx(ipopt.objective, rel=1e-6)


def test_fatrop_needs_stages_that_close_their_gaps():
    sc = dict(tasks())["2-PA-g0-x00"].model_dump(mode="json")
    sc["solver"]["name"] = "fatrop"
    sc["transcription"]["method"] = "trapezoidal"
    with pytest.raises(ValidationError, match="solver.name: 'fatrop' needs a transcription "
                                              "whose stages close their gaps explicitly"):
        Scene.model_validate(sc)


def test_fatrop_factors_the_stage_structure_with_the_assembled_derivatives():
    """fatrop's own statistics report the stages the layout declares (N stages of the node
    state and the other stage variables), and its Hessian is the per-stage kernels'
    (`nlp_hess_l_stages`), not CasADi's derivative of the expanded NLP."""
    sc = dict(tasks())["2-PA-g9.81-x15"]
    scene = sc.model_copy(update={"solver": sc.solver.model_copy(
        update={"name": "fatrop", "retries": 0})})
    prob = problem(ProblemKey.of(scene))
    called = {f.name() for f in prob.solver.get_function("nlp_hess_l").find_functions()}
    assert "nlp_hess_l_stages" in called
    assert plan(scene).solver.status == "Solve_Succeeded"
    stats, layout, N = prob.solver.stats(), prob.layout, prob.layout.intervals
    link = layout.stage_size - stats["nu"][0]
    assert stats["N"] == N and stats["nx"] == [link] * (N + 1) and link == 2 * 2
    assert stats["nu"] == [layout.stage_size - link] * N + [0]
    assert sum(stats["nx"]) + sum(stats["nu"]) == layout.size
    assert stats["n_call_nlp_hess_l"] >= stats["iter_count"] > 0


def test_a_fatrop_scene_probes_its_shortest_duration_with_ipopt():
    """The duration probe frees the duration, which fatrop cannot state: the probe's scene
    is one the schema accepts, solved by Ipopt, and otherwise the scene's own settings."""
    sc = dict(tasks())["4-APPA-g9.81-x39"]
    scene = sc.model_copy(update={"solver": sc.solver.model_copy(update={"name": "fatrop"})})
    probe = time_optimal(scene, 0.5, 3.0, 0.1)
    assert Scene.model_validate(probe.model_dump()) == probe
    assert probe.solver == scene.solver.model_copy(update={"name": "ipopt"})
