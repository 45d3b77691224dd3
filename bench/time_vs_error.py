"""Run time against error of every transcription, for the seed's 4-link arm and 2-link arms.

For each scene of bench/common.py ("seed-4", "arm-2", "under-2") and each transcription
(trapezoidal, Hermite-Simpson, Legendre and Radau of degree 2-5, multiple shooting with
RK4 and with CVODES) over a grid of interval counts N, one fresh process per point:

- build time of the NLP (cold cache), then `plan()` from the default initial guess,
  repeated 5 times (3 when the first solve takes 2 s or more): median wall and CPU time
  of Ipopt, iterations, status;
- re-simulation error and dynamics defect (the plan's own verification), and the error
  against a reference solution: max |q - q_ref| over the plan's dense output, the
  reference's dense output interpolated by a cubic spline.

The reference of a scene is Legendre degree 5 at N = 160, warm-started from the Legendre
degree 3 plans at N = 20, 30 and 40; the lowest objective wins (the best optimum known).
A point whose objective is more than 5 % off the reference's is flagged as another local
optimum: its error against the reference then measures the distance between optima.

Limits: each solve stops at 60 s (Ipopt wall-time option), each point's process at 600 s;
a transcription skips finer grids once a point failed, timed out or took over 60 s, and
once its error against the reference is below 1e-7 rad (the accuracy floor set by Ipopt's
tolerance 1e-8). Skips and failures are rows of the CSV.

Writes bench/results/time_vs_error.csv, docs/img/pareto_<scene>.png and the section
"Run time against error" of docs/benchmarks.md.

    .venv/bin/python bench/time_vs_error.py [--scenes seed-4 arm-2 under-2] [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (DOCS, RESULTS, build_instrumented, dense_error, isolated,  # noqa: E402
                          load, machine_note, make_scene, median, spline_floor, table,
                          write_csv, write_section)
from planner.ocp import Plan, plan  # noqa: E402

SECTION = "Run time against error"
SPECS = ([("trapezoidal", 0, "rk4"), ("hermite-simpson", 0, "rk4")]
         + [(m, d, "rk4") for m in ("legendre", "radau") for d in (2, 3, 4, 5)]
         + [("multiple-shooting", 0, "rk4"), ("multiple-shooting", 0, "cvodes")])
GRIDS = {"seed-4": [10, 20, 40, 80], "arm-2": [10, 20, 40, 80, 160, 400],
         "under-2": [10, 20, 40, 80, 160, 400]}
CVODES_MAX_N = 40  # multiple shooting with CVODES (limited-memory Hessian) above is hopeless
REFERENCE = {"degree": 5, "N": 160, "starts": (20, 30, 40)}
SOLVE_CAP, POINT_TIMEOUT, REFERENCE_TIMEOUT = 60.0, 600.0, 1800.0
FLOOR = 1e-7  # [rad]
SAME_OPTIMUM = 0.05  # relative objective difference within which two plans share an optimum


def label(method: str, degree: int, integrator: str) -> str:
    if method in ("legendre", "radau"):
        return f"{method}-{degree}"
    if method == "multiple-shooting":
        return f"shooting-{integrator}"
    return method


def reference(scene_name: str, path: str) -> dict:
    """Compute the scene's reference plan (see module doc), save it as JSON at `path`."""
    best: Plan | None = None
    for N in REFERENCE["starts"]:
        start = plan(make_scene(scene_name, "legendre", N, 3))
        fine = plan(make_scene(scene_name, "legendre", REFERENCE["N"], REFERENCE["degree"]),
                    warm_start=start)
        if fine.solver.success and (best is None or fine.objective < best.objective):
            best = fine
    if best is None:
        return {"failure": "no reference solve succeeded"}
    Path(path).write_text(best.model_dump_json())
    return {"objective": best.objective, "resimulation_error": best.verification.resimulation_error,
            "iterations": best.solver.iterations, "floor": spline_floor(best)}


def point(scene_name: str, method: str, N: int, degree: int, integrator: str,
          reference_path: str) -> dict:
    """One grid point, cold (run in a fresh process by `isolated`)."""
    scene = make_scene(scene_name, method, N, degree or 3, integrator=integrator,
                       solver={"max_wall_time": SOLVE_CAP})
    build_time, solver = build_instrumented(scene)
    plans, cpus = [plan(scene)], [solver.cpu]
    repeats = 5 if plans[0].solver.solve_time < 2.0 else 3
    for _ in range(repeats - 1):
        plans.append(plan(scene))
        cpus.append(solver.cpu)
    first = plans[0]
    ref = Plan.model_validate_json(Path(reference_path).read_text())
    v = first.verification
    return {"status": first.solver.status, "success": first.solver.success, "runs": repeats,
            "build_time": build_time, "solve": median(p.solver.solve_time for p in plans),
            "solve_min": min(p.solver.solve_time for p in plans), "solve_cpu": median(cpus),
            "iterations": first.solver.iterations,
            "same_iterations": len({p.solver.iterations for p in plans}) == 1,
            "objective": first.objective, "resim_error": v.resimulation_error,
            "defect": v.defect, "ref_error": dense_error(first, ref),
            "crossings": len(v.waveless_singular_crossings), "min_sigma": v.min_sigma}


