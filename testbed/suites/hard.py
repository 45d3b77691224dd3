"""A generated suite of hard planning tasks: where plans take hundreds of iterations.

Beside `testbed.suites.ordinary` (ordinary tasks), drawn from a seed the same way, each
task named by its category (`<category>-<index>`), one of:

- `seed-g0-cross`, `seed-g9.81-cross`: the seed's 4-link arm with its waves
  (`planner.examples.seed_arm(True)`: passive joints 0 and 2, waves on 1 and 3) in a
  horizontal (g = 0) and a vertical plane, rest to rest across a waveless coupling
  singularity: det M_pa of the arm without waves has opposite signs at the start and the
  goal, which lie about a singular configuration (`testbed.suites.ordinary.singular_configuration`)
  with every joint moved by up to MOVE = 1.5 rad;
- `seed-swing`: the seed arm in gravity, one active joint swung by SWING = 2 rad, the
  other joints moved by up to 0.5 rad;
- `links-5to8`: random 5- to 8-link arms (`testbed.suites.ordinary.random_robot`) with mixed joints
  (at least one passive, no more passive than active; as many passive as active for half
  of the even numbers of links), across a waveless singularity where M_pa is square, every
  joint moved by up to LINKS_MOVE = 0.8 rad;
- `torque-limit`: the seed arm across a waveless singularity (moves up to 1 rad),
  time-optimal (duration up to 4 s, time weight 1, effort 1e-2) under a torque limit: at
  least twice the holding torque at the start and the goal and 1.5 times the largest torque
  of the straight (cubic) move in 4 s (`guess_peak`), plus 0.5 to 2 N m; the shortest
  duration allowed (0.5 s or less) would need 1.5 times the limit for that move, so the
  limit, not the duration's bound, is what a time-optimal plan runs into;
- `free-time`: random 2- to 4-link arms (across a waveless singularity where M_pa is
  square, moves up to 1 rad), free final time (1 to 4 s) with a time weight of 0.5 to 5
  beside the effort;
- `tip-target`: random 3- to 5-link arms whose final angles are free: the tip must reach
  the tip of a random goal configuration (reachable by construction), at rest;
- `bounds`: the seed arm across a waveless singularity (moves up to 1 rad) with position
  and velocity bounds on about three quarters of its joints, drawn from witnesses (see
  `witnessed`): the unbounded plan of the move (the task without bounds, on
  WITNESS_INTERVALS intervals) has its peak rate cut by SPEED_CUT and its excursion
  beyond BOUND_MARGIN around start and goal by EXCURSION_CUT, and a verified plan within
  those bounds (the witness) proves them feasible; the unbounded plan leaves them, so they
  bind. Bounds drawn around start and goal alone (0.1 to 0.3 rad beyond them, rates 2.5
  times the straight move's mean) could not be kept: plans of a crossing verified only
  with those rate bounds 4 to 8 times as wide (docs/benchmarks.md, "The hard suite");
- `co-design`: the seed arm with its wave amplitudes and phases co-designed (amplitude at
  most 0.06 m, frequencies 4) and a coupling margin of 0.005, across a waveless
  singularity (moves up to 1 rad): with the seed's designed waves (a design the co-design
  may choose) sigma_min(M_pa) keeps twice the margin along the straight segment, and
  det M_pa keeps the sign it has at the start for the planner's first design.

Beside the suite's cycle, extra categories are drawn on their own (`category_tasks`,
EXTRA_COUNT tasks a seed), so that adding one leaves the suite's tasks as they were:

- `bounds-5-links`: random 5-link arms (mixed joints, as `links-5to8`), every joint moved
  by up to LINKS_MOVE rad, with position and velocity bounds drawn from a witness as for
  `bounds`.

Where a category does not fix it, gravity alternates between g = 0 and g = 9.81 from one
round of CYCLE to the next.

Every task is feasible by construction as far as can be checked before a solve (see
`check`): start and goal within their bounds, sigma_min(M_pa) at the start and the goal at
least the margin, the tip target within reach; a bounds task has, besides, a witness (a
verified plan within its bounds). Witnesses cost solves: those of the tasks of SEED and
HELD_OUT within COUNT and EXTRA_COUNT are stored (WITNESS_FILE, data/hard-witnesses.json,
written by `python -m testbed.suites regenerate --suite hard`), any other is solved when its
task is drawn (seconds to minutes).
Everything else is the scene's default (Legendre degree 3 on 50 intervals, Ipopt, 60 s).

    hard_tasks(count, seed) -> list of (name, Scene)
    category_tasks(name, count, seed) -> list of (name, Scene)
    task_of((seed, index)) -> (name, Scene)

SEED is the suite's own seed, HELD_OUT two seeds for tasks the planner was not tuned on.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import model_validator

from planner.coupling_block import along, zeros_along
from planner.dynamics import Dynamics
from planner.examples import SEED_WAVES, seed_arm
from planner.model import Robot, Wave
from planner.scene import DurationRange, Scene
from testbed.suites.ordinary import random_robot, singular_configuration
from testbed.suites.records import DATA, Key, Record, StoredRecords, close

if TYPE_CHECKING:
    from planner.ocp.result import Plan

SEED = 20261125
HELD_OUT = (31415926, 27182818)
"""Seeds of the hard suite that nothing was tuned on."""
COUNT = 48
CATEGORIES = ("seed-g0-cross", "seed-g9.81-cross", "seed-swing", "links-5to8", "torque-limit",
              "free-time", "tip-target", "bounds", "co-design")
EXTRA_CATEGORIES = ("bounds-5-links",)
"""Categories drawn on their own (`category_tasks`), outside the suite's cycle, so that the
suite's tasks stay what they were."""
EXTRA_COUNT = 8  # tasks of an extra category, per seed
EXTRA_INDEX = 1000  # extra category k's task i is drawn from (seed, EXTRA_INDEX (k + 1) + i)
CYCLE = (*CATEGORIES, "seed-g0-cross", "seed-g9.81-cross", "links-5to8")
"""Task i is of category CYCLE[i % 12]: every category within the first nine tasks; of 48,
eight of each seed-arm crossing and of 5 to 8 links, four of every other."""

