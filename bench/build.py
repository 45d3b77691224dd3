"""Building an NLP against the number of links, now and at an earlier commit, in one run.

For n = 2 ... 8 links (passive base, the other joints active with a wave each, g = 9.81),
the default transcription (Legendre degree 3, 50 intervals) and an effort objective with a
torque limit, a fresh process imports the planner, derives the arm's dynamics and builds
the NLP with its Ipopt solver (`planner.ocp.problem.problem`), once with this checkout's
planner and once with the planner of `--before`. Reported: the wall time of the build
(derivation included) and the process's peak resident memory after it.

    python -m bench build [--before 893832c] [--links 2,3,4,5,6,7,8]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench import harness
from bench.examples import BEFORE

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Building an NLP against the number of links"

_RUN = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
from planner.ocp.problem import ProblemKey, problem
from planner.scene import Scene
scene = Scene.model_validate(json.loads(sys.argv[1]))
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
started = time.perf_counter()
problem(ProblemKey.of(scene))
elapsed = time.perf_counter() - started
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print("RESULT " + json.dumps({{"build": elapsed, "peak_mb": peak / 1024,
                               "imported_mb": before / 1024}}))
"""


def scene(n: int) -> dict:
    """The n-link arm's default plan request."""
    links = [{"length": 0.4, "mass": 0.8, "inertia": 0.01, "joint": "passive"}]
    links += [{"length": 0.35, "mass": 0.6, "inertia": 0.006, "joint": "active",
               "wave": {"amplitude": 0.04, "frequency": 3.0, "phase": 0.2}}
              for _ in range(n - 1)]
    return {"robot": {"links": links, "gravity": 9.81},
            "task": {"duration": 2.0, "initial": {"q": [0.0] * n, "dq": [0.0] * n},
                     "final": {"q": [0.2] * n, "dq": [0.0] * n}, "torque_limit": 20.0}}


def _build_at(root: Path, request: dict) -> dict:
    return harness.run_at(root, _RUN.format(root=str(root)), [json.dumps(request)], 1800)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench build", description=__doc__)
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--links", default="2,3,4,5,6,7,8")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    with harness.checkout(args.before) as old:
        for n in map(int, args.links.split(",")):
            now, before = _build_at(harness.ROOT, scene(n)), _build_at(old, scene(n))
            rows.append({"links": n, **{f"now_{k}": v for k, v in now.items()},
                         **{f"before_{k}": v for k, v in before.items()}})
            print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "build.csv", rows)
    columns = [("links", "links"), ("before_build", "build before [s]"),
               ("before_peak_mb", "peak before [MB]"), ("now_build", "build now [s]"),
               ("now_peak_mb", "peak now [MB]"), ("now_imported_mb", "after imports [MB]")]
    text = "\n\n".join([
        "A default plan (Legendre degree 3, 50 intervals, effort, torque limit) of an arm "
        "with a passive base and n - 1 wavy active joints under gravity: the wall time of "
        "deriving its dynamics and building its NLP and Ipopt solver in a fresh process, and "
        f"the process's peak resident memory after it, with the planner of {args.before} "
        "(before: the whole graph expanded to SX, derivatives generated for it) and of this "
        "checkout (now: per-stage derivative kernels mapped over the stages).",
        harness.table(rows, columns),
        f"Rows: `bench/results/build.csv`. {harness.manifest('build', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
