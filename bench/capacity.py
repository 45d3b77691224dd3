"""How much memory a plan's NLP needs: the measurements behind app/capacity.py.

Each point builds one NLP from a cold cache in a fresh process and runs Ipopt for
`ITERATIONS` iterations, recording how far the process grew beyond its size after the
imports: address space (VmPeak - VmSize, what UNDERTOW_WORKER_MEMORY_MB caps) and
resident memory (VmHWM - VmRSS), after the build and after the iterations, with the build
time. Robots: `testbed.robots.chain_scene` (0.4 m, 1 kg links, even joints passive,
waves on the odd active ones), each joint moving +0.5 rad rest to rest in 1 s; `extra`
adds a coupling margin (0.001) or wave co-design (amplitudes up to 0.05 m).

Compares app/capacity.py's estimate with each point and writes
bench/results/capacity.csv (which tests/test_capacity.py checks the estimate against) and
the section "Memory of one plan" of docs/deploy.md.

    python -m bench capacity [--points 27]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from app.capacity import dynamics_knots, estimate_mb
from bench import harness
from planner.scene import Scene
from testbed.robots import chain_scene

SECTION = "Memory of one plan"
ITERATIONS = 3
TIMEOUT = 900.0
GUARD_MB = 12_000  # address-space cap of a measuring process, so a point cannot sink the host
POINTS = [  # links, method, degree, intervals, integrator, steps, form, extra
    (2, "legendre", 3, 20, "rk4", 4, "implicit", ""),
    (4, "legendre", 3, 20, "rk4", 4, "implicit", ""),
    (6, "legendre", 3, 20, "rk4", 4, "implicit", ""),
    (8, "legendre", 3, 20, "rk4", 4, "implicit", ""),
    (8, "legendre", 3, 40, "rk4", 4, "implicit", ""),
    (8, "legendre", 3, 400, "rk4", 4, "implicit", ""),
    (8, "radau", 9, 8, "rk4", 4, "implicit", ""),
    (8, "radau", 9, 200, "rk4", 4, "implicit", ""),
    (8, "radau", 1, 60, "rk4", 4, "implicit", ""),
    (8, "trapezoidal", 3, 60, "rk4", 4, "implicit", ""),
    (8, "hermite-simpson", 3, 30, "rk4", 4, "implicit", ""),
    (4, "radau", 9, 20, "rk4", 4, "implicit", ""),
    (2, "legendre", 3, 400, "rk4", 4, "implicit", ""),
    (2, "legendre", 3, 20, "rk4", 4, "explicit", ""),
    (4, "legendre", 3, 20, "rk4", 4, "explicit", ""),
    (8, "legendre", 3, 20, "rk4", 4, "explicit", ""),
    (8, "legendre", 3, 200, "rk4", 4, "explicit", ""),
    (2, "multiple-shooting", 3, 20, "rk4", 4, "implicit", ""),
    (4, "multiple-shooting", 3, 20, "rk4", 4, "implicit", ""),
    (6, "multiple-shooting", 3, 20, "rk4", 4, "implicit", ""),
    (8, "multiple-shooting", 3, 20, "rk4", 4, "implicit", ""),
    (8, "multiple-shooting", 3, 40, "rk4", 4, "implicit", ""),
    (8, "multiple-shooting", 3, 20, "rk4", 8, "implicit", ""),
    (8, "multiple-shooting", 3, 10, "rk4", 12, "implicit", ""),
    (8, "multiple-shooting", 3, 40, "cvodes", 4, "implicit", ""),
    (8, "legendre", 3, 20, "rk4", 4, "implicit", "margin"),
    (8, "legendre", 3, 20, "rk4", 4, "implicit", "co-design"),
]


def scene_of(links: int, method: str, degree: int, intervals: int, integrator: str, steps: int,
             form: str, extra: str) -> Scene:
    """The scene of one point, stopped after `ITERATIONS` Ipopt iterations."""
    return chain_scene(links, extra=extra, solver={"max_iter": ITERATIONS}, method=method,
                       degree=degree, intervals=intervals, integrator=integrator, steps=steps,
                       form=form)


def point(links: int, method: str, degree: int, intervals: int, integrator: str, steps: int,
          form: str, extra: str) -> dict:
    """One point in this (fresh) process: memory [MB] and build time [s]."""
    from app.procmem import limit_growth, status_mb
    from planner.ocp import plan
    from planner.ocp.problem import ProblemKey, problem

    scene = scene_of(links, method, degree, intervals, integrator, steps, form, extra)
    size, rss = status_mb("VmSize"), status_mb("VmRSS")
    limit_growth(GUARD_MB)
    started = time.perf_counter()
    problem(ProblemKey.of(scene))
    build = time.perf_counter() - started
    built = {"vm_build": status_mb("VmPeak") - size, "rss_build": status_mb("VmHWM") - rss}
    result = plan(scene)
    return {"build": build, **built, "vm_solve": status_mb("VmPeak") - size,
            "rss_solve": status_mb("VmHWM") - rss, "status": result.solver.status,
            "vm_imports": size, "rss_imports": rss}


COLUMNS = [("links", "links"), ("method", "method"), ("degree", "degree"),
           ("intervals", "intervals"), ("integrator", "integrator"), ("steps", "steps"),
           ("form", "form"), ("extra", "extra"), ("knots", "dynamics knots"),
           ("build", "build [s]"), ("vm_build", "address space, build [MB]"),
           ("vm_solve", f"after {ITERATIONS} iterations [MB]"),
           ("rss_solve", "resident [MB]"), ("estimate", "estimate [MB]"),
           ("ratio", "measured / estimate"), ("failure", "failure")]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench capacity", description=__doc__)
    parser.add_argument("--points", type=int, default=len(POINTS),
                        help="measure the first this many points")
    args = parser.parse_args(argv)
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for links, method, degree, intervals, integrator, steps, form, extra in POINTS[:args.points]:
        spec: dict[str, Any] = {
            "links": links, "method": method, "degree": degree, "intervals": intervals,
            "integrator": integrator, "steps": steps, "form": form, "extra": extra}
        out = harness.isolated("capacity", "point", spec, TIMEOUT)
        scene = scene_of(**spec)
        row = {**spec, "knots": dynamics_knots(scene.transcription),
               "estimate": estimate_mb(scene), "load": harness.load(), **out}
        if "vm_solve" in row:
            row["ratio"] = row["vm_solve"] / row["estimate"]
        rows.append(row)
        print(row, flush=True)
    harness.write_csv(harness.RESULTS / "capacity.csv", [{k: r.get(k) for k in [
        "links", "method", "degree", "intervals", "integrator", "steps", "form", "extra",
        "knots", "status", "build", "vm_build", "rss_build", "vm_solve", "rss_solve",
        "estimate", "ratio", "vm_imports", "rss_imports", "load", "failure"]} for r in rows])
    text = "\n\n".join([
        (f"Each point builds one NLP in a fresh process and runs {ITERATIONS} Ipopt "
         "iterations; the memory is how far the process grew beyond its size after the "
         "imports: address space (what `UNDERTOW_WORKER_MEMORY_MB` caps) and resident. "
         "Robots: chains of 0.4 m, 1 kg links, even joints passive, waves on the odd active "
         "ones. *Estimate*: `app/capacity.py`, whose constants keep it at or below every "
         "measured point, so it refuses (422) only plans that certainly do not fit; a "
         "plan's refined meshes (up to `transcription.refinement.max_intervals`) can need "
         "more, which the worker limit catches."),
        harness.table(rows, COLUMNS),
        f"Rows: `bench/results/capacity.csv`. "
        f"{harness.manifest('capacity', argv, started, note)}"])
    print(text)
    harness.write_section(harness.DOCS / "deploy.md", SECTION, text)
    return 0
