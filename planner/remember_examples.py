"""Plan the built-in plan examples and store their motions for the planner's memory
(`planner.ocp.recall`): run after an example's request changes.

    python -m planner.remember_examples
"""

from __future__ import annotations

from pathlib import Path

from planner.examples import examples
from planner.ocp import plan
from planner.ocp.recall import FOLDER, Motion, digest
from planner.scene import Scene


def write() -> list[Path]:
    """Plan every plan example with its own settings and store its motion."""
    FOLDER.mkdir(exist_ok=True)
    written = []
    for example in (e for e in examples() if e.kind == "plan"):
        result = plan(Scene.model_validate(example.request))
        if result.status != "verified" or result.torque is None:
            raise RuntimeError(f"{example.name}: its plan is {result.status}")
        motion = Motion(example=example.name, digest=digest(example.request),
                        duration=result.duration, t=result.t, q=result.q, dq=result.dq,
                        ddq=result.ddq, tau=result.tau, torque=result.torque)
        path = FOLDER / f"{example.name}.json"
        path.write_text(motion.model_dump_json() + "\n")
        written.append(path)
    return written


if __name__ == "__main__":
    for path in write():
        print(path)
