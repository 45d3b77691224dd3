"""Run time against error of every transcription, for the seed's 4-link arm and 2-link arms.

For each scene of bench/scenes.py ("seed-4", "arm-2", "under-2") and each transcription
(trapezoidal, Hermite-Simpson, Legendre and Radau of degree 2-5, multiple shooting with
RK4 and with CVODES) over a grid of interval counts N, one fresh process per point, one
solve per plan (mesh refinement and retries off, so that N stays the point's):

- build time of the NLP (cold cache), then `plan()` from the default initial guess,
  repeated 5 times (3 when the first solve takes 2 s or more): median wall and CPU time
  of Ipopt, iterations, status;
- interval error, open-loop replay error and dynamics defect (the plan's own
  verification), and the error against a reference solution: max |q - q_ref| over the
  plan's dense output, the reference's dense output interpolated by a cubic spline.

The reference of a scene is Legendre degree 5 at N = 160, warm-started from the Legendre
degree 3 plans at N = 20, 30 and 40; the lowest objective wins (the best optimum known).
A point whose objective is more than 5 % off the reference's is flagged as another local
optimum: its error against the reference then measures the distance between optima.

With `--warm SCENE`, the scene is swept a second time ("SCENE, warm") with every plan
warm-started from the Legendre-3 plan the reference grew from (continuation from a coarse
grid, the remedy when the default guess leads Ipopt to other optima).

Limits: each solve stops at 60 s (Ipopt wall-time option), each point's process at 600 s;
a transcription skips finer grids once a point failed, timed out or took over 60 s, and
once its error against the reference is below 1e-7 rad (the accuracy floor set by Ipopt's
tolerance 1e-8). Skips and failures are rows of the CSV.

Writes bench/results/time_vs_error.csv, docs/img/pareto_<scene>.png and the section
"Run time against error" of docs/benchmarks.md.

    python -m bench time_vs_error [--scenes seed-4 arm-2 under-2] [--warm seed-4] [--quick]
        [--transcriptions legendre-3,...]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import harness
from bench.plans import dense_error, spline_floor
from bench.scenes import make_scene
from planner.ocp import Plan, plan

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Run time against error"
SPECS = ([("trapezoidal", 0, "rk4"), ("hermite-simpson", 0, "rk4")]
         + [(m, d, "rk4") for m in ("legendre", "radau") for d in (2, 3, 4, 5)]
         + [("multiple-shooting", 0, "rk4"), ("multiple-shooting", 0, "cvodes")])
GRIDS = {"seed-4": [10, 20, 40, 80], "arm-2": [10, 20, 40, 80, 160, 400],
         "under-2": [10, 20, 40, 80, 160, 400]}
CVODES_MAX_N = 40  # multiple shooting with CVODES (limited-memory Hessian) above is hopeless
REFERENCE: dict[str, Any] = {"degree": 5, "N": 160, "starts": (20, 30, 40)}
SOLVE_CAP, POINT_TIMEOUT, REFERENCE_TIMEOUT = 60.0, 600.0, 1800.0
FLOOR = 1e-7  # [rad]
SAME_OPTIMUM = 0.05  # relative objective difference within which two plans share an optimum


def slug(scene_name: str) -> str:
    return scene_name.replace(", ", "-")


def label(method: str, degree: int, integrator: str) -> str:
    if method in ("legendre", "radau"):
        return f"{method}-{degree}"
    if method == "multiple-shooting":
        return f"shooting-{integrator}"
    return method


def reference(scene_name: str, path: str) -> dict:
    """Compute the scene's reference plan (see module doc), save it as JSON at `path`."""
    best: tuple[Plan, Plan, float] | None = None  # (start, fine, fine's objective)
    for N in REFERENCE["starts"]:
        start = plan(make_scene(scene_name, "legendre", N, 3, one_solve=True))
        fine = plan(make_scene(scene_name, "legendre", REFERENCE["N"], REFERENCE["degree"],
                               one_solve=True), warm_start=start)
        objective = fine.objective
        if (fine.solver.success and objective is not None
                and (best is None or objective < best[2])):
            best = (start, fine, objective)
    if best is None:
        return {"failure": "no reference solve succeeded"}
    start, fine, _ = best
    Path(path).write_text(fine.model_dump_json())
    Path(path + ".start.json").write_text(start.model_dump_json())
    return {"objective": fine.objective, "interval_error": fine.verification.local_error,
            "replay_error": fine.verification.resimulation_error,
            "iterations": fine.solver.iterations, "floor": spline_floor(fine),
            "start_N": len(start.t) - 1, "start_solve": start.solver.solve_time,
            "start_build": start.solver.build_time}


