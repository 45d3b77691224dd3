"""Built-in scenes: ready-to-post requests for the service's endpoints.

Two arms start their prescribed passive motion at a configuration where the waveless
coupling block M_pa is exactly singular (the active angle solves det M_pa = 0):

- `two_link`: passive shoulder, active elbow, horizontal plane (g = 0).
- `seed_arm`: the seed paper's 4-link arm, passive joints 0 and 2, active 1 and 3,
  horizontal plane (g = 0).

Two plans (kind "plan") cross a waveless singularity: the two-link arm in a horizontal
plane, and the seed's arm in a vertical one (`VERTICAL_SEED_ARM`) with its passive links
hanging at rest.

For each: the waveless inverse dynamics (it stops at once), the wave design along the
motion, and the inverse dynamics with the designed waves (it completes). The designed
waves below are the output of `planner.waves.design` on the wave-design example, rounded
to 8 digits (`tests/test_waves.py` re-derives them).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from planner.coupling_block import sweep, zeros_along
from planner.model import Robot, Wave

Kind = Literal["inverse-dynamics", "wave-design", "coupling", "plan"]


class Example(BaseModel):
    """A named request for the endpoint of its kind."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    title: str
    description: str
    kind: Kind
    request: dict[str, Any]


# --------------------------------------------------------------------------- the arms

TWO_LINK_WAVE = Wave(amplitude=0.06, frequency=3, phase=-2.1883119)
"""Designed wave of the two-link arm's elbow (joint 1)."""
SEED_WAVES = {1: Wave(amplitude=0.06, frequency=4, phase=-2.8508593),
              3: Wave(amplitude=0.06, frequency=4, phase=0.23561034)}
"""Designed waves of the seed arm's active joints 1 and 3."""

DURATION = 2.0
"""Duration of both prescribed motions [s]."""
MARGIN = 0.02
"""Required sigma_min(M_pa) of both wave designs [kg m^2]."""
AMPLITUDE_MAX = 0.06
FREQUENCY_MAX = 4
SAMPLES = 401
SIGMA_THRESHOLD = 1e-3

TWO_LINK_PASSIVE = ([0.0], [0.6])
"""Passive shoulder angle at the start and the end [rad]."""
SEED_PASSIVE = ([0.2, -0.6], [0.3, -0.5])
"""Passive angles (joints 0, 2) at the start and the end [rad]."""
SEED_ACTIVE_GUESS = (0.8, -2.4)
"""Joint 1's start angle and a guess of joint 3's singular angle [rad]."""


def two_link(waves: bool) -> Robot:
    """Two links, passive shoulder, active elbow; g = 0. With `waves`, the designed wave."""
    links = [
        {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
         "wave": TWO_LINK_WAVE.model_dump() if waves else None},
    ]
    return Robot.model_validate({"links": links, "gravity": 0.0})


def seed_arm(waves: bool) -> Robot:
    """The seed's 4-link arm: lengths 0.5, 0.4, 0.4, 0.3 m, masses 1.0, 0.8, 0.6, 0.4 kg,
    inertias 0.01, 0.008, 0.006, 0.004 kg m^2, passive 0 and 2, active 1 and 3; g = 0."""
    lengths, masses = (0.5, 0.4, 0.4, 0.3), (1.0, 0.8, 0.6, 0.4)
    inertias = (0.01, 0.008, 0.006, 0.004)
    links = []
    for i, (length, mass, inertia) in enumerate(zip(lengths, masses, inertias, strict=True)):
        wave = SEED_WAVES.get(i) if waves else None
        links.append({"length": length, "mass": mass, "inertia": inertia,
                      "joint": "active" if i % 2 else "passive",
                      "wave": wave.model_dump() if wave else None})
    return Robot.model_validate({"links": links, "gravity": 0.0})


def _singular_angle(robot: Robot, q: list[float], joint: int, guess: float,
                    width: float = 0.5) -> float:
    """The first angle of `joint` [rad] within `width` of `guess` where det M_pa = 0, the
    other joints at q (to machine precision)."""
    u = np.linspace(guess - width, guess + width, 201)
    roots = zeros_along(robot, sweep(q, joint), u)
    if roots is None:
        raise ValueError("det M_pa needs a square coupling block")
    return float(roots[0])


@lru_cache(maxsize=1)
def two_link_start() -> list[float]:
    """Start configuration of the two-link arm: det M_pa = 0 without the wave [rad]."""
    q0 = TWO_LINK_PASSIVE[0][0]
    return [q0, _singular_angle(two_link(False), [q0, 0.0], 1, 1.6)]


@lru_cache(maxsize=1)
def seed_start() -> list[float]:
    """Start configuration of the seed arm: det M_pa = 0 without waves [rad]."""
    (q0, q2), (q1, guess) = SEED_PASSIVE[0], SEED_ACTIVE_GUESS
    return [q0, q1, q2, _singular_angle(seed_arm(False), [q0, q1, q2, 0.0], 3, guess)]


