"""Two solver processes at once, with the solver's OpenBLAS on its own thread count or on
one thread: does MUMPS' BLAS, a thread per core by default, slow the solves down where
every core already holds one?

The first `--count` tasks of the hard suite (`testbed.suites.hard`, `--seed`), stated as
`python -m bench suite --suite hard` states them (with its uncertainty), split between two
processes that plan their halves at the same time (tasks alternating), as two solver
workers of the service do on a 2-core machine: each plan alone
(UNDERTOW_SOLVER_PROCESSES=1, no companion), with core tokens of their own. Two
configurations in rounds, the order alternating (own, one, one, own, ...) so that neither
always runs first: "own", the planner's (OpenBLAS' own count: a thread per core), and "one
thread" (OPENBLAS_NUM_THREADS=1). The compiled kernels are built before the first round.
Per task and round: wall and CPU time of the plan (the NLP's build in its first plan
included, alike in both), iterations, verified, the threads OpenBLAS ran; per
configuration: verified plans, the median and 90th percentile over the tasks of each
task's median time, and the median round's makespan (the later of its two processes).

    python -m bench blas_threads [--seed S] [--count 48] [--rounds 4]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from bench import harness, suite
from testbed.suites import hard

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Two solver processes at once: the solver's BLAS threads"
CSV = harness.RESULTS / "blas_threads.csv"
CONFIGS = {"own": "the planner's: OpenBLAS' own count, a thread per core",
           "one thread": "OPENBLAS_NUM_THREADS=1"}
PROCESSES = 2

_RUN = """
import json, os, sys, tempfile, time
config, seed, indices = json.loads(sys.argv[1])
os.environ["UNDERTOW_SOLVER_PROCESSES"] = "1"
os.environ["UNDERTOW_CORE_DIR"] = tempfile.mkdtemp(prefix="undertow-cores-")
os.environ.pop("OPENBLAS_NUM_THREADS", None)
if config == "one thread":  # read by OpenBLAS when the first solver loads it
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, {root!r})
import ctypes, pathlib
import casadi
from bench import harness
from bench.suite import with_uncertainty
from planner.ocp import plan
from planner.scene import Scene
from testbed.suites import hard
def threads():
    lib = pathlib.Path(casadi.__file__).resolve().parent / "libcasadi-tp-openblas.so.0"
    return ctypes.CDLL(str(lib)).openblas_get_num_threads() if lib.exists() else None
rows = []
for index in indices:
    name, scene = hard.hard_task(index, seed)
    scene = Scene.model_validate(with_uncertainty(scene.model_dump(mode="json")))
    cpu, started = harness.cpu_time(), time.perf_counter()
    result = plan(scene)
    wall, cpu = time.perf_counter() - started, harness.cpu_time() - cpu
    rows.append({{"task": name, "wall": wall, "cpu": cpu,
                  "iterations": result.solver.iterations,
                  "verified": bool(result.solver.success and result.verification.verified),
                  "threads": threads()}})
print("RESULT " + json.dumps({{"rows": rows}}))
"""


def order(rounds: int) -> list[str]:
    """The configuration of each round: own, one, one, own, own, one, ..."""
    pair = list(CONFIGS)
    return [pair[(r + r // 2) % 2] for r in range(rounds)]


def one_round(config: str, seed: int, count: int, number: int) -> list[dict]:
    """Both processes' rows of one round, each with its round, process and makespan."""
    halves = [list(range(p, count, PROCESSES)) for p in range(PROCESSES)]
    code = _RUN.format(root=str(harness.ROOT))
    started = time.perf_counter()

    def run(indices: list[int]) -> tuple[dict, float]:
        out = harness.run_at(harness.ROOT, code, [json.dumps([config, seed, indices])],
                             len(indices) * 200.0)
        return out, time.perf_counter() - started

    with ThreadPoolExecutor(PROCESSES) as pool:
        outs = list(pool.map(run, halves))
    rows = []
    for process, (out, _) in enumerate(outs):
        if "failure" in out:
            raise RuntimeError(f"{config}, round {number}: {out['failure']}")
        rows += [{**r, "config": config, "round": number, "process": process,
                  "makespan": max(t for _, t in outs)} for r in out["rows"]]
    return rows


def summary(rows: list[dict], config: str) -> dict:
    """Verified plans, per-task medians over the rounds, and the median makespan."""
    mine = [r for r in rows if r["config"] == config]
    tasks = sorted({r["task"] for r in mine})
    wall = [statistics.median(r["wall"] for r in mine if r["task"] == t) for t in tasks]
    cpu = [statistics.median(r["cpu"] for r in mine if r["task"] == t) for t in tasks]
    makespans = {r["round"]: r["makespan"] for r in mine}
    return {"config": config, "what": CONFIGS[config], "threads": mine[0]["threads"],
            "rounds": len(makespans), "plans": len(mine),
            "verified": sum(r["verified"] for r in mine),
            "median": statistics.median(wall), "p90": float(np.percentile(wall, 90)),
            "worst": max(wall), "cpu": statistics.median(cpu),
            "iterations": statistics.median(r["iterations"] for r in mine),
            "makespan": statistics.median(makespans.values())}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench blas_threads", description=__doc__)
    parser.add_argument("--seed", type=int, default=hard.SEED)
    parser.add_argument("--count", type=int, default=hard.COUNT)
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    suite.build_ahead("hard", args.count, args.seed, (), {})  # before any round is timed
    rows: list[dict] = []
    for number, config in enumerate(order(args.rounds)):
        print(f"round {number}: {config}", flush=True)
        rows += one_round(config, args.seed, args.count, number)
    table = [summary(rows, c) for c in CONFIGS if any(r["config"] == c for r in rows)]
    text = "\n\n".join([
        f"The first {args.count} tasks of the hard suite (seed {args.seed}, each with the "
        "suite bench's uncertainty), split between two processes that plan their halves at "
        "the same time, as two solver workers do on a 2-core machine: each plan alone "
        "(no companion). Rounds alternate the configurations "
        f"({', '.join(order(args.rounds))}). Times per task are its median over its "
        "configuration's rounds (the NLP's build in a process's first plan of a structure "
        "included, alike in both); the makespan is a round's wall time, the later of its two "
        "processes; CPU counts each plan's process. `python -m bench suite --suite hard "
        "--configs 'undertow,one BLAS thread'` compares the same two where a plan has the "
        "machine to itself and its companion.",
        harness.table(table, [("config", "configuration"), ("what", "setting"),
                              ("threads", "OpenBLAS threads"), ("rounds", "rounds"),
                              ("plans", "plans"), ("verified", "verified"),
                              ("median", "median time [s]"), ("p90", "90th percentile [s]"),
                              ("worst", "worst [s]"), ("cpu", "median CPU [s]"),
                              ("iterations", "median iterations"),
                              ("makespan", "median makespan [s]")]),
        f"Rows: `bench/results/blas_threads.csv`. "
        f"{harness.manifest('blas_threads', argv, started, note)}"])
    print(text)
    harness.write_csv(CSV, rows)
    harness.write_section(DOC, SECTION, text)
    return 0
