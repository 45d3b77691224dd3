"""The planner against a plain CasADi Opti script (bench/peers/opti.py), in one run.

Scene (`--scene`): "seed-hang", the seed's 4-link arm hanging in gravity, rest to rest in
1.6 s across the waveless singularity with coupling margin 0.005 (the default), or
"seed-4", the same arm in a horizontal plane, rest to rest in 4 s with coupling margin 0.02
(bench/scenes.py); Legendre collocation of degree 3 at each N given. Both start from the
planner's initial guess (`hermite_guess`) and have the same limits (3000 iterations,
Ipopt's default, and 600 s); the planner makes one solve per plan (mesh refinement and
retries off), as the script does. For each N:

- planner, cold: the caches of NLPs and of their stages cleared, one `plan()` (build +
  solve);
- planner, warm: `plan()` again `--repeats` times on the cached NLP (median);
- planner, explicit form: the same, with forward dynamics instead of accelerations as
  variables (the formulation of the baseline), to separate formulation from machinery;
- planner, compiled: the default form with `solver.jit` (the stages' derivative kernels
  compiled to C; the cold row includes the compilation, skipped when the compiled
  library is already on disk);
- baseline: built once, solved `--baseline-repeats` times from the same guess (median).

Reported: build time, solve time (Ipopt wall time), iterations, objective, interval
error, open-loop replay error and defect (the planner's verification applied to both),
and the solve-time ratio baseline / planner; then where the planner's solve time goes
(CasADi's per-function statistics, the rest being Ipopt's own linear algebra). Writes the
scene's section of docs/benchmarks.md ("Planner vs a plain Opti script" for seed-4,
"...: seed arm hanging" for seed-hang) and bench/results/planner_speed.csv
(planner_speed_hanging.csv).

    python -m bench planner_speed [--scene seed-hang] [--N 100 50] [--repeats 5]
        [--baseline-repeats 3]
"""

from __future__ import annotations

import argparse
import math
import time

from bench import harness
from bench.peers import opti as baseline_opti
from bench.scenes import make_scene
from planner.ocp import Plan, plan
from planner.ocp.problem import cached_problem, stages

OUTPUTS = {"seed-hang": ("Planner vs a plain Opti script: seed arm hanging",
                         "planner_speed_hanging.csv"),
           "seed-4": ("Planner vs a plain Opti script", "planner_speed.csv")}
"""Per scene: its section of docs/benchmarks.md and its CSV in bench/results."""
BUDGET = {"max_iter": 3000, "max_wall_time": baseline_opti.WALL_CAP}
"""The planner's limits here: the baseline's (Ipopt's default iteration limit, its wall cap)."""
COLUMNS = [("N", "N"), ("who", "solver"), ("build", "build [s]"), ("solve", "solve [s]"),
           ("solve_min", "fastest [s]"), ("cpu", "solve CPU [s]"), ("runs", "runs"),
           ("iterations", "iterations"), ("per_iteration", "CPU per iteration [ms]"),
           ("status", "status"), ("objective", "objective"),
           ("interval_error", "interval error [rad]"), ("replay_error", "open-loop replay [rad]"),
           ("defect", "defect [N m s]"), ("ratio", "baseline / this, wall"),
           ("cpu_ratio", "baseline / this, CPU")]
PROFILE = [("t_wall_nlp_hess_l", "Hessian of the Lagrangian"),
           ("t_wall_nlp_jac_g", "constraint Jacobian"), ("t_wall_nlp_g", "constraints"),
           ("t_wall_nlp_grad_f", "objective gradient"), ("t_wall_nlp_f", "objective"),
           ("t_wall_callback_fun", "iteration callback")]


def planner_rows(name: str, N: int, repeats: int, form: str,
                 jit: bool = False) -> tuple[dict, dict]:
    """Cold and warm rows of the planner on scene `name` at N (form: implicit or explicit;
    jit: compiled NLP), and the CasADi statistics of its last solve."""
    scene = make_scene(name, N=N, form=form, one_solve=True, solver={"jit": jit, **BUDGET})
    cached_problem.cache_clear()
    stages.cache_clear()
    started = time.perf_counter()
    build_time, solver = harness.build_instrumented(scene)
    cold = plan(scene)
    name = "planner" if form == "implicit" else "planner, explicit form"
    name += ", compiled" if jit else ""
    rows = {"cold": {**_plan_row(N, f"{name}, cold", cold, time.perf_counter() - started),
                     "build": build_time, "cpu": solver.cpu}}
    warm: list[tuple[Plan, float, float]] = []
    cpus = []
    for _ in range(repeats):
        result, wall, cpu = harness.timed(lambda: plan(scene))
        assert isinstance(result, Plan)
        warm.append((result, wall, cpu))
        cpus.append(solver.cpu)
    solves = [p.solver.solve_time for p, _, _ in warm]
    last = warm[-1][0]
    rows["warm"] = {**_plan_row(N, f"{name}, warm", last,
                                harness.median(w for _, w, _ in warm)),
                    "solve": harness.median(solves), "solve_min": min(solves), "runs": repeats,
                    "cpu": harness.median(cpus)}
    stats = dict(solver.stats())
    stats["solve_time"] = last.solver.solve_time
    return rows, stats


