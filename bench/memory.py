"""Memory of motion: a plan started from its neighbour's against the same plan from scratch.

Bases: the built-in plan examples and the first task of every hard-suite category
(`testbed.suites.hard`, its own seed). Each base is planned cold; a verified base gets
`--variants` neighbours at each goal distance d of MOVES: every given final angle moved by a
uniform draw from [-d, d], one of them by exactly ±d, a tip target by d times the arm's
reach (NumPy generator seeded by the base's index, the variant and d), so that
`planner.memory.distance` to the base is d. A neighbour known infeasible before a solve is
left out. Each neighbour is planned cold (`plan(scene)`) and from the base
(`plan(scene, warm_start=base)`, what `solver.warm_start` "nearest" does in the service), in
this process, one after the other. Reported per distance: verified plans, median wall and
CPU time to a verified plan (unverified counted as never) of both, and how often the warm
plan ends at the cold plan's optimum (objectives within `SAME` relative), at a lower or at a
higher objective.

    python -m bench memory [--variants 2] [--moves 0.02,0.05,0.1,0.2,0.3] [--bases 12]
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import time

import numpy as np

from bench import harness
from planner import feasibility
from planner.examples import examples
from planner.ocp import Plan, plan
from planner.scene import Scene
from testbed.suites.hard import CATEGORIES, category, hard_tasks

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Memory of motion: plans started from a neighbour"
MOVES = (0.02, 0.05, 0.1, 0.2, 0.3)  # [rad] distance of a neighbour's goal from its base's
SAME = 1e-3  # relative objective difference within which two plans share an optimum


def bases() -> list[tuple[str, Scene]]:
    """The built-in plan examples and the first hard-suite task of every category."""
    out = [(e.name, Scene.model_validate(e.request)) for e in examples() if e.kind == "plan"]
    tasks = hard_tasks()
    for name in CATEGORIES:
        out.append(next((tid, s) for tid, s in tasks if category(tid) == name))
    return out


def neighbour(scene: Scene, move: float, rng: np.random.Generator) -> Scene:
    """The scene with every given final angle moved by U(-move, move), one by ±move; a tip
    target moved by move times the arm's reach in a random direction."""
    request = scene.model_dump(mode="json")
    target = request["task"]["tip_target"]
    if target is not None:
        angle = rng.uniform(0.0, 2.0 * math.pi)
        reach = move * sum(link["length"] for link in request["robot"]["links"])
        target["x"] = round(target["x"] + reach * math.cos(angle), 9)
        target["y"] = round(target["y"] + reach * math.sin(angle), 9)
    final = request["task"]["final"]["q"]
    given = [k for k, v in enumerate(final) if v is not None]
    if not given:
        return Scene.model_validate(request)
    offsets = rng.uniform(-move, move, len(given))
    offsets[rng.integers(len(given))] = move * rng.choice([-1.0, 1.0])
    for k, offset in zip(given, offsets, strict=True):
        final[k] = round(final[k] + float(offset), 9)
    return Scene.model_validate(copy.deepcopy(request))


def _timed(scene: Scene, warm_start: Plan | None) -> tuple[Plan, float, float]:
    cpu, started = harness.cpu_time(), time.perf_counter()
    result = plan(scene, warm_start=warm_start)
    return result, time.perf_counter() - started, harness.cpu_time() - cpu


def _verified(result: Plan) -> bool:
    return bool(result.solver.success and result.verification.verified)


def _optimum(warm: Plan, cold: Plan) -> str:
    """Where the warm plan ended against the cold one: same, lower, higher, or '–'."""
    a, b = warm.objective, cold.objective
    if not (_verified(warm) and _verified(cold)) or a is None or b is None:
        return "–"
    if abs(a - b) <= SAME * max(1.0, abs(b)):
        return "same"
    return "lower" if a < b else "higher"