GRAVITY = 9.81
DURATION = 2.0  # [s] of a fixed-duration task
MOVE = 1.5  # [rad] largest joint move of a seed-arm crossing
SWING = 2.0  # [rad] the swung joint's move
LINKS_MOVE = 0.8  # [rad] largest joint move of a 5- to 8-link arm
FREE_TIME = (1.0, 4.0)  # [s] duration range of a free-time task
TIME_OPTIMAL = (0.5, 4.0)  # [s] duration range of a time-optimal task (its min or less)
ROOM = 1.5  # limit / the slowest straight move's peak torque, and the fastest's / limit
BOUND_MARGIN = 0.1  # [rad] least distance of start and goal from a position bound
SPEED_CUT = (0.1, 0.3)  # share of the unbounded plan's peak rate a velocity bound cuts off
EXCURSION_CUT = (0.2, 0.5)  # share of its excursion beyond BOUND_MARGIN a position bound cuts
CUT_SCALES = (1.0, 0.5, 0.0)
"""The cuts tried in turn, scaled: until a witness is verified within them; at 0 the bounds
are the unbounded plan's own envelope (rounded outwards), which it witnesses itself."""
WITNESS_TRIES = 5  # moves drawn for a bounds task until the unbounded plan of one verifies
WITNESS_INTERVALS = 30  # the witnesses' first mesh (refined as any plan's)
WITNESS_WALL_TIME = 300.0  # [s] a witness's max_wall_time: its iterations, not the
# machine's speed, decide what it finds (the scene's 60 s would, near the cap)
MARGIN = 0.005  # [kg m^2] coupling margin of a co-design task (the seed-arm example's)
AMPLITUDE_MAX = 0.06  # [m] co-designed amplitudes, as the seed's designed waves
TRIES = 500


