"""The built-in plan examples, now and at an earlier commit, in one run.

Each example is planned `--repeats` times in one process (the first plan builds the NLP;
the median is over the plans after it), once with this checkout's planner and once with
the planner of `--before` (a git commit, checked out into a temporary worktree and run with
this checkout's Python environment). Reported: Ipopt's iterations, whether the plan
verifies by each version's own check (before: the whole-horizon replay within 1e-3 rad;
now: every interval within 1e-3 rad), and the median wall time of a plan.

    python -m bench examples [--before 893832c] [--repeats 5] [--examples NAME,...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench import harness
from planner.examples import examples

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Built-in plan examples: now and before"
BEFORE = "893832c"  # the last commit before plans were refined and verified interval by interval

_RUN = """
import json, statistics, sys, time
sys.path.insert(0, {root!r})
from planner.ocp import plan
from planner.scene import Scene
scene = Scene.model_validate(json.loads(sys.argv[1]))
times, solves, result = [], [], None
for _ in range({repeats} + 1):
    started = time.perf_counter()
    result = plan(scene)
    times.append(time.perf_counter() - started)
    solves.append(result.solver.solve_time)
v = result.verification
print("RESULT " + json.dumps({{"iterations": result.solver.iterations,
      "verified": bool(result.solver.success and v.verified),
      "objective": result.objective, "time": statistics.median(times[1:]),
      "solve": statistics.median(solves[1:]), "first": times[0]}}))
"""


def _plan_at(root: Path, request: dict, repeats: int) -> dict:
    """The example planned by the planner under `root`, in a fresh process."""
    return harness.run_at(root, _RUN.format(root=str(root), repeats=repeats),
                          [json.dumps(request)], 600)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench examples", description=__doc__)
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--examples", default=None,
                        help="comma-separated names (default: every plan example)")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    plans = [e for e in examples() if e.kind == "plan"
             and (args.examples is None or e.name in args.examples.split(","))]
    rows = []
    with harness.checkout(args.before) as old:
        for example in plans:
            now = _plan_at(harness.ROOT, example.request, args.repeats)
            before = _plan_at(old, example.request, args.repeats)
            rows.append({"example": example.name, **{f"now_{k}": v for k, v in now.items()},
                         **{f"before_{k}": v for k, v in before.items()}})
            print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "examples.csv", rows)
    columns = [("example", "example"), ("before_iterations", "iterations before"),
               ("before_verified", "verified before"),
               ("before_first", "first plan before [s]"), ("before_time", "plan before [s]"),
               ("before_solve", "of it Ipopt, before [s]"),
               ("now_iterations", "iterations now"), ("now_verified", "verified now"),
               ("now_first", "first plan now [s]"), ("now_time", "plan now [s]"),
               ("now_solve", "of it Ipopt, now [s]"), ("now_objective", "objective now")]
    text = "\n\n".join([
        f"Each built-in plan example with the planner of commit {args.before} (before) and of "
        "this checkout (now), in one run; median wall time of a plan over "
        f"{args.repeats} plans after the first, and the first alone (which builds the NLP: "
        "what a fresh worker takes), with the part Ipopt took. Verified: by each "
        "version's own check (before: the whole-horizon replay within 1e-3 rad; now: every "
        "interval re-integrated within 1e-3 rad). Now, a plan's time includes its error "
        "estimate, the open-loop and closed-loop replays and the feedback.",
        harness.table(rows, columns),
        f"Rows: `bench/results/examples.csv`. "
        f"{harness.manifest('examples', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