def run(variants: int, moves: tuple[float, ...], count: int | None = None) -> list[dict]:
    """The rows of the first `count` bases (default all)."""
    rows = []
    for index, (name, scene) in enumerate(bases()[:count]):
        base, elapsed, _ = _timed(scene, None)
        print({"base": name, "verified": _verified(base), "time": elapsed}, flush=True)
        if not _verified(base):
            continue
        for move in moves:
            for variant in range(variants):
                rng = np.random.default_rng([index, variant, int(move * 1000)])
                moved = neighbour(scene, move, rng)
                row = {"base": name, "move": move, "variant": variant,
                       "feasible": not feasibility.check(moved)}
                if row["feasible"]:
                    cold, cold_time, cold_cpu = _timed(moved, None)
                    warm, warm_time, warm_cpu = _timed(moved, base)
                    row.update({"cold_verified": _verified(cold), "cold_time": cold_time,
                                "cold_cpu": cold_cpu, "cold_iterations": cold.solver.iterations,
                                "warm_verified": _verified(warm), "warm_time": warm_time,
                                "warm_cpu": warm_cpu, "warm_iterations": warm.solver.iterations,
                                "warm_strategy": warm.solver.strategy,
                                "cold_objective": cold.objective,
                                "warm_objective": warm.objective,
                                "optimum": _optimum(warm, cold)})
                rows.append(row)
                print(row, flush=True)
    return rows


def _median_time(rows: list[dict], kind: str) -> float | str:
    times = [r[f"{kind}_time"] if r[f"{kind}_verified"] else math.inf for r in rows]
    median = statistics.median(times) if times else math.nan
    return median if math.isfinite(median) else "never"


def summary(rows: list[dict]) -> list[dict]:
    out = []
    for move in sorted({r["move"] for r in rows}):
        mine = [r for r in rows if r["move"] == move and r["feasible"]]
        both = [r for r in mine if r["optimum"] != "–"]
        out.append({"move": move, "tasks": len(mine),
                    "cold_verified": sum(r["cold_verified"] for r in mine),
                    "warm_verified": sum(r["warm_verified"] for r in mine),
                    "cold_median": _median_time(mine, "cold"),
                    "warm_median": _median_time(mine, "warm"),
                    "cold_cpu": harness.median(r["cold_cpu"] for r in mine),
                    "warm_cpu": harness.median(r["warm_cpu"] for r in mine),
                    "warm_max": max((r["warm_time"] for r in mine), default=math.nan),
                    "same": sum(r["optimum"] == "same" for r in both),
                    "lower": sum(r["optimum"] == "lower" for r in both),
                    "higher": sum(r["optimum"] == "higher" for r in both)})
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench memory", description=__doc__)
    parser.add_argument("--variants", type=int, default=2)
    parser.add_argument("--moves", default=",".join(str(m) for m in MOVES))
    parser.add_argument("--bases", type=int, default=None,
                        help="plan around the first this many bases (default all)")
    args = parser.parse_args(argv)
    moves = tuple(float(m) for m in args.moves.split(","))
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.variants, moves, args.bases)
    harness.write_csv(harness.RESULTS / "memory.csv", rows)
    table = summary(rows)
    text = "\n\n".join([
        f"Bases: the built-in plan examples and the first task of every hard-suite category; "
        f"{args.variants} neighbours per base and goal distance d (every given final angle "
        "moved by up to d, one by exactly d). Cold: the neighbour planned from scratch; warm: "
        "from its base's plan (primal-dual where the NLP is the same problem), what "
        "`solver.warm_start: \"nearest\"` does. Time to a verified plan, unverified counted as "
        "never; CPU of this process and its companions. Optimum: the warm plan's objective "
        f"against the cold one's when both verified (same: within {SAME:g} relative).",
        harness.table(table, [("move", "d [rad]"), ("tasks", "neighbours"),
                              ("cold_verified", "cold verified"),
                              ("warm_verified", "warm verified"),
                              ("cold_median", "cold median [s]"),
                              ("warm_median", "warm median [s]"),
                              ("cold_cpu", "cold median CPU [s]"),
                              ("warm_cpu", "warm median CPU [s]"),
                              ("warm_max", "warm max [s]"), ("same", "same optimum"),
                              ("lower", "warm lower"), ("higher", "warm higher")]),
        f"Rows: `bench/results/memory.csv`. {harness.manifest('memory', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    for row in table:
        print(row)
    return 0
