"""Wave co-design in the planner: the robot a co-design scene starts from, and the robot a
solution's wave variables describe."""

from __future__ import annotations

import numpy as np

from planner.model import Robot, Wave
from planner.ocp.instance import Instance
from planner.scene import Scene


def design_robot(scene: Scene) -> Robot:
    """The robot whose numbers seed the NLP: co-designed joints get their fixed frequency
    and a starting amplitude [m] of half the bound."""
    co = scene.task.co_design
    if co is None:
        return scene.robot
    waves = {}
    for col, joint in enumerate(scene.robot.active):
        link = scene.robot.links[joint]
        amp = min(co.amplitude_max, 0.95 * link.length) / 2
        phase = link.wave.phase if link.wave is not None else 0.0
        waves[joint] = Wave(amplitude=amp, frequency=co.frequency[col], phase=phase)
    return scene.robot.with_waves(waves)


def solved_robot(inst: Instance, robot: Robot, x: np.ndarray) -> Robot:
    """The robot with the co-designed waves of the solution x (unchanged otherwise)."""
    if not inst.problem.key.codesign:
        return robot
    values = inst.problem.layout.view(x, "wave").ravel()
    amp, phase = values[0::2], values[1::2]
    waves = {}
    for col, joint in enumerate(robot.active):
        wave = robot.links[joint].wave
        if wave is None:
            raise ValueError(f"co-designed joint {joint} has no wave to take its frequency from")
        a = float(np.clip(amp[col], 0.0, 0.95 * robot.links[joint].length))
        waves[joint] = Wave(amplitude=a, frequency=wave.frequency, phase=float(phase[col]))
    return robot.with_waves(waves)
