"""A generated adversarial suite: tasks drawn to make a plan's verdict lie, if it can.

Drawn from a seed, each task named by its category (`<category>-<index>`), one of:

- `short-budget`: a 3- to 6-link chain with a tip target in reach and free final angles,
  planned with a budget far too short for it (a wall time of 0.2 to 2 s, or 1 to 10
  iterations), no retries: what it returns must not be called verified unless it does
  the task;
- `tip-near-reach`: a 2- or 3-link chain with free final angles and a tip target at
  1 - 0.02 to 1 + 0.02 times the arm's extent in a random direction (`extent`): beyond it
  the task is impossible (a proof), within it possible or not (the farthest tip in a
  direction need not lie on its ray);
- `energy-starved`: a 2- or 3-link chain in gravity raised or lowered between rest
  states under a torque limit of 0.3 to 3 times (log-uniform) the one at which the
  energy the move needs equals what the limit lets the actuators exchange
  (`planner.energy_bound`): below it proven impossible, above it possible or not;
- `margin`: the two-link example with a coupling margin log-uniform from 1e-6 to half
  sigma_min at its start;
- `duration`: a 2- or 3-link chain in gravity under a torque limit of 2 to 6 N m, asked to
  move in a duration log-uniform from 0.1 to 3 s.

    tasks(count, seed) -> list of (name, Scene)
"""

from __future__ import annotations

import copy
import math

import numpy as np

from planner import feasibility
from planner.coupling_block import at
from planner.dynamics import Dynamics
from planner.energy_bound import energy_reach
from planner.examples import example
from planner.scene import Scene
from testbed.robots import chain

SEED = 20261127
CATEGORIES = ("short-budget", "tip-near-reach", "energy-starved", "margin", "duration")
COUNT = 40


def _scene(robot: dict, task: dict, solver: dict | None = None,
           intervals: int = 30) -> Scene:
    return Scene.model_validate({"robot": robot, "task": task,
                                 "transcription": {"intervals": intervals},
                                 "solver": solver or {}})


def _rest(n: int, q: list[float]) -> dict:
    return {"q": q, "dq": [0.0] * n}


def _short_budget(rng: np.random.Generator) -> Scene:
    n = int(rng.integers(3, 7))
    start = [0.1 * k for k in range(n)]
    angle = rng.uniform(-math.pi / 2, math.pi / 2)
    radius = rng.uniform(0.4, 0.8) * 0.4 * n
    task = {"duration": 1.5, "initial": _rest(n, start),
            "final": {"q": [None] * n, "dq": [0.0] * n},
            "tip_target": {"x": radius * math.cos(angle), "y": radius * math.sin(angle)}}
    solver: dict = {"retries": 0}
    if rng.random() < 0.5:
        solver["max_wall_time"] = float(round(rng.uniform(0.2, 2.0), 2))
    else:
        solver["max_iter"] = int(rng.integers(1, 11))
    return _scene(chain(n, True), task, solver)


def _tip_near_reach(rng: np.random.Generator) -> Scene:
    n = int(rng.integers(2, 4))
    start = [0.1 * k for k in range(n)]
    task = {"duration": 1.5, "initial": _rest(n, start),
            "final": {"q": [None] * n, "dq": [0.0] * n}}
    free = _scene(chain(n, True, gravity=0.0), {**task, "tip_target": {"x": 0.1, "y": 0.0}})
    theta = rng.uniform(-math.pi, math.pi)
    reach = float(feasibility.extent(free, np.array([theta]))[0])
    radius = reach * (1 + rng.uniform(-0.02, 0.02))
    task["tip_target"] = {"x": radius * math.cos(theta), "y": radius * math.sin(theta)}
    return _scene(chain(n, True, gravity=0.0), task)


def _energy_starved(rng: np.random.Generator) -> Scene:
    n = int(rng.integers(2, 4))
    low = [float(v) for v in rng.uniform(-0.3, 0.3, n)]
    high = [float(v) for v in rng.uniform(1.2, 2.2, n)]
    start, goal = (low, high) if rng.random() < 0.5 else (high, low)
    robot = chain(n, False)
    duration = float(round(rng.uniform(0.8, 2.0), 2))
    scene = _scene(robot, {"duration": duration, "initial": _rest(n, start),
                           "final": _rest(n, goal)})
    needed = sum(Dynamics(scene.robot).energy(goal, [0.0] * n)) \
        - sum(Dynamics(scene.robot).energy(start, [0.0] * n))
    limit = _balanced_limit(scene, needed) * math.exp(rng.uniform(math.log(0.3), math.log(3.0)))
    return _scene(robot, {**scene.task.model_dump(exclude_none=True),
                          "torque_limit": float(limit)})


def _balanced_limit(scene: Scene, needed: float) -> float:
    """[N m] The torque limit (on every active joint) at which the energy the move needs
    (`needed` [J], negative to take it) is what the limit lets the actuators add (or take)
    in the task's duration."""
    task, robot = scene.task, scene.robot
    low, high = 1e-6, 1e3
    for _ in range(60):
        middle = math.sqrt(low * high)
        reach = energy_reach(robot, task.initial.q, task.initial.dq,
                             np.full(len(robot.active), middle), task.duration_span[1])
        enough = reach.highest - reach.start >= needed if needed > 0 \
            else reach.start - reach.lowest >= -needed
        low, high = (low, middle) if enough else (middle, high)
    return high


def _margin(rng: np.random.Generator) -> Scene:
    request = copy.deepcopy(example("two-link-plan").request)
    scene = Scene.model_validate(request)
    sigma = at(scene.robot, scene.task.initial.q).sigma_min
    assert sigma is not None  # the example has a passive joint
    request["task"]["coupling_margin"] = float(math.exp(
        rng.uniform(math.log(1e-6), math.log(sigma / 2))))
    return Scene.model_validate(request)


def _duration(rng: np.random.Generator) -> Scene:
    n = int(rng.integers(2, 4))
    start = [float(v) for v in rng.uniform(-0.5, 0.5, n)]
    goal = [s + float(rng.uniform(-0.8, 0.8)) for s in start]
    duration = float(math.exp(rng.uniform(math.log(0.1), math.log(3.0))))
    task = {"duration": round(duration, 3), "initial": _rest(n, start),
            "final": _rest(n, goal), "torque_limit": float(round(rng.uniform(2.0, 6.0), 2))}
    return _scene(chain(n, bool(rng.random() < 0.5)), task)


_MAKERS = {"short-budget": _short_budget, "tip-near-reach": _tip_near_reach,
           "energy-starved": _energy_starved, "margin": _margin, "duration": _duration}


def task(index: int, seed: int = SEED) -> tuple[str, Scene]:
    """The suite's task `index` of `seed`: categories in turn."""
    kind = CATEGORIES[index % len(CATEGORIES)]
    rng = np.random.default_rng([seed, index])
    return f"{kind}-{index}", _MAKERS[kind](rng)


def tasks(count: int = COUNT, seed: int = SEED) -> list[tuple[str, Scene]]:
    """The first `count` tasks of `seed`."""
    return [task(index, seed) for index in range(count)]
