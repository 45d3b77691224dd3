"""Robots for tests and benchmarks: random robots and states (seeded by the caller's
generator), and chains of links with their rest-to-rest task."""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.model import Robot
from planner.scene import Scene


def random_robot(rng: np.random.Generator, n: int, *, waves: bool = True,
                 gravity: float | None = None, rotational: str | None = None,
                 inertia: bool = True) -> Robot:
    """A random n-link robot.

    Lengths 0.2..1 m, masses 0.2..2 kg, inertias 0..0.05 kg m^2 (all zero if not
    `inertia`); each joint active with probability 1/2, at least one active; with
    `waves`, every active joint carries a wave of amplitude 0.01..0.3 of its length,
    frequency 1..5 and phase -pi..pi. gravity None draws 0 or 9.81; rotational None
    draws the convention.
    """
    active = rng.random(n) < 0.5
    active[rng.integers(n)] = True
    links = []
    for k in range(n):
        length = float(rng.uniform(0.2, 1.0))
        link: dict[str, Any] = {"length": length, "mass": float(rng.uniform(0.2, 2.0)),
                                "inertia": float(rng.uniform(0.0, 0.05)) if inertia else 0.0,
                                "joint": "active" if active[k] else "passive"}
        if waves and active[k]:
            link["wave"] = {"amplitude": float(rng.uniform(0.01, 0.3)) * length,
                            "frequency": float(rng.uniform(1.0, 5.0)),
                            "phase": float(rng.uniform(-np.pi, np.pi))}
        links.append(link)
    if gravity is None:
        gravity = float(rng.choice([0.0, 9.81]))
    if rotational is None:
        rotational = str(rng.choice(["cumulative", "absolute"]))
    return Robot.model_validate({"links": links, "gravity": gravity,
                                 "rotational_inertia": rotational})


def random_state(rng: np.random.Generator, n: int,
                 speed: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Angles uniform in [-pi, pi] rad and rates uniform in [-speed, speed] rad/s."""
    return rng.uniform(-np.pi, np.pi, n), rng.uniform(-speed, speed, n)


def tip_of(robot: Robot, q: np.ndarray) -> np.ndarray:
    """The last tip [m] (2,), summed link by link from the model's definition, apart from
    the derived kinematics: r_i = l_i + a_i sin(n_i q_i + eps_i) along (cos q_i, sin q_i)."""
    point = np.zeros(2)
    for link, angle in zip(robot.links, q, strict=True):
        wave = link.wave
        r = link.length + (0.0 if wave is None else
                           wave.amplitude * np.sin(wave.frequency * angle + wave.phase))
        point += r * np.array([np.cos(angle), np.sin(angle)])
    return point


def chain(n: int, under: bool, masses: list[float] | None = None,
          lengths: list[float] | None = None, frequency: float = 3.0,
          gravity: float = 9.81) -> dict:
    """n links (0.4 m, 1 kg, I = m l^2 / 50 [kg m^2] unless given); under: even joints
    passive; active odd joints carry a wave of amplitude 0.1 l, `frequency`, phase 0.3."""
    masses = masses or [1.0] * n
    lengths = lengths or [0.4] * n
    links = []
    for k in range(n):
        active = (k % 2 == 1) or not under or n == 1
        link: dict[str, Any] = {"length": lengths[k], "mass": masses[k],
                                "inertia": masses[k] * lengths[k] ** 2 / 50,
                                "joint": "active" if active else "passive"}
        if active and k % 2 == 1:
            link["wave"] = {"amplitude": 0.1 * lengths[k], "frequency": frequency, "phase": 0.3}
        links.append(link)
    return {"links": links, "gravity": gravity}


def chain_scene(links: int, under: bool = True, extra: str = "", solver: dict | None = None,
                **transcription: object) -> Scene:
    """`chain(links, under)` moving every joint +0.5 rad rest to rest in 1 s from
    q_k = 0.1 k rad; `extra` "margin" adds a coupling margin of 1e-3, "co-design" wave
    co-design (amplitudes up to 0.05 m, frequency 3); the transcription's fields as
    keywords, and solver settings."""
    start = [0.1 * k for k in range(links)]
    task: dict = {"duration": 1.0, "initial": {"q": start, "dq": [0.0] * links},
                  "final": {"q": [s + 0.5 for s in start], "dq": [0.0] * links}}
    if extra == "margin":
        task["coupling_margin"] = 1e-3
    elif extra == "co-design":
        task["co_design"] = {"amplitude_max": 0.05, "frequency": [3.0] * (links // 2)}
    return Scene.model_validate({"robot": chain(links, under), "task": task,
                                 "transcription": transcription, "solver": solver or {}})
