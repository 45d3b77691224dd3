"""A reserve above the coupling margin for the NLP, once a plan's margin dips between knots.

The NLP holds sigma_least(M_pa) >= m at its knots, and an optimum that needs the margin
rides it: between the knots sigma_least dips, and where the dip exceeds the proof's
tolerance (`planner.ocp.margin_proof.MARGIN_RTOL`) the plan is not verified. Cutting those
intervals only moves the dip (the next optimum rides the margin at the new knots, and a
solve on a new mesh may wander to another optimum), so an accurate plan whose margin is
not proven is solved again on its own mesh, from its own solution, with its knots held at
m (1 + r): r at least RESERVE, twice the relative dip seen and twice the reserve before,
up to MAX_RESERVE. Its plans are still verified against m itself.

The held margin never exceeds the sigma_least of the task's fixed end states, so that it
cannot make the NLP infeasible at its ends (co-design excepted: its waves move those
values); where the ends leave no room above m, the mesh is cut as before
(`planner.ocp.refine`).
"""

from __future__ import annotations

import numpy as np

from planner.model import Robot
from planner.ocp.margin_proof import MarginProof
from planner.ocp.verify import coupling_along
from planner.scene import Scene, Task

RESERVE = 5e-3
"""The least relative reserve: five times the proof's tolerance, the dip of a binding
margin on a mesh about twice as coarse as the one whose dip the tolerance absorbs."""
MAX_RESERVE = 0.5
"""The largest relative reserve: past it, the knots are too far apart for the margin's
shape (sigma_least turns sharply near a waveless singularity), and the mesh is cut."""
END_ROOM = 1.0 - 1e-6
"""A fixed end state keeps this share of its own sigma_least as room for the reserve."""


def next_reserve(proof: MarginProof, previous: float) -> float | None:
    """The relative reserve for the pass after a plan whose margin `proof` failed, after a
    reserve of `previous` (0 for none): at least RESERVE, twice the plan's deepest sampled
    dip below the margin, and twice `previous`; None above MAX_RESERVE (the mesh is cut
    instead)."""
    unproven = np.flatnonzero(proof.unproven())
    deepest = min((proof.bounds[k].sampled for k in unproven), default=proof.margin)
    dip = max(0.0, 1.0 - deepest / proof.margin) if np.isfinite(deepest) else 0.0
    reserve = max(RESERVE, 2.0 * dip, 2.0 * previous)
    return reserve if reserve <= MAX_RESERVE else None


def reserved_margin(task: Task, robot: Robot, reserve: float) -> float | None:
    """The margin [kg m^2] the NLP holds at its knots with a relative `reserve`, capped by
    the sigma_least of the task's fixed end states for `robot` (not with co-design); None
    when the task has no margin or those ends leave no room above it."""
    margin = task.coupling_margin
    if margin is None:
        return None
    fixed = task.co_design is None
    ends = [state.q for state in (task.initial, task.final) if fixed and None not in state.q]
    sigma = coupling_along(robot, np.array(ends, float))[0] if ends else np.array([np.inf])
    room = float(np.min(np.nan_to_num(sigma, nan=0.0))) * END_ROOM
    held = min(margin * (1.0 + reserve), room)
    return held if held > margin else None


def with_margin(scene: Scene, margin: float | None) -> Scene:
    """The scene whose NLP holds `margin` at its knots (None: the scene itself); its plans
    are still verified against the scene's own margin."""
    if margin is None:
        return scene
    return scene.model_copy(update={
        "task": scene.task.model_copy(update={"coupling_margin": margin})})
