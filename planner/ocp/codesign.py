"""Wave co-design in the planner: the robot a co-design scene starts from, and the robot a
solution's wave variables describe."""

from __future__ import annotations

import numpy as np

from planner.model import Robot, Wave
from planner.ocp.instance import Instance
from planner.scene import Scene


def design_robot(scene: Scene) -> Robot:
    """The robot whose numbers seed the NLP: a co-designed joint starts from the arm's own
    wave where it has one of the co-design's frequency (its amplitude [m] within the
    bound), else from half the bound, at its fixed frequency. An arm's own
    design is the better start where it keeps the coupling margin along the straight move,
    as on the hard suite's co-design crossings (docs/benchmarks.md, "Hard suite")."""
    co = scene.task.co_design
    if co is None:
        return scene.robot
    return scene.robot.with_waves({joint: _first_wave(scene.robot.links[joint].wave,
                                                      _bound(scene.robot, joint, co.amplitude_max),
                                                      co.frequency[col])
                                   for col, joint in enumerate(scene.robot.active)})


def _bound(robot: Robot, joint: int, amplitude_max: float) -> float:
    """[m] the largest amplitude the co-design gives `joint`'s wave."""
    return min(amplitude_max, 0.95 * robot.links[joint].length)


def _first_wave(own: Wave | None, bound: float, frequency: float) -> Wave:
    """A co-designed joint's first wave: its own, where of `frequency`, within `bound` [m];
    else half the bound, with its own phase (0 without a wave)."""
    phase = own.phase if own is not None else 0.0
    if own is not None and own.frequency == frequency:
        return Wave(amplitude=min(own.amplitude, bound), frequency=frequency, phase=phase)
    return Wave(amplitude=bound / 2, frequency=frequency, phase=phase)


def solved_robot(inst: Instance, robot: Robot, x: np.ndarray) -> Robot:
    """The robot with the co-designed waves of the solution x (unchanged otherwise)."""
    if not inst.problem.key.codesign:
        return robot
    values = np.asarray(x)[inst.problem.layout.first("wave")]
    amp, phase = values[0::2], values[1::2]
    waves = {}
    for col, joint in enumerate(robot.active):
        wave = robot.links[joint].wave
        if wave is None:
            raise ValueError(f"co-designed joint {joint} has no wave to take its frequency from")
        a = float(np.clip(amp[col], 0.0, 0.95 * robot.links[joint].length))
        waves[joint] = Wave(amplitude=a, frequency=wave.frequency, phase=float(phase[col]))
    return robot.with_waves(waves)
