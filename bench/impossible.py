"""Impossible tasks: how many end `infeasible`, how soon, and within what share of the budget.

Eight tasks that cannot be done, on 2- and 3-link arms moving 0.5 rad per joint, g = 0,
default settings (60 s budget): three that the checks before a solve see (a tip target
beyond reach, a zero torque limit on a 3-link arm, velocity bounds that cannot cover the
move) and five durations below the minimum under a torque limit (2 and 3 links, fully
actuated and with a passive first joint, and a duration range). Reported per task: the
outcome, whether it says `infeasible` (`plan.infeasibility` set), wall time, and that time
as a share of the budget.

    python -m bench impossible
"""

from __future__ import annotations

import time
from typing import Any

from bench import harness
from planner.ocp import plan
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Impossible tasks: said infeasible, and how soon"
BUDGET = 60.0  # [s] the default solver.max_wall_time


def _arm(n: int, passive_first: bool) -> dict[str, Any]:
    lengths, masses = (0.5, 0.4, 0.3)[:n], (1.0, 0.8, 0.6)[:n]
    return {"links": [{"length": length, "mass": mass, "inertia": 0.01,
                       "joint": "passive" if passive_first and k == 0 else "active"}
                      for k, (length, mass) in enumerate(zip(lengths, masses, strict=True))],
            "gravity": 0.0}


def _scene(n: int, passive_first: bool, duration: Any, **task: Any) -> Scene:
    rest = [0.0] * n
    return Scene.model_validate({"robot": _arm(n, passive_first), "task": {
        "duration": duration, "initial": {"q": rest, "dq": rest},
        "final": {"q": [0.5] * n, "dq": rest}, **task}})


def tasks() -> list[tuple[str, Scene]]:
    """The eight impossible tasks, named."""
    return [
        ("tip beyond reach", _scene(2, False, 2.0, final={"q": [None, None], "dq": [0, 0]},
                                    tip_target={"x": 2.0, "y": 0.0})),
        ("zero torque, 3 links", _scene(3, False, 2.0, torque_limit=0.0)),
        ("velocity bounds too tight", _scene(2, False, 1.0, velocity_bounds={
            "lower": [-0.1, -0.1], "upper": [0.1, 0.1]})),
        ("2 links actuated, 0.3 s, 1 N m", _scene(2, False, 0.3, torque_limit=1.0)),
        ("2 links passive first, 0.15 s, 1 N m", _scene(2, True, 0.15, torque_limit=1.0)),
        ("3 links actuated, 0.3 s, 2 N m", _scene(3, False, 0.3, torque_limit=2.0)),
        ("3 links passive first, 0.2 s, 1 N m", _scene(3, True, 0.2, torque_limit=1.0)),
        ("2 links actuated, 0.1 to 0.2 s, 1 N m",
         _scene(2, False, {"min": 0.1, "max": 0.2}, torque_limit=1.0,
                objective={"effort": 1.0, "time": 1.0})),
    ]


def main(argv: list[str]) -> int:
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for name, scene in tasks():
        cpu = harness.cpu_time()
        wall = time.perf_counter()
        result = plan(scene)
        wall, cpu = time.perf_counter() - wall, harness.cpu_time() - cpu
        named = result.infeasibility is not None
        rows.append({"task": name, "status": result.solver.status,
                     "infeasible": "yes" if named else "no", "time": wall, "cpu": cpu,
                     "budget_share": wall / BUDGET,
                     "within_quarter": "yes" if named and wall <= BUDGET / 4 else "no"})
        print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "impossible.csv", rows)
    said = sum(r["infeasible"] == "yes" for r in rows)
    quick = sum(r["within_quarter"] == "yes" for r in rows)
    text = "\n\n".join([
        f"Eight tasks that cannot be done (bench/impossible.py), default settings and a "
        f"{BUDGET:g} s budget, one plan each in one process. {said} of {len(rows)} end "
        f"`infeasible`, {quick} of them within a quarter of the budget.",
        harness.table(rows, [("task", "task"), ("status", "status"),
                             ("infeasible", "said infeasible"), ("time", "wall [s]"),
                             ("cpu", "CPU [s]"), ("budget_share", "share of the budget"),
                             ("within_quarter", "infeasible within a quarter")]),
        f"Rows: `bench/results/impossible.csv`. "
        f"{harness.manifest('impossible', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
