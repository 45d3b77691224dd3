"""The NLP solvers a scene can name: Ipopt and fatrop reach the same optimum."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from planner.ocp import plan
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