def _seed_robot(gravity: float) -> Robot:
    robot = seed_arm(True)
    return robot.model_copy(update={"gravity": gravity})


def _det(robot: Robot, qs) -> np.ndarray:
    det = along(robot, np.atleast_2d(qs)).det
    assert det is not None  # the seed arm's block is square
    return det


def crosses(robot: Robot, start, goal) -> bool:
    """Whether det M_pa of the arm without waves has opposite signs at start and goal (so
    that every path between them passes a configuration where it is singular)."""
    a, b = _det(robot.without_waves(), np.stack([start, goal]))
    return bool(a * b < 0.0)


def _crossing(rng: np.random.Generator, robot: Robot, move: float,
              extra: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Start and goal about a waveless singular configuration, each joint moved by up to
    `move` (plus `extra`), with opposite signs of the waveless det M_pa."""
    for _ in range(TRIES):
        centre = singular_configuration(robot, rng)
        if centre is None:
            break
        step = rng.uniform(-move, move, robot.n) + (0.0 if extra is None else extra)
        start, goal = centre - step / 2, centre + step / 2
        if crosses(robot, start, goal):
            return start, goal
    raise RuntimeError("no crossing found")


def _rest(n: int) -> list[float]:
    return [0.0] * n


def _scene(robot: Robot, start, goal, **task: Any) -> Scene:
    final = task.pop("final", {"q": np.round(goal, 6).tolist(), "dq": _rest(robot.n)})
    return Scene.model_validate({
        "robot": robot.model_dump(mode="json"),
        "task": {"duration": DURATION, "initial": {"q": np.round(start, 6).tolist(),
                                                   "dq": _rest(robot.n)},
                 "final": final, "objective": {"effort": 1.0}, **task}})


def _split(rng: np.random.Generator, n: int) -> str:
    """Joint kinds of n links: 1 to n // 2 passive joints at random places, n // 2 (a
    square M_pa, with waveless singularities to cross) for half of the even n."""
    passive = int(rng.integers(1, n // 2 + 1))
    if n % 2 == 0 and rng.random() < 0.5:
        passive = n // 2
    kinds = np.array(["A"] * n)
    kinds[rng.choice(n, passive, replace=False)] = "P"
    return "".join(kinds)


def _random_arm(rng: np.random.Generator, links: tuple[int, int], gravity: float) -> Robot:
    return random_robot(rng, _split(rng, int(rng.integers(links[0], links[1] + 1))), gravity)


def _moved(rng: np.random.Generator, robot: Robot, move: float) -> tuple[np.ndarray, np.ndarray]:
    """Across a waveless singularity where M_pa is square, else a random move."""
    if len(robot.passive) == len(robot.active):
        return _crossing(rng, robot, move)
    centre = rng.uniform(-0.8, 0.8, robot.n)
    step = rng.uniform(-move, move, robot.n)
    return centre - step / 2, centre + step / 2


def guess_peak(scene: Scene, duration: float) -> float:
    """The largest active torque [N m] of the planner's interpolation guess (the cubic rest
    to rest move, torques from the active rows of the dynamics) at `duration` [s]."""
    from planner.ocp.guess import hermite_guess

    guess = hermite_guess(scene, scene.robot, duration)(np.linspace(0.0, 1.0, 201))
    return float(np.abs(guess["tau"]).max())


def holding_torque(robot: Robot, q) -> float:
    """The largest active joint's gravity torque at rest at q [N m]."""
    return float(np.abs(Dynamics(robot).gravity(q)[robot.active]).max())


def design_start(robot: Robot, amplitude_max: float) -> Robot:
    """The robot a co-design starts from: every active joint's wave at half the amplitude
    bound, with its own frequency and phase (as the planner seeds its NLP)."""
    waves = {}
    for joint in robot.active:
        link = robot.links[joint]
        assert link.wave is not None  # the seed arm's active joints carry waves
        waves[joint] = Wave(amplitude=min(amplitude_max, 0.95 * link.length) / 2,
                            frequency=link.wave.frequency, phase=link.wave.phase)
    return robot.with_waves(waves)