def point(scene_name: str, method: str, N: int, degree: int, integrator: str,
          reference_path: str, warm_path: str | None = None) -> dict:
    """One grid point, cold (run in a fresh process by `isolated`); warm-started from the
    plan stored at `warm_path` if given."""
    scene = make_scene(scene_name, method, N, degree or 3, one_solve=True,
                       integrator=integrator, solver={"max_wall_time": SOLVE_CAP})
    warm = Plan.model_validate_json(Path(warm_path).read_text()) if warm_path else None
    build_time, solver = harness.build_instrumented(scene)
    plans, cpus = [plan(scene, warm_start=warm)], [solver.cpu]
    repeats = 5 if plans[0].solver.solve_time < 2.0 else 3
    for _ in range(repeats - 1):
        plans.append(plan(scene, warm_start=warm))
        cpus.append(solver.cpu)
    first = plans[0]
    ref = Plan.model_validate_json(Path(reference_path).read_text())
    v = first.verification
    return {"status": first.solver.status, "success": first.solver.success, "runs": repeats,
            "build_time": build_time,
            "solve": harness.median(p.solver.solve_time for p in plans),
            "solve_min": min(p.solver.solve_time for p in plans),
            "solve_cpu": harness.median(cpus), "iterations": first.solver.iterations,
            "same_iterations": len({p.solver.iterations for p in plans}) == 1,
            "objective": first.objective, "interval_error": v.local_error,
            "replay_error": v.resimulation_error, "defect": v.defect,
            "ref_error": dense_error(first, ref),
            "crossings": len(v.waveless_singular_crossings), "min_sigma": v.min_sigma}


def sweep(scene_name: str, grid: list[int], ref_path: str, ref_objective: float,
          log, warm_path: str | None = None, specs: list = SPECS) -> list[dict]:
    rows = []
    name_of_scene = f"{scene_name}, warm" if warm_path else scene_name
    for method, degree, integrator in specs:
        name = label(method, degree, integrator)
        stop = ""
        for N in grid:
            if method == "multiple-shooting" and integrator == "cvodes" and N > CVODES_MAX_N:
                continue
            row = {"scene": name_of_scene, "transcription": name, "N": N, "load": harness.load()}
            if stop:
                rows.append({**row, "status": "skipped", "note": stop})
                continue
            started = time.perf_counter()
            out = harness.isolated("time_vs_error", "point",
                           {"scene_name": scene_name, "method": method, "N": N,
                            "degree": degree, "integrator": integrator,
                            "reference_path": ref_path, "warm_path": warm_path}, POINT_TIMEOUT)
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
                           (axes[1], "interval_error", "interval error [rad]")):
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
    fig.savefig(harness.output(path), dpi=110)
    plt.close(fig)


BANDS = (1e-2, 1e-4, 1e-6)


def recommendations(rows: list[dict]) -> list[dict]:
    """Per scene and accuracy band: the fastest point (median solve wall time, cached NLP)
    whose error against the reference is within the band (hence on the reference's
    optimum), the fastest counting the cold build too, and the fastest whose interval
    error is within the band (on whatever optimum it found)."""
    out = []
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        ok = [r for r in rows if r["scene"] == scene_name and r.get("success")]
        for band in BANDS:
            row: dict = {"scene": scene_name, "band": band}
            hits = [r for r in ok if r["ref_error"] <= band]
            if hits:
                fast = min(hits, key=lambda r: r["solve"])
                cold = min(hits, key=lambda r: r["solve"] + r["build_time"])
                row.update(fastest=f"{fast['transcription']}, N = {fast['N']}", solve=fast["solve"],
                           error=fast["ref_error"],
                           cold=f"{cold['transcription']}, N = {cold['N']}",
                           cold_time=cold["solve"] + cold["build_time"])
            else:
                row["fastest"] = "none reached it"
            resim = [r for r in ok
                     if r["interval_error"] is not None and r["interval_error"] <= band]
            if resim:
                best = min(resim, key=lambda r: r["solve"])
                row.update(resim=f"{best['transcription']}, N = {best['N']}",
                           resim_solve=best["solve"])
            else:
                row["resim"] = "none reached it"
            out.append(row)
    return out


