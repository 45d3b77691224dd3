"""The task suite (planner.suite): how often a plan verifies, and how long a verified plan
takes, against the same planner with mesh refinement off, without retries or with fatrop
instead of Ipopt, and a plain CasADi Opti script (bench/peers/opti.py, Legendre degree 3
on the same 50 intervals).

Every configuration runs in a process of its own, its tasks one after the other as a
service worker would (NLPs built once per structure and number of intervals stay cached).
A plan counts as verified when Ipopt succeeded and every interval, re-integrated from the
plan's own state with its torque, lands on the plan within solver.resimulation_tolerance
(1e-3 rad); the Opti script's plans are checked by the same code. Time to a verified plan
is the wall time of the whole plan (build, every solve, mesh pass and retry, error
estimates and verification), counted only for verified plans.

    python -m bench suite [--count 48] [--seed 20261123] [--configs undertow,...]

`--seed` other than the suite's own writes its own section and CSV (suite-seed-N.csv):
tasks the planner was not tuned on.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import harness
from bench.examples import BEFORE
from planner.suite import COUNT, SEED, tasks

CONFIGS = {
    "undertow": "default settings",
    "refinement off": "transcription.refinement.enabled false",
    "retries off": "solver.retries 0",
    "fatrop": "solver.name fatrop",
    "before": f"the planner of {BEFORE}, before plans were refined and checked interval by "
              "interval (verified: the whole-horizon replay within 1e-3 rad)",
    "Opti script": "plain CasADi Opti, Legendre 3, 50 intervals, Ipopt defaults",
}
WALL_TIME = 60.0  # [s] every configuration's cap on one task (the planner's default)
DOC = harness.DOCS / "benchmarks.md"
SECTION = "Task suite: verified plans and time to a verified plan"


def _settings(config: str) -> dict:
    """Scene changes of a planner configuration."""
    return {"refinement off": {"transcription": {"refinement": {"enabled": False}}},
            "retries off": {"solver": {"retries": 0}},
            "fatrop": {"solver": {"name": "fatrop"}}}.get(config, {})


def _merged(scene: dict, changes: dict) -> dict:
    out = dict(scene)
    for key, value in changes.items():
        out[key] = _merged(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


def run_planner(config: str, count: int, seed: int) -> dict:
    """Every task with the planner in one configuration (in this process)."""
    from planner.ocp import plan
    from planner.scene import Scene

    rows = []
    for name, scene in tasks(count, seed):
        scene = Scene.model_validate(_merged(scene.model_dump(mode="json"), _settings(config)))
        started = time.perf_counter()
        result = plan(scene)
        elapsed = time.perf_counter() - started
        v, s = result.verification, result.solver
        ok = bool(s.success and v.verified)
        rows.append({"task": name, "config": config, "verified": ok, "status": s.status,
                     "iterations": s.iterations, "solves": len(result.mesh_passes),
                     "intervals": len(result.t) - 1, "time": elapsed,
                     "time_to_verified": elapsed if ok else math.nan,
                     "local_error": v.local_error, "resimulation_error": v.resimulation_error,
                     "growth_factor": v.growth_factor, "closed_loop_error": v.closed_loop_error,
                     "perturbed_closed_loop_error": v.perturbed_closed_loop_error,
                     "objective": result.objective, "strategy": s.strategy})
    return {"rows": rows}


def run_opti(count: int, seed: int) -> dict:
    """Every task with the plain Opti script (in this process)."""
    from bench.peers import opti

    rows = []
    for name, scene in tasks(count, seed):
        scene = scene.model_copy(update={"solver": scene.solver.model_copy(
            update={"max_wall_time": WALL_TIME})})
        started = time.perf_counter()
        out = opti.solve(scene)
        elapsed = time.perf_counter() - started
        ok = bool(out["success"] and out["local_error"] <= scene.solver.resimulation_tolerance)
        rows.append({"task": name, "config": "Opti script", "verified": ok,
                     "status": out["status"], "iterations": out["iterations"], "solves": 1,
                     "intervals": scene.transcription.intervals, "time": elapsed,
                     "time_to_verified": elapsed if ok else math.nan,
                     "local_error": out["local_error"],
                     "resimulation_error": out["resimulation_error"], "growth_factor": math.nan,
                     "closed_loop_error": math.nan, "perturbed_closed_loop_error": math.nan,
                     "objective": out["objective"], "strategy": "direct"})
    return {"rows": rows}


_BEFORE_RUN = """
import json, sys, time
sys.path.insert(0, {root!r})
from planner.ocp import plan
from planner.scene import Scene
for line in sys.stdin:
    name, scene = json.loads(line)
    started = time.perf_counter()
    result = plan(Scene.model_validate(scene))
    elapsed = time.perf_counter() - started
    v = result.verification
    print("RESULT " + json.dumps({{"task": name, "status": result.solver.status,
          "verified": bool(result.solver.success and v.verified),
          "iterations": result.solver.iterations, "time": elapsed,
          "resimulation_error": v.resimulation_error, "objective": result.objective}}),
          flush=True)
