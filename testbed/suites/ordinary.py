"""A generated suite of ordinary planning tasks, the measure of how often plans verify.

Rest-to-rest tasks of underactuated arms drawn from a fixed seed: 2, 3 and 4 links with
every passive/active split that has at least as many active as passive joints and at
least one passive joint; random lengths, masses and inertias; a wave on about half of
the active joints; a horizontal (g = 0) and a vertical (g = 9.81) plane in turn. Where
the waveless coupling block M_pa is square, the move of up to MOVE rad per joint crosses
one of its singular configurations (det M_pa = 0, found by root finding along an active
joint) at its midpoint; elsewhere it starts and ends at random. Duration 2 s, |tau| <= 20
N m, effort objective, every other setting the scene's default.

    tasks(count, seed) -> list of (name, Scene)
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from planner.coupling_block import sweep, zeros_along
from planner.model import Robot
from planner.scene import Scene

SEED = 20261123
COUNT = 48
MOVE = 0.6  # [rad] largest move of a joint
DURATION = 2.0  # [s]
TORQUE_LIMIT = 20.0  # [N m]


def splits(n: int) -> list[str]:
    """Joint kinds (P passive, A active) of n links with 1 <= passive <= active."""
    return ["".join(kinds) for kinds in itertools.product("PA", repeat=n)
            if 1 <= kinds.count("P") <= kinds.count("A")]


def random_robot(rng: np.random.Generator, kinds: str, gravity: float) -> Robot:
    """Links of the given joint kinds (P passive, A active) with random lengths, masses and
    inertias, a wave on about half of the active joints."""
    links = []
    for kind in kinds:
        length, mass = rng.uniform(0.3, 0.6), rng.uniform(0.4, 1.2)
        link: dict[str, Any] = {
            "length": round(length, 3), "mass": round(mass, 3),
            "inertia": round(mass * length**2 / 12 * rng.uniform(0.5, 1.5), 5),
            "joint": "active" if kind == "A" else "passive"}
        if kind == "A" and rng.random() < 0.5:
            link["wave"] = {"amplitude": round(rng.uniform(0.02, 0.06), 3),
                            "frequency": float(rng.integers(2, 5)),
                            "phase": round(rng.uniform(-math.pi, math.pi), 3)}
        links.append(link)
    return Robot.model_validate({"links": links, "gravity": gravity})


def singular_configuration(robot: Robot, rng: np.random.Generator,
                           tries: int = 20) -> np.ndarray | None:
    """A configuration where the waveless M_pa of a square block is singular, or None: a
    random configuration with one active joint moved to the nearest zero of det M_pa
    within pi of it."""
    if len(robot.passive) != len(robot.active):
        return None
    waveless = robot.without_waves()
    for _ in range(tries):
        q = rng.uniform(-1.0, 1.0, robot.n)
        joint = int(rng.choice(robot.active))
        grid = np.linspace(q[joint] - math.pi, q[joint] + math.pi, 73)
        zeros = zeros_along(waveless, sweep(q, joint), grid)
        if zeros is not None and zeros.size:
            q[joint] = zeros[np.argmin(np.abs(zeros - q[joint]))]
            return q
    return None


def _task(rng: np.random.Generator, robot: Robot) -> tuple[np.ndarray, np.ndarray, bool]:
    """Start and goal angles, and whether their straight path crosses a waveless singularity."""
    move = rng.uniform(-MOVE, MOVE, robot.n)
    centre = singular_configuration(robot, rng)
    crossing = centre is not None
    if centre is None:
        centre = rng.uniform(-0.8, 0.8, robot.n)
    return centre - move / 2, centre + move / 2, crossing


def tasks(count: int = COUNT, seed: int = SEED) -> list[tuple[str, Scene]]:
    """`count` tasks named "<links>-<split>-g<gravity>-<index>"."""
    rng = np.random.default_rng(seed)
    kinds = [(n, split) for n in (2, 3, 4) for split in splits(n)]
    out = []
    for index in range(count):
        n, split = kinds[index % len(kinds)]
        gravity = 0.0 if index % 2 == 0 else 9.81
        robot = random_robot(rng, split, gravity)
        start, goal, crossing = _task(rng, robot)
        rest = [0.0] * n
        scene = Scene.model_validate({
            "robot": robot.model_dump(mode="json"),
            "task": {"duration": DURATION, "initial": {"q": start.round(6).tolist(), "dq": rest},
                     "final": {"q": goal.round(6).tolist(), "dq": rest},
                     "torque_limit": TORQUE_LIMIT, "objective": {"effort": 1.0}}})
        name = f"{n}-{split}-g{gravity:g}-{'x' if crossing else 'r'}{index:02d}"
        out.append((name, scene))
    return out
