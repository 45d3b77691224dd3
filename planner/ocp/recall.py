"""The planner's own memory of motion: the built-in plan examples' motions, kept beside the
code, as the first guess of a scene near one of them.

A scene of the same shape as a plan example (`planner.memory.shape`) and within
`planner.memory.REACH` of it (its goal moved by up to 0.05 rad, say), but not the example
itself, starts from the example's motion: its angles, rates and delivered torque
interpolated onto the scene's own mesh (`planner.ocp.starts.warm_starts`). From a
linearly interpolated guess, the two-link example with its goal moved can wander for
thousands of iterations into a wrong family of motions (one of five such goals ended
unverified after 37 s); from the example's motion it converges in tens
(docs/benchmarks.md, "Built-in plan examples with their goals moved").

The motions live in `recalled/<example>.json`, each with the digest of the request it was
planned from; one whose example has changed since is not used (`tests/test_recall.py`
fails then). `python -m planner.remember_examples` plans the examples again and writes
them.
"""

from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

from pydantic import BaseModel, Field

from planner.examples import examples
from planner.memory import REACH, distance
from planner.scene import Scene
from planner.torque import TorquePolynomial

FOLDER = Path(__file__).resolve().parent / "recalled"


class Motion(BaseModel):
    """A plan example's motion: nodes (time-major) and its delivered torque."""

    example: str
    digest: str = Field(description="sha256 of the example's request, as JSON with sorted keys")
    duration: float = Field(description="[s]")
    t: list[float] = Field(description="node times [s]")
    q: list[list[float]] = Field(description="angles at t [rad]")
    dq: list[list[float]] = Field(description="rates at t [rad/s]")
    ddq: list[list[float]] = Field(description="accelerations at t [rad/s^2]")
    tau: list[list[float]] = Field(description="torques at t [N m]")
    torque: TorquePolynomial


def digest(request: dict) -> str:
    """The digest a motion keeps of the request it was planned from."""
    return hashlib.sha256(json.dumps(request, sort_keys=True).encode()).hexdigest()


@lru_cache(maxsize=1)
def motions() -> tuple[tuple[Scene, Motion], ...]:
    """Each plan example's scene and its stored motion, where the motion is of the
    example's request as it is now."""
    found = []
    for example in (e for e in examples() if e.kind == "plan"):
        path = FOLDER / f"{example.name}.json"
        if not path.exists():
            continue
        motion = Motion.model_validate_json(path.read_text())
        if motion.digest == digest(example.request):
            found.append((Scene.model_validate(example.request), motion))
    return tuple(found)


def recall(scene: Scene) -> tuple[Motion, float] | None:
    """The nearest plan example's motion within REACH of the scene and its distance [rad];
    None when none is near, or the scene is an example itself (distance 0)."""
    best: tuple[Motion, float] | None = None
    for example, motion in motions():
        d = distance(scene, example)
        if 0.0 < d <= REACH and (best is None or d < best[1]):
            best = (motion, d)
    return best