def seed_crossing() -> tuple[list[float], list[float]]:
    """Two configurations of the seed arm whose straight segment crosses det M_pa = 0
    (waveless): the singular start moved by -/+ (0.1, 0.2, 0.1, 0.3) rad."""
    q = np.array(seed_start())
    step = np.array([0.1, 0.2, 0.1, 0.3])
    return (q - step).tolist(), (q + step).tolist()


# --------------------------------------------------------------------------- requests


def _motion(robot: Robot, passive: tuple[list[float], list[float]],
            start: list[float]) -> dict[str, Any]:
    active = robot.active
    return {"passive_motion": {"profile": "beta", "alpha": 3.0, "beta": 3.0,
                               "start": passive[0], "end": passive[1]},
            "duration": DURATION,
            "active_initial": {"q": [start[j] for j in active], "dq": [0.0] * len(active)}}


def _inverse(robot: Robot, passive, start) -> dict[str, Any]:
    return {"robot": robot.model_dump(mode="json"), **_motion(robot, passive, start),
            "samples": SAMPLES, "sigma_threshold": SIGMA_THRESHOLD}


def _design(robot: Robot, passive, start) -> dict[str, Any]:
    return {"robot": robot.model_dump(mode="json"), "amplitude_max": AMPLITUDE_MAX,
            "frequency_max": FREQUENCY_MAX, "margin": MARGIN,
            "motion": _motion(robot, passive, start)}


def _trio(key: str, label: str, arm, passive, start) -> list[Example]:
    """Waveless inverse dynamics, wave design, and inverse dynamics with the waves."""
    plain, wavy = arm(False), arm(True)
    return [
        Example(name=f"{key}-waveless", title=f"{label}: waveless inverse dynamics",
                description="The prescribed passive motion starts where det M_pa = 0; "
                            "the classical inverse dynamics stops at once.",
                kind="inverse-dynamics", request=_inverse(plain, passive, start)),
        Example(name=f"{key}-wave-design", title=f"{label}: wave design along the motion",
                description=f"Waves with amplitude <= {AMPLITUDE_MAX} m and frequency <= "
                            f"{FREQUENCY_MAX} that keep sigma_min(M_pa) >= {MARGIN} "
                            "along the motion the inverse dynamics produces.",
                kind="wave-design", request=_design(plain, passive, start)),
        Example(name=f"{key}-waves", title=f"{label}: inverse dynamics with designed waves",
                description="The same motion with the designed waves: it completes, with "
                            f"sigma_min(M_pa) above {MARGIN} throughout.",
                kind="inverse-dynamics", request=_inverse(wavy, passive, start)),
    ]


def _coupling_examples() -> list[Example]:
    start = two_link_start()
    a, b = seed_crossing()
    return [
        Example(name="two-link-coupling-map", title="Two-link arm: det M_pa map",
                description="det M_pa of the waveless two-link arm over a box around the "
                            "singular start; singular points refined on the grid edges.",
                kind="coupling",
                request={"robot": two_link(False).model_dump(mode="json"),
                         "grid": {"lower": [-0.5, start[1] - 0.5],
                                  "upper": [0.5, start[1] + 0.5], "points": 41},
                         "threshold": SIGMA_THRESHOLD}),
        Example(name="seed-arm-coupling-crossing", title="Seed arm: a path across a singularity",
                description="The straight path between the two configurations of "
                            "seed_crossing() crosses det M_pa = 0 (waveless).",
                kind="coupling",
                request={"robot": seed_arm(False).model_dump(mode="json"),
                         "configurations": [(np.array(a) + u * (np.array(b) - np.array(a)))
                                            .tolist() for u in np.linspace(0.0, 1.0, 21)],
                         "threshold": SIGMA_THRESHOLD}),
    ]


VERTICAL_SEED_ARM: dict[str, Any] = {
    "links": [
        {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
         "wave": {"amplitude": 0.05, "frequency": 3.0, "phase": 0.3}},
        {"length": 0.4, "mass": 0.6, "inertia": 0.006, "joint": "passive"},
        {"length": 0.3, "mass": 0.4, "inertia": 0.004, "joint": "active",
         "wave": {"amplitude": 0.04, "frequency": 4.0, "phase": 0.1}},
    ],
    "gravity": 9.81,
    "rotational_inertia": "cumulative",
}
"""The seed's 4-link arm in a vertical plane, waves on its active joints 1 and 3: the arm of
the seed-arm plan, of the tests of the seed's printed equations and of the benches (the
seed's excerpt gives no numbers)."""

PLAN_ARM: dict[str, Any] = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 0.0}
"""Two links, passive shoulder, wavy active elbow; g = 0 (the planner's test arm)."""