def segment(start, goal, samples: int = 201) -> np.ndarray:
    """Configurations along the straight segment from start to goal, (samples, n)."""
    u = np.linspace(0.0, 1.0, samples)[:, None]
    return np.asarray(start) + u * (np.asarray(goal) - np.asarray(start))


def _co_design_ok(robot: Robot, start, goal, margin: float) -> bool:
    """The seed's designed waves keep sigma_min >= 2 margin along the segment, and their det
    has the sign the planner's first design has at the start."""
    path = segment(start, goal)
    witness = along(robot, path)
    first = _det(design_start(robot, AMPLITUDE_MAX), path[:1])[0]
    assert witness.det is not None
    return bool(witness.sigma_min.min() >= 2 * margin
                and np.all(np.sign(witness.det) == np.sign(first)))


def _torque_limited(rng: np.random.Generator, gravity: float) -> Scene:
    """A `torque-limit` task (see the module)."""
    robot = _seed_robot(gravity)
    start, goal = _crossing(rng, robot, 1.0)
    hold = max(holding_torque(robot, start), holding_torque(robot, goal))
    plain = _scene(robot, start, goal)
    slow = ROOM * guess_peak(plain, TIME_OPTIMAL[1])
    limit = round(max(2 * hold, slow, 1.0) + rng.uniform(0.5, 2.0), 2)
    shortest = TIME_OPTIMAL[0]
    while guess_peak(plain, shortest) < ROOM * limit:
        shortest /= 2
    return _scene(robot, start, goal, torque_limit=limit,
                  duration={"min": round(shortest, 4), "max": TIME_OPTIMAL[1]},
                  objective={"effort": 1e-2, "time": 1.0})


def _co_designed(rng: np.random.Generator, gravity: float) -> Scene:
    """A `co-design` task (see the module)."""
    robot = _seed_robot(gravity)
    for _ in range(TRIES):
        start, goal = _crossing(rng, robot, 1.0)
        if _co_design_ok(robot, start, goal, MARGIN):
            freq = [SEED_WAVES[j].frequency for j in robot.active]
            return _scene(robot, start, goal, coupling_margin=MARGIN,
                          co_design={"amplitude_max": AMPLITUDE_MAX, "frequency": freq})
    raise RuntimeError("no co-design crossing found")


def _task(category: str, rng: np.random.Generator, gravity: float,
          key: Key | None = None) -> Scene:
    """A task of `category`; `gravity` for the categories that alternate it; `key` (seed,
    index) names a bounds task's stored witness."""
    if category in ("seed-g0-cross", "seed-g9.81-cross"):
        robot = _seed_robot(0.0 if category == "seed-g0-cross" else GRAVITY)
        return _scene(robot, *_crossing(rng, robot, MOVE))
    if category == "seed-swing":
        robot = _seed_robot(GRAVITY)
        joint = int(rng.choice(robot.active))
        q = rng.uniform(-0.8, 0.8, robot.n)
        step = rng.uniform(-0.5, 0.5, robot.n)
        step[joint] = SWING * rng.choice([-1.0, 1.0])
        return _scene(robot, q - step / 2, q + step / 2)
    if category == "links-5to8":
        robot = _random_arm(rng, (5, 8), gravity)
        return _scene(robot, *_moved(rng, robot, LINKS_MOVE))
    if category == "torque-limit":
        return _torque_limited(rng, gravity)
    if category == "free-time":
        robot = _random_arm(rng, (2, 4), gravity)
        start, goal = _moved(rng, robot, 1.0)
        return _scene(robot, start, goal, duration={"min": FREE_TIME[0], "max": FREE_TIME[1]},
                      objective={"effort": 1.0, "time": round(float(rng.uniform(0.5, 5.0)), 3)})
    if category == "tip-target":
        robot = _random_arm(rng, (3, 5), gravity)
        start, goal = rng.uniform(-1.0, 1.0, robot.n), rng.uniform(-1.0, 1.0, robot.n)
        x, y = Dynamics(robot).tips(goal)[-1]
        return _scene(robot, start, goal, tip_target={"x": round(float(x), 6),
                                                      "y": round(float(y), 6)},
                      final={"q": [None] * robot.n, "dq": _rest(robot.n)})
    if category == "bounds":
        robot = _seed_robot(gravity)
        return _bounded(rng, robot, lambda: _crossing(rng, robot, 1.0), key)
    if category == "bounds-5-links":
        robot = _random_arm(rng, (5, 5), gravity)
        return _bounded(rng, robot, lambda: _moved(rng, robot, LINKS_MOVE), key)
    if category == "co-design":
        return _co_designed(rng, gravity)
    raise ValueError(f"unknown category {category!r}")


