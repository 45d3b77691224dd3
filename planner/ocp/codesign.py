"""Wave co-design in the planner: the robot a co-design scene starts from, the robot a
solution's wave variables describe, and the designed waves' coupling margin proven along
the plan."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from planner import coupling_block
from planner.certify import PROOF_RTOL, Bound, CouplingCertificate, decide, path
from planner.model import Robot, Wave
from planner.ocp.instance import Instance
from planner.scene import Scene

if TYPE_CHECKING:
    from planner.ocp.result import Plan

MARGIN_SLACK = 1e-3
"""The proof's target is the task's coupling margin (1 - MARGIN_SLACK): the NLP holds the
margin at its knots only to Ipopt's tolerance, and a margin that binds there would
otherwise be refuted by rounding."""


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


def certificate(scene: Scene, plan: Plan, times: np.ndarray,
                deadline: float | None = None) -> CouplingCertificate | None:
    """The co-designed waves' sigma_min(M_pa) proven along the plan's angle polynomials
    (`plan.states`), interval by interval, against the task's coupling margin; sampled
    at `times` (K,) [s] too. None without co-design, a margin or a passive joint. Past
    `deadline` (time.perf_counter() seconds) the intervals left are undecided."""
    margin = scene.task.coupling_margin
    if scene.task.co_design is None or margin is None or not scene.robot.passive:
        return None
    robot, q = plan.robot_of(scene.robot), plan.interpolant().q
    until = None if deadline is None else time.monotonic() + deadline - time.perf_counter()

    def run(target: float | None) -> Bound:
        return path(robot, q, target=target, rtol=PROOF_RTOL, deadline=until)
    sampled = float(coupling_block.along(robot, q(times)).least.min())
    return decide(run, margin * (1.0 - MARGIN_SLACK), sampled)
