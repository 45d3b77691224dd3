"""A generated suite of impossible planning tasks: how plainly and how early the planner
says that a task cannot be done.

Drawn from a seed like `planner.suite` and `planner.hard_suite`, each task named by its
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
HELD_OUT within COUNT are stored (`planner.impossible_suite_references`, written by
`python -m planner.impossible_suite [SEED ...]`, which solves the seeds given, all stored
ones by default, and keeps the others); any other is solved when its task is drawn.

    impossible_tasks(count, seed) -> list of (name, Scene)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner import feasibility
from planner.hard_suite import guess_peak
from planner.model import Robot
from planner.scene import Scene
from planner.stored_records import module_text
from planner.suite import random_robot

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
REFERENCE_FILE = Path(__file__).with_name("impossible_suite_references.py")


@dataclass(frozen=True)
class Reference:
    """The reference solves of a short task's move: its torque limit [N m], start and goal
    [rad], the shortest verified duration they found [s] (None: none verified) and their
    Ipopt iterations."""

    limit: float
    start: tuple[float, ...]
    goal: tuple[float, ...]
    shortest: float | None
    iterations: int


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

_use_stored = True
_solved: dict[tuple[int, int], list[Reference]] = {}


def _stored(key: tuple[int, int] | None, start: np.ndarray, goal: np.ndarray,
            limit: float) -> Reference | None:
    if key is None or not _use_stored:
        return None
    from planner.impossible_suite_references import REFERENCES

    for record in REFERENCES.get(key, []):
        if len(record["start"]) == len(start) \
                and np.allclose(record["start"], start, rtol=0.0, atol=1e-9) \
                and np.allclose(record["goal"], goal, rtol=0.0, atol=1e-9) \
                and record["limit"] == limit:
            return _reference(record)
    return None


def _reference(record: dict[str, Any]) -> Reference:
    """A stored record as a Reference."""
    return Reference(**{**record, "start": tuple(record["start"]),
                        "goal": tuple(record["goal"])})


def time_optimal(robot: Robot, start, goal, limit: float) -> Scene:
    """The time-optimal task of a move under a torque limit: duration free in
    REFERENCE_RANGE, the duration minimised with a little effort."""
    return _scene(robot, start, goal, torque_limit=limit,
                  duration={"min": REFERENCE_RANGE[0], "max": REFERENCE_RANGE[1]},
                  objective={"effort": 1e-3, "time": 1.0})


def _solve_reference(robot: Robot, start: np.ndarray, goal: np.ndarray,
                     limit: float) -> Reference:
    """The least verified duration of the two reference solves (see the module)."""
    from planner.hard_suite import one_process
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
    return Reference(limit, tuple(start.tolist()), tuple(goal.tolist()),
                     min(found) if found else None, iterations)


def reference(robot: Robot, start: np.ndarray, goal: np.ndarray, limit: float,
              key: tuple[int, int] | None = None) -> Reference:
    """The reference shortest duration of a move under a torque limit: stored for the
    tasks of `key` (seed, index) in `planner.impossible_suite_references`, else solved."""
    found = _stored(key, start, goal, limit) or _solve_reference(robot, start, goal, limit)
    if key is not None and found not in _solved.setdefault(key, []):
        _solved[key].append(found)
    return found


# --------------------------------------------------------------------------- tasks


def _short(rng: np.random.Generator, gravity: float, key: tuple[int, int] | None,
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
          key: tuple[int, int] | None) -> Scene:
    if kind in ("short-duration", "short-range"):
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


# --------------------------------------------------------------------------- stored

_DOCSTRING = """What the reference solves of the impossible suite's short tasks found, for the tasks
of planner.impossible_suite.SEED and HELD_OUT within COUNT: per (seed, index), per move
drawn, `planner.impossible_suite.Reference` as a dict. Written by `python -m
planner.impossible_suite`; not edited by hand."""


def write_references(seeds: tuple[int, ...] = (SEED, *HELD_OUT), count: int = COUNT) -> None:
    """Solve the references of the short tasks of `seeds` within `count` afresh and store
    them in REFERENCE_FILE beside the stored ones of other seeds."""
    global _use_stored
    from planner.impossible_suite_references import REFERENCES

    _solved.clear()
    for key, records in REFERENCES.items():
        if key[0] not in seeds:
            _solved[key] = [_reference(record) for record in records]
    _use_stored = False
    try:
        for seed in seeds:
            for index in range(count):
                name, _ = impossible_task(index, seed)
                for found in _solved.get((seed, index), []):
                    print(seed, name, f"shortest {found.shortest}, "
                          f"{found.iterations} iterations", flush=True)
    finally:
        _use_stored = True
    stored = {key: [asdict(r) for r in found] for key, found in _solved.items()}
    REFERENCE_FILE.write_text(module_text(_DOCSTRING, "REFERENCES", stored))


if __name__ == "__main__":
    import sys

    from planner import impossible_suite

    impossible_suite.write_references(tuple(int(s) for s in sys.argv[1:])
                                      or (SEED, *HELD_OUT))