def _bounded(rng: np.random.Generator, robot: Robot,
             move: Callable[[], tuple[np.ndarray, np.ndarray]],
             key: Key | None) -> Scene:
    """A bounds task of `robot`: a move drawn by `move` until its unbounded plan verifies,
    with position and velocity bounds on about three quarters of the joints from its
    witness (`witnessed`)."""
    for _ in range(WITNESS_TRIES):
        start, goal = move()
        start, goal = np.round(start, 6), np.round(goal, 6)
        bounded = rng.random(robot.n) < 0.75
        bounded[int(rng.integers(robot.n))] = True
        cuts = (float(rng.uniform(*SPEED_CUT)), float(rng.uniform(*EXCURSION_CUT)))
        found = witnessed(robot, start, goal, bounded, cuts, key)
        if found.free is not None:
            position, velocity = bounds_of(start, goal, found.free, bounded,
                                           *(found.scale * c for c in cuts))
            return _scene(robot, start, goal, position_bounds=position,
                          velocity_bounds=velocity)
    raise RuntimeError("no move whose unbounded plan verifies")


# --------------------------------------------------------------------------- witnesses


class Envelope(Record):
    """A plan's range of angles [rad] and largest |rate| [rad/s], per joint: on its dense
    samples and at every interval's exact extrema, as its verification checks bounds."""

    q_min: tuple[float, ...]
    q_max: tuple[float, ...]
    rate_max: tuple[float, ...]

    @model_validator(mode="after")
    def _per_joint(self) -> Envelope:
        if not len(self.q_min) == len(self.q_max) == len(self.rate_max):
            raise ValueError("q_min, q_max and rate_max of different numbers of joints")
        return self

    @classmethod
    def of(cls, plan: Plan) -> Envelope:
        assert plan.states is not None  # a plan of this planner has them
        q_of, dq_of = plan.states.polynomials()
        t = np.asarray(plan.dense.t)
        q_ext, dq_ext = q_of.extrema(), dq_of.extrema()
        q = np.vstack([q_of(t), q_ext.low, q_ext.high])
        rate = np.abs(np.vstack([dq_of(t), dq_ext.low, dq_ext.high]))
        return cls(q_min=tuple(q.min(0).tolist()), q_max=tuple(q.max(0).tolist()),
                   rate_max=tuple(rate.max(0).tolist()))


class Witnessed(Record):
    """What the solves of a bounds task found: the envelope of the unbounded plan of its
    move (`free`; None: that plan did not verify, and the task draws another move), the
    scale of the cuts whose bounds a verified plan keeps (one of CUT_SCALES) and that
    plan's envelope (`witness`; the unbounded plan's own at scale 0), and the Ipopt
    iterations of all those solves."""

    start: tuple[float, ...]
    goal: tuple[float, ...]
    free: Envelope | None
    scale: float
    witness: Envelope | None
    iterations: int

    @model_validator(mode="after")
    def _consistent(self) -> Witnessed:
        joints = {len(self.start), len(self.goal)} | {
            len(e.q_min) for e in (self.free, self.witness) if e is not None}
        if len(joints) > 1:
            raise ValueError("start, goal and envelopes of different numbers of joints")
        if (self.free is None) != (self.witness is None) or self.scale not in CUT_SCALES \
                or self.iterations < 0:
            raise ValueError("a witness without an unbounded plan (or none with one), a scale "
                             "not of CUT_SCALES or negative iterations")
        return self