COLUMNS = [("transcription", "transcription"), ("N", "N"), ("status", "status"),
           ("runs", "runs"), ("build_time", "build [s]"), ("solve", "solve [s]"),
           ("solve_cpu", "solve CPU [s]"), ("iterations", "iterations"),
           ("objective", "objective"), ("optimum", "optimum"),
           ("interval_error", "interval error [rad]"),
           ("replay_error", "open-loop replay [rad]"), ("defect", "defect [N m s]"),
           ("ref_error", "error vs ref. [rad]"), ("note", "note")]


def report(rows: list[dict], refs: dict) -> str:
    parts = [
        ("Load average at each point is in the CSV (`bench/results/time_vs_error.csv`). Each "
         "point runs in a fresh process, one solve per plan (mesh refinement and retries "
         "off): build from a cold cache, then `plan()` from the default initial guess; "
         "`solve` is the median Ipopt wall time over `runs` solves (5, or 3 when a solve "
         "takes 2 s or more), `solve CPU` the median CPU time of the same solves (it exceeds "
         "the wall time where MUMPS' BLAS ran a second thread on large KKT systems). Errors: "
         "the interval error (every interval re-integrated by CVODES from the plan's own "
         "state with its torque, what `verified` judges), the open-loop replay (the torque "
         "over the whole horizon from the planned start), the defect (integral of "
         "|M ddq + h - B tau| along the interpolant), and max |q - q_ref| over the dense "
         "output against the reference (Legendre degree 5, N = 160, warm-started from the "
         "Legendre-3 plans at N = 20, 30, 40, lowest objective; the highest order on a grid "
         "whose own interval error, in the table below, is already at the floor that "
         "Ipopt's tolerance sets, so a finer reference would not move any error above "
         f"{FLOOR:g} rad). `optimum`: `other` when the "
         "objective is more than 5 % off the reference's, i.e. Ipopt found another local "
         "optimum from the default guess. Grids stop early once the error against the "
         f"reference is below {FLOOR:g} rad or a point fails or exceeds {SOLVE_CAP:g} s."),
        harness.table([{"scene": k, **v} for k, v in refs.items()],
                      [("scene", "scene"), ("objective", "reference objective"),
                       ("interval_error", "its interval error [rad]"),
                       ("replay_error", "its open-loop replay [rad]"),
                       ("iterations", "iterations"), ("floor", "spline floor [rad]"),
                       ("start_N", "grown from Legendre-3 at N ="),
                       ("start_solve", "that start's solve [s]")]),
        ("Fastest transcription per accuracy band: against the reference (so on its "
         "optimum), by median solve time with the NLP cached, and counting the cold build of "
         "a new NLP structure too; and by interval error alone (on any optimum):"),
        harness.table(recommendations(rows),
                      [("scene", "scene"), ("band", "error <= [rad]"),
                       ("fastest", "fastest, cached NLP"), ("solve", "solve [s]"),
                       ("error", "error [rad]"), ("cold", "fastest with build"),
                       ("cold_time", "build + solve [s]"),
                       ("resim", "fastest by interval error"),
                       ("resim_solve", "its solve [s]")]),
    ]
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        parts += [f"### {scene_name}",
                  f"![Pareto front, {scene_name}](img/pareto_{slug(scene_name)}.png)",
                  harness.table([r for r in rows if r["scene"] == scene_name], COLUMNS)]
    return "\n\n".join(parts)


def read_csv(path: Path) -> list[dict]:
    """Rows written by `write_csv`, with numbers, booleans and empty cells (None) restored."""
    def value(text: str):
        if text == "":
            return None
        if text in ("True", "False"):
            return text == "True"
        for kind in (int, float):
            try:
                return kind(text)
            except ValueError:
                pass
        return text

    with open(path, newline="") as f:
        return [{k: value(v) for k, v in row.items()} for row in csv.DictReader(f)]


