"""A generated suite of impossible planning tasks: how plainly and how early the planner
says that a task cannot be done.

Drawn from a seed like `testbed.suites.ordinary` and `testbed.suites.hard`, each task named by its
category (`<category>-<index>`), one of:

- `short-duration`: a random 2- to 4-link arm (any mix of passive and active joints, g = 0
  or 9.81, waves on about half of the active joints) moving every joint by up to MOVE rad
  rest to rest under a torque limit, in a fixed duration of SHORT (0.3 to 0.7) times the
  reference shortest duration of that move under that limit (`reference`);
- `short-range`: the same with a duration range whose longest end is such a share;
- `unreachable-tip`: a random 2- to 5-link arm whose tip must reach a point beyond its
  reach (1.02 to 1.5 times it), or, for an arm whose first link outreaches the others,
  a point nearer to the base than the arm folds;
- `zero-torque`: a random 2- to 4-link arm with a torque limit of 0 on every joint and a
  goal its free motion does not reach;
- `contradictory-bounds`: in turn, position bounds that exclude the goal, velocity bounds
  too tight to cover the move in the duration, and a tip target out of the tip's reach
  with the final angles within their position bounds.

The last three are impossible by construction: each is drawn until a check of
`planner.feasibility` proves it so (those checks are sufficient conditions). A short
duration is impossible as far as the reference goes: the reference is the shortest
duration of a verified time-optimal plan of the move under its limit, the least of two
solves (from the planner's interpolation guess, and from the unlimited motion stretched,
`planner.ocp.shortest`), each within REFERENCE_WALL_TIME in one process; a share of at
most 0.7 of it leaves room for local optima of those solves. A move whose reference
solves give no verified plan is drawn again. References cost solves: those of SEED and
HELD_OUT within COUNT are stored (REFERENCE_FILE, data/impossible-references.json, written
by `python -m testbed.suites regenerate --suite impossible`); any other is solved when its
task is drawn.

    impossible_tasks(count, seed) -> list of (name, Scene)
    task_of((seed, index)) -> (name, Scene)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pydantic import model_validator

from planner import feasibility
from planner.model import Robot
from planner.scene import Scene
from testbed.suites.hard import guess_peak, one_process
from testbed.suites.ordinary import random_robot
from testbed.suites.records import DATA, Key, Record, StoredRecords, close

SEED = 20261126
HELD_OUT = (16180339, 14142135)
"""A seed of the suite that nothing was tuned on."""
COUNT = 40
CATEGORIES = ("short-duration", "short-range", "unreachable-tip", "zero-torque",
              "contradictory-bounds")
GRAVITY = 9.81
DURATION = 1.0  # [s] the duration a torque limit is drawn at, and that of the others
MOVE = 1.0  # [rad] largest joint move
LIMIT = (0.4, 1.0)  # the torque limit's share of the cubic move's peak torque in DURATION
SHORT = (0.3, 0.7)  # a short duration's share of the reference shortest one
RANGE_START = (0.3, 0.8)  # a short range's shortest end as a share of its longest
REFERENCE_RANGE = (0.02, 20.0)  # [s] the reference time-optimal solves' duration range
REFERENCE_WALL_TIME = 300.0  # [s] each reference solve's budget
TRIES = 20
SHORT_CATEGORIES = ("short-duration", "short-range")
"""The categories whose tasks draw references."""


class Reference(Record):
    """The reference solves of a short task's move: its torque limit [N m], start and goal
    [rad], the shortest verified duration they found [s] (None: none verified) and their
    Ipopt iterations."""

    limit: float
    start: tuple[float, ...]
    goal: tuple[float, ...]
    shortest: float | None
    iterations: int

    @model_validator(mode="after")
    def _consistent(self) -> Reference:
        if len(self.start) != len(self.goal) or self.limit <= 0.0 or self.iterations < 0 \
                or (self.shortest is not None and self.shortest <= 0.0):
            raise ValueError("start and goal of different numbers of joints, or a limit, "
                             "a shortest duration or iterations not positive")
        return self


def _kinds(rng: np.random.Generator, n: int) -> str:
    """Joint kinds of n links, at least one active."""
    kinds = rng.choice(["A", "P"], n)
    kinds[int(rng.integers(n))] = "A"
    return "".join(kinds)


def _arm(rng: np.random.Generator, links: tuple[int, int], gravity: float) -> Robot:
    n = int(rng.integers(links[0], links[1] + 1))
    return random_robot(rng, _kinds(rng, n), gravity)


def _scene(robot: Robot, start, goal, **task: Any) -> Scene:
    final = task.pop("final", {"q": np.round(goal, 6).tolist(), "dq": [0.0] * robot.n})
    return Scene.model_validate({
        "robot": robot.model_dump(mode="json"),
        "task": {"duration": DURATION, "initial": {"q": np.round(start, 6).tolist(),
                                                   "dq": [0.0] * robot.n},
                 "final": final, **task}})


def _move(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    centre = rng.uniform(-1.0, 1.0, n)
    step = rng.uniform(-MOVE, MOVE, n)
    return np.round(centre - step / 2, 6), np.round(centre + step / 2, 6)


def _proven(scene: Scene) -> bool:
    """Whether a check before any solve proves the task infeasible."""
    return bool(feasibility.check(scene))


# --------------------------------------------------------------------------- references


def stored_reference(key: Key | None, start, goal, limit: float) -> Reference | None:
    """The stored reference of task `key` (seed, index) for this move and limit, if any."""
    return REFERENCES.lookup(key, lambda r: r.limit == limit and close(r.start, start)
                             and close(r.goal, goal))


def time_optimal(robot: Robot, start, goal, limit: float) -> Scene:
    """The time-optimal task of a move under a torque limit: duration free in
    REFERENCE_RANGE, the duration minimised with a little effort."""
    return _scene(robot, start, goal, torque_limit=limit,
                  duration={"min": REFERENCE_RANGE[0], "max": REFERENCE_RANGE[1]},
                  objective={"effort": 1e-3, "time": 1.0})


def _solve_reference(robot: Robot, start: np.ndarray, goal: np.ndarray,
                     limit: float) -> Reference:
    """The least verified duration of the two reference solves (see the module)."""
    from planner.ocp import plan
    from planner.ocp.planner import shortest_duration

    scene = time_optimal(robot, start, goal, limit)
    data = scene.model_dump(mode="json")
    data["solver"]["max_wall_time"] = REFERENCE_WALL_TIME
    scene = Scene.model_validate(data)
    found: list[float] = []
    iterations = 0
    with one_process():
        direct = plan(scene)
        iterations += direct.solver.iterations
        if direct.solver.success and direct.verification.verified:
            found.append(direct.duration)
        fixed = _scene(robot, start, goal, torque_limit=limit).model_copy(
            update={"solver": scene.solver})
        probe = shortest_duration(fixed, REFERENCE_RANGE[0])
        iterations += sum(p.iterations for p in probe.passes)
        if probe.shortest is not None:
            found.append(probe.shortest)
    return Reference(limit=limit, start=tuple(start.tolist()), goal=tuple(goal.tolist()),
                     shortest=min(found) if found else None, iterations=iterations)


def reference(robot: Robot, start: np.ndarray, goal: np.ndarray, limit: float,
              key: Key | None = None) -> Reference:
    """The reference shortest duration of a move under a torque limit: stored for the
    tasks of `key` (seed, index) in REFERENCE_FILE, else solved."""
    found = stored_reference(key, start, goal, limit)
    if found is None:
        found = _solve_reference(robot, start, goal, limit)
    REFERENCES.keep(key, found)
    return found


# --------------------------------------------------------------------------- tasks


def _short(rng: np.random.Generator, gravity: float, key: Key | None,
           ranged: bool) -> Scene:
    for _ in range(TRIES):
        robot = _arm(rng, (2, 4), gravity)
        start, goal = _move(rng, robot.n)
        peak = guess_peak(_scene(robot, start, goal), DURATION)
        limit = round(float(rng.uniform(*LIMIT)) * peak, 3)
        share = float(rng.uniform(*SHORT))
        first = float(rng.uniform(*RANGE_START))
        if limit <= 0.0:
            continue
        ref = reference(robot, start, goal, limit, key)
        if ref.shortest is None:
            continue
        longest = round(share * ref.shortest, 4)
        duration: float | dict = ({"min": round(first * longest, 4), "max": longest}
                                  if ranged else longest)
        return _scene(robot, start, goal, torque_limit=limit, duration=duration)
    raise RuntimeError("no move whose reference solves verified")


def _unreachable_tip(rng: np.random.Generator, gravity: float, index: int) -> Scene:
    robot = _arm(rng, (2, 5), gravity)
    start, _ = _move(rng, robot.n)
    angle = float(rng.uniform(-math.pi, math.pi))
    if index % 2:  # a first link that outreaches the others: the arm cannot fold onto it
        links = robot.model_dump(mode="json")["links"]
        others = feasibility.reach(robot) - robot.links[0].length
        links[0]["length"] = round(others + float(rng.uniform(0.1, 0.3)), 3)
        links[0]["wave"] = None
        robot = Robot.model_validate({"links": links, "gravity": gravity})
        distance = feasibility.innermost(robot) * float(rng.uniform(0.0, 0.9))
    else:
        distance = feasibility.reach(robot) * float(rng.uniform(1.02, 1.5))
    return _scene(robot, start, start, tip_target={
        "x": round(distance * math.cos(angle), 6), "y": round(distance * math.sin(angle), 6)},
        final={"q": [None] * robot.n, "dq": [0.0] * robot.n})


def _zero_torque(rng: np.random.Generator, gravity: float) -> Scene:
    for _ in range(TRIES):
        robot = _arm(rng, (2, 4), gravity)
        scene = _scene(robot, *_move(rng, robot.n), torque_limit=0.0)
        if _proven(scene):
            return scene
    raise RuntimeError("no zero-torque task its free motion misses")


def _contradictory(rng: np.random.Generator, gravity: float, index: int) -> Scene:
    for _ in range(TRIES):
        robot = _arm(rng, (2, 4), gravity)
        start, goal = _move(rng, robot.n)
        joint = int(rng.integers(robot.n))
        kind = (index // len(CATEGORIES)) % 3
        if kind == 0:  # the goal outside its joint's position bounds
            gap = float(rng.uniform(0.05, 0.3))
            lower: list[float | None] = [None] * robot.n
            upper: list[float | None] = [None] * robot.n
            lo, hi = sorted((start[joint], goal[joint]))
            if goal[joint] >= start[joint]:  # a bound between the start's side and the goal
                lower[joint] = round(lo - 0.1, 6)
                upper[joint] = round(max(goal[joint] - gap, lo - 0.09), 6)
            else:
                upper[joint] = round(hi + 0.1, 6)
                lower[joint] = round(min(goal[joint] + gap, hi + 0.09), 6)
            scene = _scene(robot, start, goal,
                           position_bounds={"lower": lower, "upper": upper})
        elif kind == 1:  # rates too slow for the move in the duration
            needed = abs(goal[joint] - start[joint]) / DURATION
            rate = round(needed * float(rng.uniform(0.3, 0.9)), 6)
            bounds = {"lower": [-rate if j == joint else None for j in range(robot.n)],
                      "upper": [rate if j == joint else None for j in range(robot.n)]}
            scene = _scene(robot, start, goal, velocity_bounds=bounds)
        else:  # a tip target the bounded final angles cannot reach
            width = rng.uniform(0.1, 0.6, robot.n)
            lower = np.round(goal - width / 2, 6).tolist()
            upper = np.round(goal + width / 2, 6).tolist()
            lower = [min(lo, s) for lo, s in zip(lower, start, strict=True)]  # start within
            upper = [max(hi, s) for hi, s in zip(upper, start, strict=True)]
            angle = float(np.mean(goal)) + math.pi + float(rng.uniform(-0.5, 0.5))
            distance = feasibility.reach(robot) * float(rng.uniform(0.2, 0.9))
            scene = _scene(robot, start, goal, position_bounds={"lower": lower, "upper": upper},
                           tip_target={"x": round(distance * math.cos(angle), 6),
                                       "y": round(distance * math.sin(angle), 6)},
                           final={"q": [None] * robot.n, "dq": [0.0] * robot.n})
        if _proven(scene):
            return scene
    raise RuntimeError("no contradictory bounds found")


def _task(kind: str, rng: np.random.Generator, gravity: float, index: int,
          key: Key | None) -> Scene:
    if kind in SHORT_CATEGORIES:
        return _short(rng, gravity, key, kind == "short-range")
    if kind == "unreachable-tip":
        return _unreachable_tip(rng, gravity, index)
    if kind == "zero-torque":
        return _zero_torque(rng, gravity)
    if kind == "contradictory-bounds":
        return _contradictory(rng, gravity, index)
    raise ValueError(f"unknown category {kind!r}")


def impossible_task(index: int, seed: int = SEED) -> tuple[str, Scene]:
    """Task `index` of the suite of `seed`, named "<category>-<index>"; gravity alternates
    from one round of the categories to the next."""
    kind = CATEGORIES[index % len(CATEGORIES)]
    gravity = GRAVITY if (index // len(CATEGORIES)) % 2 else 0.0
    rng = np.random.default_rng([seed, index])
    return f"{kind}-{index:02d}", _task(kind, rng, gravity, index, (seed, index))


def impossible_tasks(count: int = COUNT, seed: int = SEED) -> list[tuple[str, Scene]]:
    """The first `count` tasks of the suite of `seed` (task i depends on (seed, i) alone,
    so a shorter suite is the start of a longer one)."""
    return [impossible_task(index, seed) for index in range(count)]


def task_of(key: Key) -> tuple[str, Scene]:
    """The task whose random draws come from `key` (seed, index)."""
    return impossible_task(key[1], key[0])


# --------------------------------------------------------------------------- stored


def reference_keys(seed: int) -> list[Key]:
    """(seed, index) of the tasks of `seed` within COUNT that draw references: the short
    ones."""
    return [(seed, i) for i in range(COUNT) if CATEGORIES[i % len(CATEGORIES)] in SHORT_CATEGORIES]


REFERENCE_FILE = DATA / "impossible-references.json"
REFERENCES = StoredRecords(
    REFERENCE_FILE, Reference,
    "What the reference solves of the impossible suite's short tasks found "
    "(testbed.suites.impossible.Reference), per task (seed, index), per move its draw tried. "
    "Written by `python -m testbed.suites regenerate --suite impossible`; not edited by hand.",
    seeds=(SEED, *HELD_OUT), keys=reference_keys, draw=task_of)
"""The stored references of the short tasks of SEED and HELD_OUT within COUNT."""