def _plan_row(N: int, who: str, p: Plan, wall: float) -> dict:
    v = p.verification
    return {"N": N, "who": who, "build": p.solver.build_time, "solve": p.solver.solve_time,
            "solve_min": p.solver.solve_time, "runs": 1, "iterations": p.solver.iterations,
            "status": p.solver.status, "objective": p.objective,
            "interval_error": v.local_error, "replay_error": v.resimulation_error,
            "defect": v.defect, "plan_wall": wall,
            "crossings": len(v.waveless_singular_crossings), "min_sigma": v.min_sigma}


def baseline_row(name: str, N: int, repeats: int) -> tuple[dict, dict]:
    """The baseline on scene `name`, built once and solved `repeats` times; its last
    statistics."""
    scene = make_scene(name, N=N)
    built = baseline_opti.build(scene)
    runs = [baseline_opti.solve(scene, built) for _ in range(repeats)]
    solves = [r["solve_time"] for r in runs]
    first, last = runs[0], runs[-1]
    row = {"N": N, "who": "baseline (Opti)", "build": first["build_time"],
           "solve": harness.median(solves), "solve_min": min(solves), "runs": repeats,
           "iterations": last["iterations"], "status": last["status"],
           "objective": last["objective"], "interval_error": last["local_error"],
           "replay_error": last["resimulation_error"], "defect": last["defect"],
           "cpu": harness.median(r["cpu_time"] for r in runs)}
    stats = {**last["stats"], "solve_time": last["solve_time"]}
    return row, stats


def profile_rows(N: int, who: str, stats: dict) -> list[dict]:
    """Where one solve's wall time went: CasADi's per-function times, the rest in Ipopt."""
    total = stats["solve_time"]
    rows, used = [], 0.0
    for key, label in PROFILE:
        value = float(stats.get(key, 0.0))
        calls = stats.get("n_call_" + key.split("_", 2)[2])
        used += value
        rows.append({"N": N, "who": who, "part": label, "time": value, "share": value / total,
                     "calls": calls, "per_call": value / calls * 1e3 if calls else None})
    rest = total - used
    rows.append({"N": N, "who": who, "part": "Ipopt itself (KKT factorization, line search)",
                 "time": rest, "share": rest / total, "calls": stats.get("iter_count"),
                 "per_call": rest / stats["iter_count"] * 1e3 if stats.get("iter_count") else None})
    return rows


def run(name: str, grid: list[int], repeats: int,
        baseline_repeats: int) -> tuple[list[dict], list[dict], list[str]]:
    rows, profile, loads = [], [], [harness.load()]
    for N in grid:
        planner, p_stats = planner_rows(name, N, repeats, "implicit")
        explicit, _ = planner_rows(name, N, repeats, "explicit")
        compiled, c_stats = planner_rows(name, N, repeats, "implicit", jit=True)
        base, b_stats = baseline_row(name, N, baseline_repeats)
        loads.append(harness.load())
        for row in (planner["cold"], planner["warm"], explicit["cold"], explicit["warm"],
                    compiled["cold"], compiled["warm"], base):
            row["ratio"] = base["solve"] / row["solve"] if row["solve"] else math.nan
            row["cpu_ratio"] = base["cpu"] / row["cpu"] if row["cpu"] else math.nan
            row["per_iteration"] = 1e3 * row["cpu"] / max(1, row["iterations"])
            rows.append(row)
        profile += profile_rows(N, "planner, warm", p_stats)
        profile += profile_rows(N, "planner, compiled, warm", c_stats)
        profile += profile_rows(N, "baseline", b_stats)
        print(harness.table(rows[-7:], COLUMNS), flush=True)
    return rows, profile, loads


def report(rows: list[dict], profile: list[dict], loads: list[str]) -> str:
    prof_cols = [("N", "N"), ("who", "solver"), ("part", "part"), ("time", "wall [s]"),
                 ("share", "share"), ("calls", "calls"), ("per_call", "per call [ms]")]
    return "\n\n".join([
        (f"Load averages after each N: {'; '.join(loads[1:])}. `solve` is the median Ipopt "
         "wall time over `runs` solves from the same initial guess (`fastest` their "
         "minimum), `solve CPU` the median CPU time of the same solves (what the machine's "
         "other load disturbs least); the planner makes one solve per plan (refinement and "
         "retries off), its warm rows reuse the cached NLP, the baseline's repeats reuse its "
         "built Opti problem; cold rows are one build and one solve. The ratios divide the "
         "baseline's median by the row's."),
        harness.table(rows, COLUMNS),
        ("Where one solve's wall time goes (CasADi's per-function statistics of the last "
         "solve; the rest is Ipopt's own work, mostly the sparse KKT factorizations and "
         "back-solves in MUMPS):"),
        harness.table(profile, prof_cols),
    ])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench planner_speed", description=__doc__)
    parser.add_argument("--scene", choices=sorted(OUTPUTS), default="seed-hang")
    parser.add_argument("--N", type=int, nargs="+", default=[100, 50])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-repeats", type=int, default=3)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows, profile, loads = run(args.scene, args.N, args.repeats, args.baseline_repeats)
    section, csv_name = OUTPUTS[args.scene]
    text = "\n\n".join([
        report(rows, profile, loads),
        f"Rows: `bench/results/{csv_name}`. "
        f"{harness.manifest('planner_speed', argv, started, note)}"])
    print(text)
    harness.write_csv(harness.RESULTS / csv_name, rows)
    harness.write_section(harness.DOCS / "benchmarks.md", section, text)
    return 0
