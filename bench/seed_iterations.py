"""Where the seed arm's Ipopt iterations go, from the default interpolation guess.

The seed scene (bench/scenes.py "seed-4": passive joints 0 and 2, g = 0, coupling margin
0.02, Legendre 3) takes hundreds of iterations where a fully actuated arm takes tens. Each
case solves it once (mesh refinement and retries off) with Ipopt's log written to a file,
and counts the iterations Ipopt spends in its feasibility-restoration phase (the lines
marked "r"):

- default: the planner as shipped, N = 50 and 100;
- no margin: the same task without the coupling margin (the plan may then pass through
  configurations that are singular even with waves);
- objective ×10: Ipopt's `obj_scaling_factor` 10 (how sensitive the path is to scaling);
- mesh sequencing: N = 20 solved first, N = 100 warm-started from its plan.

Reported per case: status, iterations, restoration iterations, solve time, objective,
interval error, open-loop replay error, min sigma_min along the plan and whether it is
verified (Ipopt succeeded and every interval re-integrates within 1e-3 rad).
Writes docs/benchmarks.md section "Seed arm: where the iterations go" and
bench/results/seed_iterations.csv.

    python -m bench seed_iterations [--N 50,100] [--coarse 20] [--fine 100]
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time

from bench import harness
from bench.plans import summary
from bench.scenes import make_scene
from planner.ocp import Plan, plan
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Seed arm: where the iterations go"
LIMITS = {"max_iter": 3000, "max_wall_time": 600.0}
RESTORATION = re.compile(r"^\s*\d+r\s")
COLUMNS = [("case", "case"), ("N", "N"), ("status", "status"), ("iterations", "iterations"),
           ("restoration", "of which restoration"), ("solve", "solve [s]"),
           ("objective", "objective"), ("interval_error", "interval error [rad]"),
           ("replay_error", "open-loop replay [rad]"), ("min_sigma", "min sigma_min"),
           ("verified", "verified")]


def _solve(scene: Scene, options: dict, warm_start: Plan | None = None) -> tuple[Plan, int]:
    """The plan of a scene solved with extra Ipopt options, and its restoration iterations
    (the solver holds the log file open until the cache releases it)."""
    with tempfile.NamedTemporaryFile("r", suffix=".log") as log:
        with harness.ipopt_options({"output_file": log.name, "file_print_level": 5, **options}):
            result = plan(scene, warm_start=warm_start)
        restoration = sum(bool(RESTORATION.match(line)) for line in log)
    return result, restoration


def _row(case: str, N: int, result: Plan, restoration: int) -> dict:
    return {"case": case, "N": N, **summary(result), "restoration": restoration,
            "load": harness.load()}


def _scene(N: int) -> Scene:
    return make_scene("seed-4", N=N, one_solve=True, solver=LIMITS)


def cases(grid: list[int], coarse_N: int, fine_N: int) -> list[dict]:
    """Every case of the module docstring, in order."""
    rows = []
    for N in grid:
        scene = _scene(N)
        free = scene.model_copy(update={"task": scene.task.model_copy(
            update={"coupling_margin": None})})
        for case, s, options in (("default", scene, {}), ("no margin", free, {}),
                                 ("objective ×10", scene, {"obj_scaling_factor": 10.0})):
            rows.append(_row(case, N, *_solve(s, options)))
            print(harness.table(rows[-1:], COLUMNS), flush=True)
    coarse, restoration = _solve(_scene(coarse_N), {})
    rows.append(_row("mesh sequencing, coarse", coarse_N, coarse, restoration))
    fine, restoration = _solve(_scene(fine_N), {}, warm_start=coarse)
    rows.append(_row("mesh sequencing, fine (warm)", fine_N, fine, restoration))
    print(harness.table(rows[-2:], COLUMNS), flush=True)
    return rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench seed_iterations", description=__doc__)
    parser.add_argument("--N", default="50,100", help="the grids of the first three cases")
    parser.add_argument("--coarse", type=int, default=20, help="mesh sequencing's first N")
    parser.add_argument("--fine", type=int, default=100, help="mesh sequencing's second N")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = cases([int(n) for n in args.N.split(",")], args.coarse, args.fine)
    harness.write_csv(harness.RESULTS / "seed_iterations.csv", rows)
    text = "\n\n".join([
        ("The seed scene, Legendre 3, interpolation guess (the warm-started row: the coarse "
         f"plan), at most {LIMITS['max_iter']} iterations and {LIMITS['max_wall_time']:g} s, "
         "one solve per row (refinement and retries off); restoration iterations counted "
         "from Ipopt's log. Load averages in the CSV."),
        harness.table(rows, COLUMNS),
        f"Rows: `bench/results/seed_iterations.csv`. "
        f"{harness.manifest('seed_iterations', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