def bounds_of(start, goal, free: Envelope, bounded, speed_cut: float,
              excursion_cut: float) -> tuple[dict, dict]:
    """Position and velocity bounds (the scene's fields; None on joints not `bounded`) from
    the envelope of an unbounded plan: its peak rate cut by the share `speed_cut`, its
    excursion beyond BOUND_MARGIN around start and goal by the share `excursion_cut`
    (a bound no closer to start and goal than BOUND_MARGIN), rounded outwards to 1e-3."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    q_min, q_max, rate = (np.asarray(v, float) for v in (free.q_min, free.q_max, free.rate_max))
    below = np.minimum(start, goal) - BOUND_MARGIN
    above = np.maximum(start, goal) + BOUND_MARGIN
    lower = np.minimum(below, q_min + excursion_cut * np.maximum(below - q_min, 0.0))
    upper = np.maximum(above, q_max - excursion_cut * np.maximum(q_max - above, 0.0))
    speed = np.maximum((1.0 - speed_cut) * rate, 1e-3)

    def side(values: np.ndarray, up: bool) -> list[float | None]:
        rounded = (np.ceil if up else np.floor)(values * 1e3) / 1e3
        return [round(float(v), 3) if b else None for v, b in zip(rounded, bounded, strict=True)]
    return ({"lower": side(lower, False), "upper": side(upper, True)},
            {"lower": side(-speed, False), "upper": side(speed, True)})


@contextlib.contextmanager
def one_process() -> Iterator[None]:
    """Plans in this process alone: with a companion, which process wins depends on
    timing (docs/planner.md, "Both cores")."""
    from planner.ocp.portfolio import ENVIRONMENT

    saved = os.environ.get(ENVIRONMENT)
    os.environ[ENVIRONMENT] = "1"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(ENVIRONMENT, None)
        else:
            os.environ[ENVIRONMENT] = saved


def _witness(scene: Scene) -> tuple[Envelope | None, int]:
    """The envelope of the scene's plan on WITNESS_INTERVALS intervals in one process
    within WITNESS_WALL_TIME (None unless verified), and its Ipopt iterations."""
    from planner.ocp import plan

    data = scene.model_dump(mode="json")
    data["transcription"]["intervals"] = WITNESS_INTERVALS
    data["solver"]["max_wall_time"] = WITNESS_WALL_TIME
    with one_process():
        found = plan(Scene.model_validate(data))
    ok = found.solver.success and bool(found.verification.verified)
    return (Envelope.of(found) if ok else None), found.solver.iterations


_found: dict[tuple, Witnessed] = {}  # solved in this process, by move, joints and cuts


def stored_witness(key: Key | None, start, goal) -> Witnessed | None:
    """The stored witness of task `key` (seed, index) for this move, if any."""
    return WITNESSES.lookup(key, lambda w: close(w.start, start) and close(w.goal, goal))


def witnessed(robot: Robot, start: np.ndarray, goal: np.ndarray, bounded: np.ndarray,
              cuts: tuple[float, float], key: Key | None = None) -> Witnessed:
    """The witness of a bounds task: the unbounded plan of the move, then plans within the
    bounds of its envelope cut by `cuts` (speed, excursion) times each of CUT_SCALES
    until one verifies (`bounds_of`); stored for the tasks of `key` (seed, index) in
    WITNESS_FILE, else solved (and kept for this process)."""
    found = stored_witness(key, start, goal)
    if found is None:
        memo = (robot.gravity, tuple(start), tuple(goal), tuple(bounded), cuts)
        if memo not in _found:
            _found[memo] = _solve_witness(robot, start, goal, bounded, cuts)
        found = _found[memo]
    WITNESSES.keep(key, found)
    return found


def _solve_witness(robot: Robot, start: np.ndarray, goal: np.ndarray, bounded: np.ndarray,
                   cuts: tuple[float, float]) -> Witnessed:
    ends = {"start": tuple(np.asarray(start).tolist()), "goal": tuple(np.asarray(goal).tolist())}
    free, iterations = _witness(_scene(robot, start, goal))
    if free is None:
        return Witnessed(**ends, free=None, scale=0.0, witness=None, iterations=iterations)
    for scale in CUT_SCALES:
        if scale == 0.0:
            return Witnessed(**ends, free=free, scale=0.0, witness=free, iterations=iterations)
        position, velocity = bounds_of(start, goal, free, bounded, *(scale * c for c in cuts))
        witness, spent = _witness(_scene(robot, start, goal, position_bounds=position,
                                         velocity_bounds=velocity))
        iterations += spent
        if witness is not None:
            return Witnessed(**ends, free=free, scale=scale, witness=witness,
                             iterations=iterations)
    raise AssertionError("CUT_SCALES ends with 0")


def category(name: str) -> str:
    """The category of a task's name."""
    return name.rsplit("-", 1)[0]


