"""The planner's initial guesses compared on the underactuated scenes, in one run.

For "under-2" and "seed-4" (bench/scenes.py) at Legendre 5, N = 40 and at the default
transcription, Legendre 3, N = 50: one solve (refinement and retries off, so that the
guess alone decides where Ipopt ends) from the interpolation guess and from the
classical-inverse-dynamics guess (`solver.initial_guess`), 60 s wall-time cap; the solve
time excludes the NLP's build. Reported: status, iterations, Ipopt wall time, objective,
interval error and open-loop replay error, and whether the plan is verified. Writes
bench/results/initial_guess.csv and the section "Initial guesses" of docs/benchmarks.md.

    python -m bench initial_guess [--scenes under-2,seed-4] [--grids 5:40,3:50]
"""

from __future__ import annotations

import argparse
import time

from bench import harness
from bench.plans import SUMMARY_COLUMNS, summary
from bench.scenes import make_scene
from planner.ocp import plan

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Initial guesses"
GUESSES = ("interpolation", "inverse-dynamics")


def row(scene_name: str, degree: int, N: int, guess: str) -> dict:
    """One solve from one guess."""
    scene = make_scene(scene_name, N=N, degree=degree, one_solve=True,
                       solver={"initial_guess": guess, "max_wall_time": 60.0})
    result = plan(scene)
    return {"scene": scene_name, "transcription": f"legendre-{degree}, N = {N}", "guess": guess,
            **summary(result), "used": result.solver.initial_guess, "load": harness.load()}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench initial_guess", description=__doc__)
    parser.add_argument("--scenes", default="under-2,seed-4")
    parser.add_argument("--grids", default="5:40,3:50", help="degree:N, comma-separated")
    args = parser.parse_args(argv)
    grids = [tuple(map(int, g.split(":"))) for g in args.grids.split(",")]
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for scene_name in args.scenes.split(","):
        for degree, N in grids:
            for guess in GUESSES:
                rows.append(row(scene_name, degree, N, guess))
                print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "initial_guess.csv", rows)
    text = "\n\n".join([
        ("One solve per row (mesh refinement and retries off) from the named "
         "`solver.initial_guess`, 60 s wall-time cap; `solve` is Ipopt's wall time, the "
         "NLP's build excluded. The inverse-dynamics guess follows the interpolation's "
         "passive path with the classical inverse dynamics until sigma_min(M_pa) meets the "
         "coupling margin (seed-4: 0.02; under-2, without a margin: 1e-3), then hands over "
         "to the interpolation; `guess used` says where Ipopt did start."),
        harness.table(rows, [("scene", "scene"), ("transcription", "transcription"),
                             ("guess", "guess"), ("used", "guess used"),
                             *[c for c in SUMMARY_COLUMNS if c[0] != "solves"],
                             ("load", "load average")]),
        f"Rows: `bench/results/initial_guess.csv`. "
        f"{harness.manifest('initial_guess', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
