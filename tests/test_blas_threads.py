"""A solver process runs CasADi's OpenBLAS on one thread (`planner.blas_threads`) unless
its environment says otherwise: checked in fresh processes, since OpenBLAS keeps its
thread count for the life of the process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from planner import blas_threads

PROBE = """
import json
from planner import blas_threads
from planner.examples import example
from planner.ocp import plan
from planner.prebuild import one_iteration
from planner.scene import Scene
before = blas_threads.threads()
plan(one_iteration(Scene.model_validate(example("two-link-plan").request)))
print(json.dumps({"before": before, "after": blas_threads.threads(),
                  "limited": blas_threads.limit()}))
"""


def _probe(**env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k != blas_threads.ENVIRONMENT}
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         check=True, timeout=300, env={**clean, **env})
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(blas_threads.threads() is None, reason="CasADi brings no OpenBLAS here")
def test_a_plan_runs_the_solver_blas_on_one_thread():
    found = _probe()
    assert found["limited"] is True
    assert found["after"] == 1
    assert found["before"] == os.cpu_count()  # OpenBLAS' own choice: a thread per core


@pytest.mark.skipif(blas_threads.threads() is None, reason="CasADi brings no OpenBLAS here")
def test_the_environment_keeps_its_own_thread_count():
    cores = os.cpu_count() or 1  # OpenBLAS runs at most a thread per core
    found = _probe(**{blas_threads.ENVIRONMENT: str(cores)})
    assert found["limited"] is False
    assert found["after"] == cores