def index_of(name: str) -> int:
    """The index a task's random draws come from (seed, index): its number in the suite,
    or for an extra category's task its number past that category's first index."""
    kind, number = category(name), int(name.rsplit("-", 1)[1])
    if kind in EXTRA_CATEGORIES:
        return EXTRA_INDEX * (EXTRA_CATEGORIES.index(kind) + 1) + number
    return number


def hard_task(index: int, seed: int = SEED) -> tuple[str, Scene]:
    """Task `index` of the suite of `seed`, named "<category>-<index>": of category
    CYCLE[index % 12], gravity alternating by round where its category leaves it open."""
    kind = CYCLE[index % len(CYCLE)]
    gravity = GRAVITY if (index // len(CYCLE)) % 2 else 0.0
    rng = np.random.default_rng([seed, index])
    return f"{kind}-{index:02d}", _task(kind, rng, gravity, (seed, index))


def category_task(name: str, number: int, seed: int = SEED) -> tuple[str, Scene]:
    """Task `number` of the extra category `name` (one of EXTRA_CATEGORIES) of `seed`,
    named "<name>-<number>", gravity alternating between 0 and GRAVITY."""
    label = f"{name}-{number:02d}"
    index = index_of(label)
    rng = np.random.default_rng([seed, index])
    return label, _task(name, rng, GRAVITY if number % 2 else 0.0, (seed, index))


def category_tasks(name: str, count: int = EXTRA_COUNT,
                   seed: int = SEED) -> list[tuple[str, Scene]]:
    """`count` tasks of the extra category `name`; task i depends on (seed, i) alone."""
    return [category_task(name, number, seed) for number in range(count)]


def hard_tasks(count: int = COUNT, seed: int = SEED) -> list[tuple[str, Scene]]:
    """`count` tasks named "<category>-<index>"; task i depends on (seed, i) alone, so a
    shorter suite is the start of a longer one."""
    return [hard_task(index, seed) for index in range(count)]


def task_of(key: Key) -> tuple[str, Scene]:
    """The task whose random draws come from `key` (seed, index): of the suite below
    EXTRA_INDEX, of an extra category beyond."""
    seed, index = key
    if index < EXTRA_INDEX:
        return hard_task(index, seed)
    return category_task(EXTRA_CATEGORIES[index // EXTRA_INDEX - 1], index % EXTRA_INDEX, seed)


# --------------------------------------------------------------------------- checks


def check(scene: Scene) -> list[str]:
    """What a scene violates of what can be checked before a solve ([] when nothing): start
    and goal within the position bounds by BOUND_MARGIN / 2 and at rest within the velocity
    bounds, sigma_min(M_pa) at least the margin at the start and the goal (co-design: for
    the robot's own waves), the tip target within reach (no farther than the links' longest
    extent), a torque limit above the holding torque at the start and the goal (and, with a
    free duration, ROOM times the peak torque of the straight move at the longest)."""
    task, robot = scene.task, scene.robot
    start = np.asarray(task.initial.q, float)
    goal = None if any(v is None for v in task.final.q) else np.asarray(task.final.q, float)
    ends = [start] if goal is None else [start, goal]
    problems = []
    if task.position_bounds is not None:
        for q in ends:
            for k, (lo, hi) in enumerate(zip(task.position_bounds.lower,
                                             task.position_bounds.upper, strict=True)):
                if lo is not None and q[k] < lo + BOUND_MARGIN / 2 \
                        or hi is not None and q[k] > hi - BOUND_MARGIN / 2:
                    problems.append(f"joint {k} at {q[k]:g} too close to its position bounds")
    if task.velocity_bounds is not None:
        for k, (lo, hi) in enumerate(zip(task.velocity_bounds.lower,
                                         task.velocity_bounds.upper, strict=True)):
            if lo is not None and lo >= 0.0 or hi is not None and hi <= 0.0:
                problems.append(f"joint {k}: velocity bounds exclude rest")
    if task.coupling_margin is not None:
        sigma = along(robot, np.stack(ends)).sigma_min
        if not np.all(sigma >= task.coupling_margin):
            problems.append(f"sigma_min(M_pa) {sigma.min():g} below the margin")
    if task.tip_target is not None:
        reach = sum(link.length + (link.wave.amplitude if link.wave else 0.0)
                    for link in robot.links)
        if math.hypot(task.tip_target.x, task.tip_target.y) > reach:
            problems.append("tip target out of reach")
    if isinstance(task.torque_limit, float) and robot.gravity > 0.0:
        hold = max(holding_torque(robot, q) for q in ends)
        if task.torque_limit <= hold:
            problems.append(f"torque limit {task.torque_limit:g} below the holding torque")
    if isinstance(task.torque_limit, float) and isinstance(task.duration, DurationRange) \
            and task.torque_limit < ROOM * guess_peak(scene, task.duration.max):
        problems.append(f"torque limit {task.torque_limit:g} below {ROOM:g} times the "
                        "straight move's peak at the longest duration")
    return problems


def crossing_zeros(scene: Scene) -> np.ndarray:
    """Where det M_pa of the scene's arm without waves vanishes on the straight segment from
    start to goal, as fractions of it (None entries of the goal: no segment, empty)."""
    task = scene.task
    if any(v is None for v in task.final.q):
        return np.empty(0)
    start, goal = np.asarray(task.initial.q, float), np.asarray(task.final.q, float)
    zeros = zeros_along(scene.robot.without_waves(),
                        lambda u: start + np.asarray(u)[:, None] * (goal - start),
                        np.linspace(0.0, 1.0, 201))
    return np.empty(0) if zeros is None else zeros


# --------------------------------------------------------------------------- stored witnesses


def witness_keys(seed: int) -> list[Key]:
    """(seed, index) of the tasks of `seed` that draw witnesses: the bounds tasks within
    COUNT and the EXTRA_COUNT of every extra category (each a bounds category)."""
    suite = [(seed, i) for i in range(COUNT) if CYCLE[i % len(CYCLE)] == "bounds"]
    return suite + [(seed, index_of(f"{name}-{number:02d}"))
                    for name in EXTRA_CATEGORIES for number in range(EXTRA_COUNT)]


WITNESS_FILE = DATA / "hard-witnesses.json"
WITNESSES = StoredRecords(
    WITNESS_FILE, Witnessed,
    "What the witness solves of the hard suite's bounds tasks found "
    "(testbed.suites.hard.Witnessed), per task (seed, index), per move its draw tried. "
    "Written by `python -m testbed.suites regenerate --suite hard`; not edited by hand.",
    seeds=(SEED, *HELD_OUT), keys=witness_keys, draw=task_of)
"""The stored witnesses of the bounds tasks of SEED and HELD_OUT within COUNT and
EXTRA_COUNT."""