_HORIZONTAL_PLAN: dict[str, Any] = {
    "robot": {**VERTICAL_SEED_ARM, "gravity": 0.0},
    "task": {"duration": 2.0,
             "initial": {"q": [-0.48, 1.22, 0.02, -1.47], "dq": [0.0] * 4},
             "final": {"q": [0.18, 2.19, -1.03, -0.45], "dq": [0.0] * 4},
             "objective": {"effort": 1.0}},
    "transcription": {"method": "legendre", "intervals": 50, "degree": 3},
    "solver": {"max_iter": 1000, "max_wall_time": 60.0},
}
"""The seed arm in a horizontal plane: without gravity a passive joint turns only by the
coupling to the active ones (the passive base keeps the angular momentum at zero), and
the waveless det M_pa changes sign on the way; the hard suite's kind of task
("seed-g0-cross", docs/benchmarks.md, "The hard suite"), verified in about 60 iterations."""

_HANGING_PLAN: dict[str, Any] = {
    "robot": VERTICAL_SEED_ARM,
    "task": {"duration": 1.6, "initial": {"q": [0.0, 1.45, 0.0, -0.8], "dq": [0.0] * 4},
             "final": {"q": [0.0, 1.70, 0.0, -0.8], "dq": [0.0] * 4},
             "coupling_margin": 0.005, "objective": {"effort": 1.0}},
    "transcription": {"method": "legendre", "intervals": 50, "degree": 3},
    "solver": {"max_iter": 1000, "max_wall_time": 60.0},
}
"""The seed arm's: with q0 = q2 = 0 the waveless M_01 and M_21 go as cos(q1), so det M_pa
changes sign where link 1 is horizontal; gravity holds the passive links near rest and
Ipopt converges in about ten iterations (docs/benchmarks.md, "seed-hang")."""

_CROSSING_PLAN: dict[str, Any] = {
    "robot": PLAN_ARM,
    "task": {"duration": 2.0, "initial": {"q": [0.0, 0.8], "dq": [0.0, 0.0]},
             "final": {"q": [0.0, 1.75], "dq": [0.0, 0.0]}, "coupling_margin": 0.01,
             "objective": {"effort": 1.0}},
    "transcription": {"method": "legendre", "intervals": 40, "degree": 3},
    "solver": {"max_iter": 1000, "max_wall_time": 60.0},
}
"""The two-link arm's starts and ends at rest; without the wave
M_pa = I2 + m2 l1 l2 cos(q0 - q1) changes sign between the two configurations, with it
the determinant keeps its sign. With a passive shoulder, g = 0 and the margin, nearby end
states lead Ipopt to spurious local optima (docs/planner.md, "Passive joints and the
coupling margin"); this one converges to a verified plan in under a hundred iterations."""


def _plan_examples() -> list[Example]:
    """Optimal-control plans (kind "plan", scenes for planner.ocp.plan), the headline first."""
    return [
        Example(name="seed-arm-horizontal-plan",
                title="Seed arm, horizontal plane: across a waveless singularity",
                description="The seed's 4-link arm in a horizontal plane (g = 0), passive "
                            "links 0 and 2: with no gravity, the passive joints move only "
                            "through the inertial coupling, and the motion between these rest "
                            "states crosses a configuration where the waveless M_pa is "
                            "singular, which the classical inverse dynamics cannot pass. The "
                            "planner never inverts M_pa; the result lists the crossings and "
                            "sigma_min(M_pa) with and without the waves along the plan.",
                kind="plan", request=_HORIZONTAL_PLAN),
        Example(name="seed-arm-plan", title="Seed arm: rest to rest through a singularity",
                description="The seed's 4-link arm in a vertical plane, its passive links 0 "
                            "and 2 hanging at rest: active link 1 swings across the "
                            "horizontal, where the waveless coupling is singular, keeping "
                            "sigma_min(M_pa) >= 0.005; the passive links come back to rest.",
                kind="plan", request=_HANGING_PLAN),
        Example(name="two-link-plan", title="Two-link arm: rest to rest through a singularity",
                description="Feed-forward torques that move a passive shoulder and a wavy elbow "
                            "through configurations where the waveless coupling is singular, "
                            "keeping sigma_min(M_pa) >= 0.01; the result lists the crossings.",
                kind="plan", request=_CROSSING_PLAN),
    ]


def examples() -> list[Example]:
    """Every built-in example."""
    return [
        *_plan_examples(),
        *_trio("two-link", "Two-link arm", two_link, TWO_LINK_PASSIVE, two_link_start()),
        *_trio("seed-arm", "Seed 4-link arm", seed_arm, SEED_PASSIVE, seed_start()),
        *_coupling_examples(),
    ]


def example(name: str) -> Example:
    """The example called `name`; KeyError lists the known names."""
    for item in examples():
        if item.name == name:
            return item
    raise KeyError(f"no example called {name!r}; known: "
                   + ", ".join(item.name for item in examples()))
