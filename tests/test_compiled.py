"""solver.jit: the first plans of a structure run interpreted while its kernels are compiled
in the background; later plans run compiled and agree with the interpreted ones."""

from __future__ import annotations

import numpy as np
import pytest

from planner import compiled
from planner.ocp import plan
from planner.scene import Scene

TWO_LINK = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.02, "joint": "passive"},
                      {"length": 0.4, "mass": 0.7, "inertia": 0.01, "joint": "active"}],
            "gravity": 9.81}


def _scene(goal: float) -> Scene:
    return Scene.model_validate({
        "robot": TWO_LINK,
        "task": {"duration": 1.2, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                 "final": {"q": [goal, 0.4], "dq": [0.0, 0.0]},
                 "objective": {"effort": 1.0}},
        "transcription": {"method": "trapezoidal", "intervals": 12},
        "solver": {"jit": True, "retries": 0}})


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("UNDERTOW_CACHE_DIR", str(tmp_path))
    return tmp_path


def test_a_new_structure_plans_at_once_and_compiles_in_the_background(cache):
    first = plan(_scene(0.3))
    assert first.solver.success and not first.solver.compiled
    assert compiled.building()  # the stages' kernels, the flow and the linearisation's
    # Jacobians, each in a process of its own
    compiled.wait(300)
    assert not compiled.building()
    assert sorted(p.name.split("_")[0] for p in cache.glob("*.so")) == ["flow", "jacobians",
                                                                      "stages"]
    assert not [p for p in cache.iterdir() if p.is_dir()]  # the build folders are gone

    again = plan(_scene(0.3))
    assert again.solver.compiled
    assert again.objective == pytest.approx(first.objective, rel=1e-9)
    assert np.allclose(again.tau, first.tau, atol=1e-9)
    assert again.verification.local_error == pytest.approx(first.verification.local_error,
                                                           rel=1e-6, abs=1e-12)