def _log(row: dict) -> None:
    print(json.dumps({k: v for k, v in row.items()
                      if k in ("scene", "transcription", "N", "status", "solve",
                               "ref_error", "optimum", "note")}), flush=True)


def sweeps(args: argparse.Namespace) -> tuple[list[dict], dict[str, dict]]:
    """The rows of every sweep the arguments ask for, and the references by scene."""
    rows: list[dict] = []
    refs: dict[str, dict] = {}
    tmp = tempfile.mkdtemp(prefix="undertow-ref-")
    specs = [s for s in SPECS if args.transcriptions is None
             or label(*s) in args.transcriptions.split(",")]
    for scene_name in args.scenes:
        ref_path = f"{tmp}/{scene_name}.json"
        refs[scene_name] = harness.isolated("time_vs_error", "reference",
                                            {"scene_name": scene_name, "path": ref_path},
                                            REFERENCE_TIMEOUT)
        print(scene_name, "reference", refs[scene_name], flush=True)
        if "failure" in refs[scene_name]:
            continue
        grid = [10, 20] if args.quick else GRIDS[scene_name]
        if not args.warm_only:
            rows += sweep(scene_name, grid, ref_path, refs[scene_name]["objective"], _log,
                          specs=specs)
        if scene_name in args.warm:
            refs[f"{scene_name}, warm"] = refs[scene_name]
            rows += sweep(scene_name, grid, ref_path, refs[scene_name]["objective"], _log,
                          warm_path=ref_path + ".start.json", specs=specs)
    return rows, refs


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench time_vs_error", description=__doc__)
    parser.add_argument("--scenes", nargs="+", default=["seed-4", "arm-2", "under-2"])
    parser.add_argument("--warm", nargs="*", default=["seed-4"],
                        help="scenes to sweep again, warm-started from the reference's start")
    parser.add_argument("--warm-only", action="store_true", help="skip the cold sweeps")
    parser.add_argument("--merge", action="store_true",
                        help="keep the other scenes' rows and references of the last run")
    parser.add_argument("--quick", action="store_true", help="N = 10, 20 only")
    parser.add_argument("--transcriptions", default=None,
                        help="comma-separated, from: " + ", ".join(label(*s) for s in SPECS)
                             + " (default: all)")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows, refs = sweeps(args)
    merged = ""
    if args.merge:
        done = {r["scene"] for r in rows}
        kept = [r for r in read_csv(harness.RESULTS / "time_vs_error.csv")
                if r["scene"] not in done]
        rows = kept + rows
        merged = (f"This run measured {', '.join(sorted(done))}; the rows of "
                  f"{', '.join(dict.fromkeys(r['scene'] for r in kept))} are kept from the "
                  f"previous run (bench/results/time_vs_error.csv as of commit "
                  f"{harness.last_commit(harness.RESULTS / 'time_vs_error.csv')}). ")
        old = {r["scene"]: r for r in read_csv(harness.RESULTS / "time_vs_error_refs.csv")}
        refs = {**{k: v for k, v in old.items() if k not in refs}, **refs}
    fields = sorted({k for r in rows for k in r}, key=lambda k: [c for c, _ in COLUMNS].index(k)
                    if k in [c for c, _ in COLUMNS] else 100)
    harness.write_csv(harness.RESULTS / "time_vs_error.csv",
                      [{k: r.get(k) for k in ["scene", *fields]} for r in rows])
    ref_keys = list(dict.fromkeys(k for v in refs.values() for k in v if k != "scene"))
    harness.write_csv(harness.RESULTS / "time_vs_error_refs.csv",
                      [{"scene": k, **{key: v.get(key) for key in ref_keys}}
                       for k, v in refs.items()])
    for scene_name in dict.fromkeys(r["scene"] for r in rows):
        plot(scene_name, [r for r in rows if r["scene"] == scene_name],
             harness.DOCS / "img" / f"pareto_{slug(scene_name)}.png")
    text = "\n\n".join([
        report(rows, refs),
        ("Rows: `bench/results/time_vs_error.csv`, `bench/results/time_vs_error_refs.csv`. "
         f"{merged}{harness.manifest('time_vs_error', argv, started, note)}")])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