"""


def run_before(count: int, seed: int, commit: str) -> list[dict]:
    """Every task with the planner of an earlier commit (a temporary worktree)."""
    lines = "".join(json.dumps([name, scene.model_dump(mode="json", exclude_defaults=True)])
                    + "\n" for name, scene in tasks(count, seed))
    rows = []
    with tempfile.TemporaryDirectory() as work:
        old = Path(work) / "before"
        subprocess.run(["git", "-C", str(harness.ROOT), "worktree", "add", "--detach", str(old),
                        commit], check=True, capture_output=True)
        try:
            run = subprocess.run([harness.PYTHON, "-c", _BEFORE_RUN.format(root=str(old))],
                                 input=lines, cwd=old, capture_output=True, text=True,
                                 timeout=count * (2 * WALL_TIME + 30), check=False)
        finally:
            subprocess.run(["git", "-C", str(harness.ROOT), "worktree", "remove", "--force",
                            str(old)], check=False, capture_output=True)
    for line in run.stdout.splitlines():
        if line.startswith("RESULT "):
            out = json.loads(line[len("RESULT "):])
            rows.append({**out, "config": "before", "solves": 1, "intervals": 50,
                         "time_to_verified": out["time"] if out["verified"] else math.nan,
                         "local_error": math.nan, "growth_factor": math.nan,
                         "closed_loop_error": math.nan, "perturbed_closed_loop_error": math.nan,
                         "strategy": "direct"})
    if len(rows) != count:
        raise RuntimeError(f"before: {len(rows)} of {count} tasks ran: "
                           + (run.stderr.strip().splitlines() or ["no output"])[-1][:200])
    return rows


def _run(config: str, count: int, seed: int) -> list[dict]:
    timeout = count * (2 * WALL_TIME + 30)
    if config == "before":
        return run_before(count, seed, BEFORE)
    if config == "Opti script":
        out = harness.isolated("suite", "run_opti", {"count": count, "seed": seed}, timeout)
    else:
        out = harness.isolated("suite", "run_planner",
                               {"config": config, "count": count, "seed": seed}, timeout)
    if "failure" in out:
        raise RuntimeError(f"{config}: {out['failure']}")
    return out["rows"]


def _summary(rows: list[dict], config: str) -> dict:
    mine = [r for r in rows if r["config"] == config]
    times = [r["time_to_verified"] for r in mine if r["verified"]]
    verified = sum(r["verified"] for r in mine)
    every = sorted(r["time_to_verified"] if r["verified"] else math.inf for r in mine)
    middle = every[(len(every) - 1) // 2] if every else math.inf
    return {"config": config, "what": CONFIGS[config], "tasks": len(mine), "verified": verified,
            "share": f"{100 * verified / len(mine):.0f} %",
            "median_time": harness.median(times),
            "median_all": "never" if math.isinf(middle) else middle,
            "p90_time": float(np.percentile(times, 90)) if times else math.nan,
            "median_iterations": harness.median([r["iterations"] for r in mine]),
            "median_solves": harness.median([r["solves"] for r in mine])}


def _plot(rows: list[dict], configs: list[str]) -> None:
    from matplotlib.figure import Figure

    from planner.plots import PALETTE, render

    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for colour, config in zip(PALETTE["joints"], configs, strict=False):
        mine = [r for r in rows if r["config"] == config]
        times = np.sort([r["time_to_verified"] for r in mine if r["verified"]])
        share = np.arange(1, len(times) + 1) / len(mine)
        ax.step(np.concatenate([[1e-2], times]), np.concatenate([[0.0], share]), where="post",
                color=colour, label=config)
    ax.set_xscale("log")
    ax.set_xlabel("time to a verified plan [s]")
    ax.set_ylabel("share of the tasks verified")
    ax.set_ylim(0, 1.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    (harness.DOCS / "img").mkdir(parents=True, exist_ok=True)
    (harness.DOCS / "img" / "suite.png").write_bytes(render(fig))


def _task_table(rows: list[dict]) -> str:
    """Per task: the default planner's figures and the others' verdicts."""
    by = {(r["task"], r["config"]): r for r in rows}
    names = list(dict.fromkeys(r["task"] for r in rows))
    others = [c for c in CONFIGS if c != "undertow" and (names[0], c) in by]
    lines = []
    for name in names:
        r = by.get((name, "undertow"))
        if r is None:
            continue
        line = {"task": name, "ok": "yes" if r["verified"] else "no", "time": r["time"],
                "iterations": r["iterations"], "solves": r["solves"], "N": r["intervals"],
                "local": r["local_error"], "open": r["resimulation_error"],
                "growth": r["growth_factor"], "closed": r["closed_loop_error"],
                "perturbed": r["perturbed_closed_loop_error"], "strategy": r["strategy"]}
        for config in others:
            line[config] = "yes" if by[(name, config)]["verified"] else "no"
        lines.append(line)
    columns = [("task", "task"), ("ok", "verified"), ("time", "time [s]"),
               ("iterations", "iterations"), ("solves", "solves"), ("N", "intervals"),
               ("local", "interval error [rad]"), ("open", "open-loop replay [rad]"),
               ("growth", "growth factor"), ("closed", "closed-loop replay [rad]"),
               ("perturbed", "closed loop, perturbed start [rad]"), ("strategy", "strategy"),
               *((c, c) for c in others)]
    return harness.table(lines, columns)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench suite", description=__doc__)
    parser.add_argument("--count", type=int, default=COUNT)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--configs", default=",".join(CONFIGS),
                        help="comma-separated, from: " + ", ".join(CONFIGS))
    args = parser.parse_args(argv)
    configs = [c.strip() for c in args.configs.split(",")]
    started = time.perf_counter()
    note = harness.machine_note()
    rows = []
    for config in configs:
        print(f"running {config} on {args.count} tasks ...", flush=True)
        rows += _run(config, args.count, args.seed)
    own = args.seed == SEED
    csv = "suite.csv" if own else f"suite-seed-{args.seed}.csv"
    harness.write_csv(harness.RESULTS / csv, rows)
    summary = [_summary(rows, c) for c in configs]
    ours = next((r for r in summary if r["config"] == "undertow"), None)
    ratios = [f"{r['config']}: {r['median_all'] / ours['median_all']:.1f}x"
              for r in summary if ours and r is not ours and isinstance(r["median_all"], float)
              and isinstance(ours["median_all"], float)]
    if own:
        _plot(rows, configs)
    text = "\n\n".join(part for part in [
        f"{args.count} rest-to-rest tasks of `planner.suite` (seed {args.seed}): 2, 3 and 4 "
        "links, every passive/active split with at least as many active as passive joints, "
        "waves on about half of the active joints, g = 0 and g = 9.81 in turn, moves of up "
        "to 0.6 rad per joint across a waveless singularity where M_pa is square; 2 s, "
        "|tau| <= 20 N m, effort objective. A plan is verified when Ipopt succeeded and every "
        "interval re-integrates within 1e-3 rad; time to a verified plan is the wall time of "
        "the whole plan, counted for verified plans only.",
        harness.table(summary, [("config", "configuration"), ("what", "settings"),
                                ("tasks", "tasks"), ("verified", "verified"),
                                ("share", "share"),
                                ("median_time", "median time to a verified plan [s]"),
                                ("median_all", "the same, unverified counted as never [s]"),
                                ("p90_time", "90th percentile [s]"),
                                ("median_iterations", "median iterations"),
                                ("median_solves", "median solves")]),
        ("Median time to a verified plan (unverified counted as never) against the default "
         "planner's: " + "; ".join(ratios) + "." if ratios else ""),
        "![Share of the suite verified within a time](img/suite.png)" if own else "",
        "Per task, the default planner: the interval error is what `verified` judges; the "
        "open-loop replay runs the delivered torque from the planned start over the whole "
        "horizon, the growth factor is the largest norm of the state transition matrix "
        "along the plan, and the closed-loop replays add the plan's LQR feedback, from the "
        "planned start and from one perturbed by 1e-3 on every angle and rate.",
        _task_table(rows),
        f"Rows: `bench/results/{csv}`. {harness.manifest('suite', argv, started, note)}"]
        if part)
    harness.write_section(DOC, SECTION if own else f"{SECTION}, seed {args.seed}", text)
    for row in summary:
        print(row)
    return 0
