"""Stand-in solve functions for the job machinery without Ipopt (tests, and the fault
benchmark's servers: UNDERTOW_SOLVE_FUNCTION=testbed.fake_solvers:fake_plan).

`fake_plan` runs `solver.max_iter` iterations of 20 ms each, reporting progress and
honouring a stop request like planner.ocp.plan does (a task refused at admission it refuses
as the planner does). `solver.tol` picks the outcome:
< 0.2 converges, [0.2, 0.25) converges to a plan whose re-simulation departs by 0.5 rad,
[0.25, 0.5) raises, [0.5, 0.7) fails, [0.7, 0.8) is refused at once (Ipopt's
"Invalid_Problem_Definition": no iteration, no progress), [0.8, 0.9) first "builds" for
`task.duration` seconds without reporting progress, then converges, [0.9, 0.95) allocates
`max_iter` MB, then converges, >= 0.95 kills the worker process.
"""

from __future__ import annotations

import os
import time

from planner.ocp.result import Plan, Progress
from planner.scene import Scene
from planner.service import plan

ITERATION = 0.02  # [s]


def _duration(scene: Scene) -> float:
    """The scene's duration, the upper bound of a free one [s]."""
    duration = scene.task.duration
    return duration if isinstance(duration, float) else duration.max


def _plan(scene: Scene, status: str, success: bool, iterations: int, elapsed: float,
          error: float = 0.0) -> Plan:
    n, na = scene.robot.n, len(scene.robot.active)
    T = _duration(scene)
    zeros, tau = [[0.0] * n] * 2, [[0.0] * na] * 2
    return Plan.model_validate({
        "t": [0.0, T], "q": [scene.task.initial.q, scene.task.initial.q], "dq": zeros,
        "ddq": zeros, "tau": tau, "dense": {"t": [0.0, T], "q": zeros, "tau": tau},
        "duration": T, "objective": 1.0, "waves": [],
        "solver": {"status": status, "success": success, "message": "" if success else status,
                   "iterations": iterations, "build_time": 0.0, "solve_time": elapsed,
                   "cache_hit": False},
        "verification": {"local_error": error, "local_status": "completed",
                         "resimulation_error": error, "resimulation_status": "completed",
                         "verified": error <= scene.solver.resimulation_tolerance,
                         "tolerance": scene.solver.resimulation_tolerance, "defect": 0.0,
                         "min_sigma": None, "waveless_min_sigma": None,
                         "waveless_singular_crossings": []}})


def fake_plan(scene: Scene, progress=None, warm_start=None, issues=None) -> Plan:
    """A plan after `max_iter` fake iterations; stops early when `progress` returns False.
    A task whose admission found `issues` is refused at once, as the planner refuses it
    (`planner.service.plan`); `warm_start` is taken and not used (the fake starts cold)."""
    if issues:
        return plan(scene, issues=issues)
    tol, start = scene.solver.tol, time.monotonic()
    if tol >= 0.95:
        os._exit(3)
    if 0.9 <= tol < 0.95:
        held = bytearray(scene.solver.max_iter * 2**20)
        return _plan(scene, "Solve_Succeeded", True, len(held) // 2**20, 0.0)
    if 0.8 <= tol < 0.9:
        time.sleep(_duration(scene))
    if 0.7 <= tol < 0.8:
        return _plan(scene, "Invalid_Problem_Definition", False, 0, 0.0)
    if 0.25 <= tol < 0.5:
        raise RuntimeError("the fake solver broke")
    for k in range(scene.solver.max_iter):
        time.sleep(ITERATION)
        step = Progress(iteration=k, objective=1.0 / (k + 1), inf_pr=float("nan"),
                        inf_du=None, elapsed=time.monotonic() - start)
        if progress is not None and not progress(step):
            return _plan(scene, "User_Requested_Stop", False, k + 1, time.monotonic() - start)
    if 0.5 <= tol < 0.7:
        return _plan(scene, "Maximum_Iterations_Exceeded", False, scene.solver.max_iter,
                     time.monotonic() - start)
    return _plan(scene, "Solve_Succeeded", True, scene.solver.max_iter, time.monotonic() - start,
                 0.5 if 0.2 <= tol < 0.25 else 0.0)