def sweep(scene_name: str, grid: list[int], ref_path: str, ref_objective: float,
          log) -> list[dict]:
    rows = []
    for method, degree, integrator in SPECS:
        name = label(method, degree, integrator)
        stop = ""
        for N in grid:
            if method == "multiple-shooting" and integrator == "cvodes" and N > CVODES_MAX_N:
                continue
            row = {"scene": scene_name, "transcription": name, "N": N, "load": load()}
            if stop:
                rows.append({**row, "status": "skipped", "note": stop})
                continue
            started = time.perf_counter()
            out = isolated("time_vs_error", "point",
                           {"scene_name": scene_name, "method": method, "N": N,
                            "degree": degree, "integrator": integrator,
                            "reference_path": ref_path}, POINT_TIMEOUT)
            row.update(out)
            row["wall"] = time.perf_counter() - started
            if "failure" in out:
                row["status"], row["note"] = "crashed", out["failure"]
                stop = f"skipped: N = {N} {out['failure']}"
            else:
                gap = abs(out["objective"] - ref_objective) / abs(ref_objective)
                row["optimum"] = "reference" if gap <= SAME_OPTIMUM else "other"
                if not out["success"] or out["solve"] > SOLVE_CAP:
                    stop = f"skipped: N = {N} ended {out['status']} after {out['solve']:.0f} s"
                elif out["ref_error"] < FLOOR:
                    stop = f"skipped: N = {N} reached the {FLOOR:g} rad floor"
            rows.append(row)
            log(row)
    return rows


def pareto(rows: list[dict], key: str) -> list[dict]:
    """Successful points not beaten by a faster point in `key` error (ascending time)."""
    ok = sorted((r for r in rows if r.get("success") and r.get(key) is not None
                 and math.isfinite(r[key])), key=lambda r: r["solve"])
    front, best = [], math.inf
    for r in ok:
        if r[key] < best:
            front.append(r)
            best = r[key]
    return front


def plot(scene_name: str, rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharex=True)
    for ax, key, title in ((axes[0], "ref_error", "error against the reference [rad]"),
                           (axes[1], "resim_error", "re-simulation error [rad]")):
        for name in dict.fromkeys(r["transcription"] for r in rows):
            pts = [r for r in rows if r["transcription"] == name and r.get("success")
                   and r.get(key)]
            if pts:
                style = "o-" if "legendre" in name else "s--" if "radau" in name else "^-."
                ax.plot([r["solve"] for r in pts], [r[key] for r in pts], style,
                        label=name, markersize=4, linewidth=0.8)
                for r in pts:
                    if r.get("optimum") == "other":
                        ax.plot(r["solve"], r[key], "x", color="red", markersize=9)
        front = pareto(rows, key)
        if front:
            ax.step([r["solve"] for r in front], [r[key] for r in front], "k-", where="post",
                    linewidth=2, alpha=0.4, label="Pareto front")
        ax.set(xscale="log", yscale="log", xlabel="solve time, median [s]", ylabel=title)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_title(f"{scene_name}: red x = another local optimum than the reference's")
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


BANDS = (1e-2, 1e-4, 1e-6)


def recommendations(rows: list[dict]) -> list[dict]:
    """Per scene and accuracy band: the fastest point (median solve) that reaches it
    against the reference, and the fastest counting the cold build too."""
    out = []
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        ok = [r for r in rows if r["scene"] == scene_name and r.get("success")
              and r.get("optimum") == "reference"]
        for band in BANDS:
            hits = [r for r in ok if r["ref_error"] <= band]
            if not hits:
                out.append({"scene": scene_name, "band": band, "fastest": "none reached it"})
                continue
            fast = min(hits, key=lambda r: r["solve"])
            cold = min(hits, key=lambda r: r["solve"] + r["build_time"])
            out.append({"scene": scene_name, "band": band,
                        "fastest": f"{fast['transcription']}, N = {fast['N']}",
                        "solve": fast["solve"], "error": fast["ref_error"],
                        "cold": f"{cold['transcription']}, N = {cold['N']}",
                        "cold_time": cold["solve"] + cold["build_time"]})
    return out


