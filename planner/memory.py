"""Memory of motion: the stored plan a new scene should start from (`solver.warm_start:
"nearest"`).

An earlier plan can seed a scene when it has the same *shape*: the same number of joints,
the same passive ones, waves on the same joints, the same final-state entries left free, and
a tip target in both or neither. Its trajectory is then an initial guess of the right size,
and where its NLP is the same problem (`planner.ocp.key.ProblemKey`), its solution
starts the solver primal and dual.

Among the plans of the same shape the nearest is the one at the least `distance`, a length
in radians: the largest change of a boundary angle, a boundary rate over the time a quarter
of the motion takes, the tip target over the arm's reach, the relative change of the
duration and of every robot number, and a whole radian for every part of the task stated
differently (objective, limits, bounds, targets). Beyond `REACH` no plan is near enough: a
cold start is the better bet.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from planner.scene import DurationRange, Scene

NEAREST = "nearest"
"""The value of solver.warm_start that asks for the nearest stored plan."""
REACH = 0.05
"""[rad] the largest distance to a plan a scene still starts from (docs/benchmarks.md,
"Memory of motion": at 0.05 rad the warm plans took a median 0.65 s against 1.76 s cold, at
0.2 rad 7.8 s against 1.3 s)."""
_STATED = ("tracking", "torque_limit", "position_bounds", "velocity_bounds",
           "objective", "coupling_margin", "co_design")
"""The parts of a task that change its optimum when stated differently."""


def shape(scene: Scene) -> tuple:
    """What must be equal for a plan of one scene to seed another: the joints (passive or
    active, waved or not), which final entries are free, and whether a tip target is."""
    links = tuple((link.joint, link.wave is not None) for link in scene.robot.links)
    final = scene.task.final
    return (links, tuple(v is None for v in final.q), tuple(v is None for v in final.dq),
            scene.task.tip_target is None)


def _duration(scene: Scene) -> float:
    """T [s]: the fixed duration, or the middle of a free one's range."""
    d = scene.task.duration
    return 0.5 * (d.min + d.max) if isinstance(d, DurationRange) else float(d)


def _numbers(scene: Scene) -> np.ndarray:
    """The robot's positive numbers (lengths, masses, inertias + 1, gravity + 1) whose
    relative change counts, shape (3 n + 1,)."""
    links = scene.robot.links
    return np.array([link.length for link in links] + [link.mass for link in links]
                    + [1.0 + link.inertia for link in links] + [1.0 + scene.robot.gravity])


def _waves(scene: Scene) -> np.ndarray:
    """Every wave's amplitude over its link length, frequency and phase, shape (3 w,)."""
    return np.array([x for link in scene.robot.links if link.wave is not None
                     for x in (link.wave.amplitude / link.length, link.wave.frequency,
                               link.wave.phase)])


def _boundary(scene: Scene, T: float) -> np.ndarray:
    """The stated boundary values: angles [rad], rates times T / 4 [rad]."""
    task = scene.task
    angles = [*task.initial.q, *(q for q in task.final.q if q is not None)]
    rates = [*task.initial.dq, *(v for v in task.final.dq if v is not None)]
    return np.array(angles + [0.25 * T * v for v in rates])


def _tip(scene: Scene) -> np.ndarray:
    """The tip target over the arm's reach [rad of the whole arm], shape (2,) or (0,)."""
    target = scene.task.tip_target
    if target is None:
        return np.zeros(0)
    return np.array([target.x, target.y]) / sum(link.length for link in scene.robot.links)


def distance(a: Scene, b: Scene) -> float:
    """How far apart two scenes of the same `shape` are [rad] (inf between shapes)."""
    if shape(a) != shape(b):
        return math.inf
    Ta, Tb = _duration(a), _duration(b)
    T = max(Ta, Tb)
    parts = [np.abs(_boundary(a, T) - _boundary(b, T)),
             np.abs(np.log(_numbers(a) / _numbers(b))),
             np.abs(_waves(a) - _waves(b)),
             [float(np.linalg.norm(_tip(a) - _tip(b)))],
             [abs(math.log(Ta / Tb))]]
    stated = sum(getattr(a.task, k) != getattr(b.task, k) for k in _STATED)
    stated += isinstance(a.task.duration, DurationRange) != isinstance(b.task.duration,
                                                                       DurationRange)
    return float(max(float(np.max(p, initial=0.0)) for p in parts)) + float(stated)


def nearest(scene: Scene, stored: Iterable[tuple[str, dict[str, Any]]],
            reach: float = REACH) -> tuple[str, float] | None:
    """The id and distance of the nearest of `stored` ((id, scene as JSON) pairs) within
    `reach`, or None. A stored scene that no longer validates is passed over."""
    best: tuple[str, float] | None = None
    for key, body in stored:
        try:
            other = Scene.model_validate(body)
        except ValueError:
            continue
        d = distance(scene, other)
        if d <= reach and (best is None or d < best[1]):
            best = (key, d)
    return best
