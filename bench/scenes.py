"""The reference scenes of the benchmarks, by name; robots from `planner.examples`.

- "seed-hang": the seed's 4-link arm (`planner.examples.VERTICAL_SEED_ARM`: passive joints
  0 and 2, waves on 1 and 3, g = 9.81) with its passive links hanging at rest (q = 0),
  active link 1 swung in 1.6 s from 1.45 to 1.70 rad across the horizontal, where the
  waveless M_pa is singular, link 3 at -0.8 rad; coupling margin 0.005, effort objective
  (the built-in example `seed-arm-plan`, whose transcription the benches set themselves);
- "seed-4": the same arm in a horizontal plane (g = 0), rest to rest in 4 s between two
  configurations whose straight path crosses waveless coupling singularities, coupling
  margin 0.02, effort objective. Without gravity the passive base keeps the arm's angular
  momentum at zero, so every net turn of it needs a loop of the other joints: a far
  harder NLP;
- "arm-2": the planner's two-link arm (`planner.examples.PLAN_ARM`) with both joints
  active and g = 9.81, 1 s from (0, 0.5) to (0.6, 1.2) rad;
- "under-2": `planner.examples.PLAN_ARM` itself (passive shoulder, g = 0), rest to rest in
  2 s from (0, 0.5) to (0.3, 1.0) rad. (The 1 s task of arm-2 needs the passive shoulder
  to swing fast, and Ipopt then ends in a different local optimum at every N.)
"""

from __future__ import annotations

import copy
from typing import Any

from planner.examples import PLAN_ARM, VERTICAL_SEED_ARM, example
from planner.scene import DurationRange, Scene

UNDERACTUATED = PLAN_ARM
"""Two links, passive shoulder, wavy active elbow; g = 0."""
ARM = {**PLAN_ARM, "links": [{**PLAN_ARM["links"][0], "joint": "active"}, PLAN_ARM["links"][1]],
       "gravity": 9.81}
"""`UNDERACTUATED` with the shoulder active, under gravity."""
SEED_TASK: dict[str, Any] = {"duration": 4.0,
             "initial": {"q": [0.766, -1.157, -1.148, -1.287], "dq": [0.0] * 4},
             "final": {"q": [0.676, -0.67, -1.306, -1.202], "dq": [0.0] * 4},
             "coupling_margin": 0.02, "objective": {"effort": 1.0}}
TWO_LINK_TASK: dict[str, Any] = {"duration": 1.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
                 "final": {"q": [0.6, 1.2], "dq": [0.0, 0.0]}}
UNDER_TASK = {"duration": 2.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
              "final": {"q": [0.3, 1.0], "dq": [0.0, 0.0]}}
HANGING = example("seed-arm-plan").request

ROBOTS = {"seed-4": {**VERTICAL_SEED_ARM, "gravity": 0.0}, "seed-hang": HANGING["robot"],
          "arm-2": ARM, "under-2": UNDERACTUATED}
TASKS = {"seed-4": SEED_TASK, "seed-hang": HANGING["task"], "arm-2": TWO_LINK_TASK,
         "under-2": UNDER_TASK}
ONE_SOLVE = ({"refinement": {"enabled": False}}, {"retries": 0})
"""Transcription and solver settings that make a plan one Ipopt solve on the scene's own
mesh (no mesh refinement, no retries): what a benchmark of one NLP measures."""


def request(name: str, method: str = "legendre", N: int = 50, degree: int = 3,
            solver: dict | None = None, one_solve: bool = False, **transcription) -> dict:
    """The plan request of the named reference scene with a transcription (`method` on N
    intervals, collocation `degree`, further transcription fields) and solver settings;
    `one_solve`: refinement and retries off (`ONE_SOLVE`)."""
    transcription = {"method": method, "intervals": N, "degree": degree, **transcription}
    solver = dict(solver or {})
    if one_solve:
        transcription.update(ONE_SOLVE[0])
        solver.update(ONE_SOLVE[1])
    return copy.deepcopy({"robot": ROBOTS[name], "task": TASKS[name],
                          "transcription": transcription, "solver": solver})


def make_scene(name: str, method: str = "legendre", N: int = 50, degree: int = 3,
               solver: dict | None = None, one_solve: bool = False, **transcription) -> Scene:
    """The named reference scene ("seed-hang", "seed-4", "arm-2", "under-2"), as `request`."""
    return Scene.model_validate(request(name, method, N, degree, solver, one_solve,
                                        **transcription))


def fixed_duration(scene: Scene) -> float:
    """The scene's duration T [s]: the peers solve fixed-duration tasks only."""
    duration = scene.task.duration
    if isinstance(duration, DurationRange):
        raise ValueError("the peers solve fixed-duration scenes only (got a duration range)")
    return float(duration)
