"""A continuation start for underactuated tasks: from fully actuated to the task's own arm.

The relaxed NLP gives every passive joint a virtual torque, priced in the effort term at a
weight that grows from solve to solve (`VIRTUAL_WEIGHTS`), so that the relaxed optimum
moves towards one that needs no virtual torque. Its first solve starts from the
interpolation with the torques of every row of the equations of motion, which satisfies
the dynamics: there is none of the infeasibility that makes Ipopt take tiny steps near a
coupling singularity. Each later solve starts from the one before, primal and dual. The
last relaxed plan, its virtual torques dropped, is the initial guess of the task's NLP.
"""

from __future__ import annotations

import numpy as np

from planner.model import Robot
from planner.ocp.guess import Guess, hermite_guess, interpolant_guess
from planner.ocp.solvers import SOLVERS
from planner.ocp.transcription import Interpolant
from planner.scene import Scene

VIRTUAL_WEIGHTS = (1e1, 1e2, 1e3, 1e4, 1e5)
"""Effort weights of the virtual torques, one relaxed solve each, in order."""
NEGLIGIBLE = 1e-6
"""[N m] virtual torques below this everywhere end the continuation early."""


def applies(scene: Scene) -> bool:
    """Whether the task has passive joints and an implicit transcription (the relaxed NLP
    adds its virtual torques to the implicit dynamics rows), and its solver starts from
    given primal and dual values (each relaxed solve from the one before)."""
    tr = scene.transcription
    return bool(scene.robot.passive) and tr.form == "implicit" \
        and tr.method != "multiple-shooting" \
        and SOLVERS[scene.solver.name].warm_options is not None


def relaxed_guess(scene: Scene, robot: Robot, T: float) -> Guess:
    """The interpolation's motion with the torques of all its rows: the active joints',
    then the passive joints' virtual ones (K x n)."""
    return hermite_guess(scene, robot, T, [*robot.active, *robot.passive])


def active_guess(interp: Interpolant, T: float, active: int) -> Guess:
    """A relaxed plan as the guess of the task's NLP: its motion and active torques."""
    full = interpolant_guess(interp, T)

    def guess(x: np.ndarray) -> dict[str, np.ndarray]:
        out = full(x)
        return {**out, "tau": out["tau"][:, :active]}

    return guess


def virtual_peak(interp: Interpolant, active: int) -> float:
    """[N m] the largest virtual torque of a relaxed plan at its breakpoints and between."""
    t = np.linspace(interp.tau.breaks[0], interp.tau.breaks[-1], 4 * len(interp.tau.breaks))
    return float(np.abs(interp.tau(t)[:, active:]).max(initial=0.0))