COLUMNS = [("transcription", "transcription"), ("N", "N"), ("status", "status"),
           ("runs", "runs"), ("build_time", "build [s]"), ("solve", "solve [s]"),
           ("solve_cpu", "solve CPU [s]"), ("iterations", "iterations"),
           ("objective", "objective"), ("optimum", "optimum"),
           ("resim_error", "re-sim. error [rad]"), ("defect", "defect [N m s]"),
           ("ref_error", "error vs ref. [rad]"), ("note", "note")]


def report(rows: list[dict], refs: dict, note: str, command: str, took: float) -> str:
    parts = [
        f"Generated by `{command}` in {took / 60:.0f} min on {note}; load average at each "
        "point is in the CSV (`bench/results/time_vs_error.csv`). Each point runs in a fresh "
        "process: build from a cold cache, then `plan()` from the default initial guess; "
        "`solve` is the median Ipopt wall time over `runs` solves (5, or 3 when a solve "
        "takes 2 s or more), `solve CPU` the median CPU time of the same solves. Errors: "
        "re-simulation (the plan's torque fed to CVODES at rtol 1e-10), defect (integral of "
        "|M ddq + h - B tau| along the interpolant), and max |q - q_ref| over the dense "
        "output against the reference (Legendre degree 5, N = 160, warm-started from the "
        "Legendre-3 plans at N = 20, 30, 40, lowest objective). `optimum`: `other` when the "
        "objective is more than 5 % off the reference's, i.e. Ipopt found another local "
        "optimum from the default guess. Grids stop early once the error against the "
        f"reference is below {FLOOR:g} rad or a point fails or exceeds {SOLVE_CAP:g} s.",
        table([{"scene": k, **v} for k, v in refs.items()],
              [("scene", "scene"), ("objective", "reference objective"),
               ("resimulation_error", "its re-sim. error [rad]"), ("iterations", "iterations"),
               ("floor", "spline floor [rad]")]),
        "Fastest transcription per accuracy band (against the reference, same optimum; "
        "`cold` counts the build of a new NLP structure too):",
        table(recommendations(rows),
              [("scene", "scene"), ("band", "error <= [rad]"), ("fastest", "fastest warm"),
               ("solve", "solve [s]"), ("error", "error [rad]"), ("cold", "fastest cold"),
               ("cold_time", "build + solve [s]")]),
    ]
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        parts += [f"### {scene_name}", f"![Pareto front, {scene_name}](img/pareto_{scene_name}.png)",
                  table([r for r in rows if r["scene"] == scene_name], COLUMNS)]
    return "\n\n".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["seed-4", "arm-2", "under-2"])
    parser.add_argument("--quick", action="store_true", help="N = 10, 20 only; write nothing")
    args = parser.parse_args()
    note, started = machine_note(), time.perf_counter()
    rows, refs = [], {}
    tmp = tempfile.mkdtemp(prefix="undertow-ref-")
    log = lambda r: print(json.dumps({k: v for k, v in r.items()  # noqa: E731
                                      if k in ("scene", "transcription", "N", "status",
                                               "solve", "ref_error", "optimum", "note")}),
                          flush=True)
    for scene_name in args.scenes:
        ref_path = f"{tmp}/{scene_name}.json"
        refs[scene_name] = isolated("time_vs_error", "reference",
                                    {"scene_name": scene_name, "path": ref_path},
                                    REFERENCE_TIMEOUT)
        print(scene_name, "reference", refs[scene_name], flush=True)
        if "failure" in refs[scene_name]:
            continue
        grid = [10, 20] if args.quick else GRIDS[scene_name]
        rows += sweep(scene_name, grid, ref_path, refs[scene_name]["objective"], log)
    if args.quick:
        return
    command = ".venv/bin/python bench/time_vs_error.py " + " ".join(sys.argv[1:])
    fields = sorted({k for r in rows for k in r}, key=lambda k: [c for c, _ in COLUMNS].index(k)
                    if k in [c for c, _ in COLUMNS] else 100)
    write_csv(RESULTS / "time_vs_error.csv", [{k: r.get(k) for k in ["scene", *fields]}
                                              for r in rows])
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        plot(scene_name, [r for r in rows if r["scene"] == scene_name],
             DOCS / "img" / f"pareto_{scene_name}.png")
    text = report(rows, refs, note, command.strip(), time.perf_counter() - started)
    write_section(DOCS / "benchmarks.md", SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
