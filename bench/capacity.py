"""How much memory a plan's NLP needs: the measurements behind app/capacity.py.

Each point builds one NLP from a cold cache in a fresh process and runs Ipopt for
`ITERATIONS` iterations, recording how far the process grew beyond its size after the
imports: address space (VmPeak - VmSize, what UNDERTOW_WORKER_MEMORY_MB caps) and
resident memory (VmHWM - VmRSS), after the build and after the iterations, with the build
time. Robots: bench/stress.py `chain(n, under=True)` (0.4 m, 1 kg links, even joints
passive, waves on the odd active ones), each joint moving +0.5 rad rest to rest in 1 s;
`extra` adds a coupling margin (0.001) or wave co-design (amplitudes up to 0.05 m).

Compares app/capacity.py's estimate with each point and writes
bench/results/capacity.csv and the section "Memory of one plan" of docs/deploy.md.

    .venv/bin/python bench/capacity.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (
    DOCS,
    RESULTS,
    isolated,
    load,
    machine_note,
    table,
    write_csv,
    write_section,
)

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
             form: str, extra: str, max_iter: int = ITERATIONS):
    from bench.stress import chain
    from planner.scene import Scene

    start = [0.1 * k for k in range(links)]
    task = {"duration": 1.0, "initial": {"q": start, "dq": [0.0] * links},
            "final": {"q": [s + 0.5 for s in start], "dq": [0.0] * links}}
    if extra == "margin":
        task["coupling_margin"] = 1e-3
    elif extra == "co-design":
        task["co_design"] = {"amplitude_max": 0.05, "frequency": [3.0] * (links // 2)}
    return Scene.model_validate({
        "robot": chain(links, under=True),
        "transcription": {"method": method, "degree": degree, "intervals": intervals,
                          "integrator": integrator, "steps": steps, "form": form},
        "solver": {"max_iter": max_iter}, "task": task})


def point(links: int, method: str, degree: int, intervals: int, integrator: str, steps: int,
          form: str, extra: str) -> dict:
    """One point in this (fresh) process."""
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


def main() -> None:
    from app.capacity import dynamics_knots, estimate_mb

    note, started, rows = machine_note(), time.perf_counter(), []
    for links, method, degree, intervals, integrator, steps, form, extra in POINTS:
        args = {"links": links, "method": method, "degree": degree, "intervals": intervals,
                "integrator": integrator, "steps": steps, "form": form, "extra": extra}
        out = isolated("capacity", "point", args, TIMEOUT)
        scene = scene_of(**args)
        row = {**args, "knots": dynamics_knots(scene.transcription),
               "estimate": estimate_mb(scene), "load": load(), **out}
        if "vm_solve" in row:
            row["ratio"] = row["vm_solve"] / row["estimate"]
        rows.append(row)
        print(row, flush=True)
    write_csv(RESULTS / "capacity.csv", [{k: r.get(k) for k in [
        "links", "method", "degree", "intervals", "integrator", "steps", "form", "extra",
        "knots", "status", "build", "vm_build", "rss_build", "vm_solve", "rss_solve",
        "estimate", "ratio", "vm_imports", "rss_imports", "load", "failure"]} for r in rows])
    text = "\n\n".join([
        (f"Generated by `.venv/bin/python bench/capacity.py` in "
         f"{(time.perf_counter() - started) / 60:.0f} min on {note}. Each point builds one "
         f"NLP in a fresh process and runs {ITERATIONS} Ipopt iterations; the memory is "
         "how far the process grew beyond its size after the imports: address space (what "
         "`UNDERTOW_WORKER_MEMORY_MB` caps) and resident. Robots: chains of 0.4 m, 1 kg "
         "links, even joints passive, waves on the odd active ones. *Estimate*: "
         "`app/capacity.py`, whose constants keep it at or below every measured point, so "
         "it refuses (422) only plans that certainly do not fit; a plan's refined meshes "
         "(up to `transcription.refinement.max_intervals`) can need more, which the "
         "worker limit catches."),
        table(rows, COLUMNS)])
    print(text)
    write_section(DOCS / "deploy.md", SECTION, text)


if __name__ == "__main__":
    main()
