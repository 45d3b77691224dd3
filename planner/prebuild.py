"""Compiled kernels built ahead of need: those of the built-in plan examples, so that
their first requests run compiled too (`python -m planner.prebuild`; the service starts it
at the lowest priority when it starts, and an image can run it at build time).

Each example is planned for one iteration with its own settings, which starts the
background builds of the libraries its first solve loads (the NLP's kernels, the
verification's flow and the linearisation's Jacobians), and the builds are waited for; a
strategy that only a longer plan reaches (a companion's continuation) has its kernels
built when a plan first runs it.
"""

from __future__ import annotations

import os
import subprocess
import sys

from planner import compiled
from planner.examples import examples
from planner.ocp.planner import plan
from planner.scene import Scene

WAIT = 900.0
"""[s] The longest the builds are waited for."""


def one_iteration(scene: Scene) -> Scene:
    """The scene stopped after one iteration of one start."""
    request = scene.model_dump(exclude_unset=True)
    request["solver"] = {**request.get("solver", {}), "max_iter": 1, "retries": 0}
    return Scene.model_validate(request)


def scenes() -> list[Scene]:
    """The built-in plan examples, each stopped after one iteration and one start."""
    return [one_iteration(Scene.model_validate(example.request)) for example in examples()
            if example.kind == "plan"]


def build(ahead: list[Scene] | None = None, wait: float = WAIT) -> list[str]:
    """Build the libraries of `ahead` (default: the examples' `scenes()`), those missing
    from the cache, and wait for them for at most `wait` seconds; the names of those this
    process started building (`compiled.building()` names those still building)."""
    if not compiled.background_builds():
        return []
    for scene in scenes() if ahead is None else ahead:
        plan(scene)
    compiled.wait(wait)
    return compiled.started()


def start() -> subprocess.Popen | None:
    """`python -m planner.prebuild` in a process of its own at the lowest priority (None
    when background builds are off)."""
    if not compiled.background_builds():
        return None
    return subprocess.Popen([sys.executable, "-m", "planner.prebuild"], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def main() -> None:
    """Build at the lowest priority, one solver process (no companion)."""
    os.nice(19)
    os.environ["UNDERTOW_SOLVER_PROCESSES"] = "1"
    built = build()
    print(f"built {len(built)} libraries in {compiled.cache_dir()}: {', '.join(built) or '-'}")


if __name__ == "__main__":
    main()
