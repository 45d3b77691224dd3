"""Warm replanning: the goal of `seed-arm-plan` moved by up to 0.05 rad per joint, planned
from the earlier plan's primal-dual solution and from scratch, in the library and through
the service.

Library: one process; the base plan is solved first (it builds, and with `solver.jit`
compiles, the NLP, so every replan finds its structure cached), then each of `--moves`
random goals (every joint of the final state moved by a uniform draw from ±0.05 rad, seed
`--seed`) is planned with `plan(scene, warm_start=base)` and with `plan(scene)`. Service: a
live server (`make serve`'s command, its own store) plans the base scene, then each moved
goal is POSTed with `solver.warm_start` naming the base job and `?wait=`; then, on a fresh
server that planned the base, with `solver.warm_start: "nearest"` (memory of motion: the
nearest of the base and the goals planned before). The time is from sending the request to
having the verified plan in hand. Time to a verified plan counts the
whole plan: solves, mesh passes, interval check, replay, feedback and coupling along the plan.

    python -m bench replan [--moves 20] [--seed 7] [--no-jit] [--no-service]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench import harness
from planner.examples import example
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Warm replanning: a moved goal on the seed arm"
MOVE = 0.05  # [rad] largest change of each joint of the goal


def moved_requests(base: dict, moves: int, seed: int) -> list[dict]:
    """`moves` copies of the request with every final joint angle moved by U(-MOVE, MOVE)."""
    rng = np.random.default_rng(seed)
    final = base["task"]["final"]
    out = []
    for _ in range(moves):
        q = (np.asarray(final["q"]) + rng.uniform(-MOVE, MOVE, len(final["q"]))).tolist()
        out.append({**base, "task": {**base["task"], "final": {**final, "q": q}}})
    return out


def _row(kind: str, result, elapsed: float) -> dict:
    return {"kind": kind, "verified": bool(result.solver.success and result.verification.verified),
            "iterations": result.solver.iterations, "time": elapsed,
            "strategy": result.solver.strategy,
            "objective": result.objective}


def library(requests: list[dict], base: dict) -> list[dict]:
    """Warm and cold plans of each moved goal, in this process."""
    from planner import compiled
    from planner.ocp import plan

    first = plan(Scene.model_validate(base))
    compiled.wait()  # solver.jit: the structure's compiled kernels, built in the background
    first = plan(Scene.model_validate(base))
    rows = []
    for request in requests:
        scene = Scene.model_validate(request)
        for kind, warm in (("library, warm", first), ("library, cold", None)):
            started = time.perf_counter()
            result = plan(scene, warm_start=warm)
            rows.append(_row(kind, result, time.perf_counter() - started))
        rows.append(_replanned(Scene.model_validate(base), first, request))
    return rows


def _replanned(scene: Scene, earlier, moved: dict) -> dict:
    """A converged `Replanner` update to the moved goal from the plan's own state at a
    quarter of its motion (a fresh replanner on the cached NLP): its row, the update's
    wall time, "verified" when within the tolerance of its rows."""
    from planner.ocp.replan import Replanner
    from planner.scene import State

    at = earlier.duration / 4
    q_p, dq_p = earlier.states.polynomials()
    goal = State.model_validate(moved["task"]["final"])
    update = Replanner(scene, earlier).update(at, q_p([at])[0].tolist(), dq_p([at])[0].tolist(),
                                              mode="converged", goal=goal)
    return {"kind": "library, Replanner update (converged)",
            "verified": update.within and not update.fallback,
            "iterations": update.iterations, "time": update.wall,
            "strategy": "replanner", "objective": None}


def service(requests: list[dict], base: dict) -> list[dict]:
    """Warm plans of each moved goal through a live server (a fresh one for each kind),
    from the base job named and from the nearest plan the server holds (the base and the
    moved goals planned before): request to verified plan."""
    from testbed.service import LiveServer

    rows = []
    for kind in ("service, warm", "service, nearest"):
        with tempfile.TemporaryDirectory() as work, \
                LiveServer(Path(work) / "jobs.sqlite3", UNDERTOW_WORKERS="1") as server, \
                httpx.Client(base_url=server.url, timeout=120) as http:
            first = http.post("/v1/plans?wait=30", json=base).json()
            if first["status"] != "succeeded":
                raise RuntimeError(f"base plan: {first['status']}")
            for request in requests:
                start = first["id"] if kind == "service, warm" else "nearest"
                rows.append(_posted(http, kind, {**request, "solver": {
                    **request["solver"], "warm_start": start}}))
    return rows


def _posted(http: httpx.Client, kind: str, request: dict) -> dict:
    """POST one plan with ?wait=30: its row, timed from sending to the answer."""
    started = time.perf_counter()
    job = http.post("/v1/plans?wait=30", json=request).json()
    elapsed = time.perf_counter() - started
    plan = job.get("plan") or {}
    solver = plan.get("solver", {})
    return {"kind": kind,
            "verified": job["status"] == "succeeded"
            and plan.get("verification", {}).get("verified", False),
            "iterations": solver.get("iterations"), "time": elapsed,
            "strategy": solver.get("strategy"), "objective": plan.get("objective")}


def summary(rows: list[dict]) -> list[dict]:
    out = []
    for kind in dict.fromkeys(r["kind"] for r in rows):
        mine = [r for r in rows if r["kind"] == kind]
        ok = [r for r in mine if r["verified"]]
        out.append({"kind": kind, "plans": len(mine), "verified": len(ok),
                    "median": harness.median(r["time"] for r in ok),
                    "p90": float(np.percentile([r["time"] for r in ok], 90)) if ok else None,
                    "iterations": harness.median(r["iterations"] for r in mine),
                    "strategy": ", ".join(sorted({str(r["strategy"]) for r in mine}))})
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench replan", description=__doc__)
    parser.add_argument("--moves", type=int, default=20)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--no-jit", action="store_true", help="interpreted NLP functions")
    parser.add_argument("--no-service", action="store_true", help="the library only")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    base = example("seed-arm-plan").request
    base = {**base, "solver": {**base["solver"], "jit": not args.no_jit}}
    requests = moved_requests(base, args.moves, args.seed)
    rows = library(requests, base)
    if not args.no_service:
        rows += service(requests, base)
    harness.write_csv(harness.RESULTS / "replan.csv", rows)
    table = summary(rows)
    text = "\n\n".join([
        f"`seed-arm-plan` (4 links, g = 9.81, Legendre 3, 50 intervals) with "
        f"`solver.jit` {'off' if args.no_jit else 'on'}; {args.moves} goals, every joint of "
        f"the final state moved by up to {MOVE} rad (seed {args.seed}). Warm: "
        "`solver.warm_start` = the base plan (its primal-dual solution, the NLP cached); "
        "cold: the same request from the default initial guess. Times are to a verified plan "
        "(solves, mesh passes, interval check, replay, feedback, coupling along the plan); "
        "the service's from sending `POST /v1/plans?wait=30` to its answer. Replanner "
        "update: `planner.ocp.replan.Replanner` on the base plan, one converged update to "
        "the moved goal from the plan's own state at a quarter of its motion (the rest of "
        "the motion on the plan's 50 intervals, its LQR gains; counted as verified when its "
        "rows are within the solver's tolerance; no interval check).",
        harness.table(table, [("kind", "plans"), ("plans", "goals"), ("verified", "verified"),
                              ("median", "median time to a verified plan [s]"),
                              ("p90", "90th percentile [s]"),
                              ("iterations", "median iterations"),
                              ("strategy", "strategy")]),
        f"Rows: `bench/results/replan.csv`. {harness.manifest('replan', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    for row in table:
        print(row)
    return 0
