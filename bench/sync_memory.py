"""How much memory one synchronous computation takes: the measurements behind
app/sync_memory.py.

Each point runs one computation the way its route does (the library function, with the
server's default budget of 20 s, UNDERTOW_SYNC_WALL_TIME) in a fresh process, after the
imports, with cold caches: the symbolic dynamics and NLPs a computation builds are
counted, though a later request of the same structure would find them built. Memory is
the resident peak (VmHWM, reset through /proc/self/clear_refs just before) minus the
resident size before: what the request adds to the server while it runs, whichever
thread runs it. `kept` is what stayed resident after it (caches: built functions and
NLPs, bounded by their lru_cache sizes).

Robots: `testbed.robots.chain` (0.4 m, 1 kg links; even joints passive, odd active with
a wave); wave designs start from the same chain without waves. Compares
app/sync_memory.py's estimate with each point and writes bench/results/sync_memory.csv
(which tests/test_sync_memory.py checks the estimate against) and the section "Memory of
synchronous computations" of docs/deploy.md.

    python -m bench sync_memory [--points N]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import Any

from pydantic import BaseModel

from bench import harness
from testbed.robots import chain

SECTION = "Memory of synchronous computations"
BUDGET = 20.0  # [s] the server's default UNDERTOW_SYNC_WALL_TIME
TIMEOUT = 300.0
POINTS: list[tuple[str, int, int, int]] = [  # kind, links, size, option
    ("dynamics", 2, 100, 0),
    ("dynamics", 2, 10_000, 0),  # the library's most states
    ("dynamics", 8, 100, 0),
    ("dynamics", 8, 10_000, 0),
    ("coupling", 2, 441, 0),
    ("coupling", 2, 20_000, 0),
    ("coupling", 8, 2_000, 0),
    ("coupling", 8, 20_000, 0),
    ("inverse-dynamics", 2, 401, 0),
    ("inverse-dynamics", 2, 20_000, 0),
    ("inverse-dynamics", 8, 401, 0),
    ("inverse-dynamics", 8, 20_000, 0),
    ("simulate", 2, 101, 0),
    ("simulate", 2, 20_000, 0),
    ("simulate", 8, 101, 0),
    ("simulate", 8, 20_000, 0),
    ("waves-motion", 2, 2_001, 4),  # size: certification points; option: frequency_max
    ("waves-motion", 4, 2_001, 4),
    ("waves-motion", 6, 2_001, 3),
    ("waves-motion", 8, 2_001, 1),
    ("waves-motion", 8, 2_001, 3),
    ("waves-motion", 8, 20_000, 3),
    ("waves-region", 2, 20_000, 4),  # option: frequency_max; every axis free but at 8
    ("waves-region", 4, 20_000, 4),  # links with frequency_max 3, whose screening frees 4
    ("waves-region", 6, 20_000, 2),  # (within UNDERTOW_MAX_WAVE_SCREENING)
    ("waves-region", 8, 2_000, 1),
    ("waves-region", 8, 20_000, 1),
    ("waves-region", 8, 20_000, 3),
    ("waves-region", 8, 20_000, 2),  # a screening of 1.7 million: beyond the server's limit
    ("plot", 2, 2_000, 0),  # size: the plan's nodes
    ("plot", 8, 2_000, 0),
    ("sample", 8, 2_000, 1_000),  # option: times
]


def _passive(n: int) -> list[int]:
    return [k for k in range(n) if k % 2 == 0] if n > 1 else []


def _motion(n: int) -> dict:
    """A passive motion of every passive joint of `chain(n)`, 2 s, from rest."""
    passive, active = _passive(n), [k for k in range(n) if k % 2 == 1]
    return {"passive_motion": {"profile": "beta", "alpha": 3.0, "beta": 3.0,
                               "start": [0.1 * k for k in passive],
                               "end": [0.1 * k + 0.3 for k in passive]},
            "duration": 2.0,
            "active_initial": {"q": [1.6 + 0.1 * k for k in active], "dq": [0.0] * len(active)}}


def request(kind: str, links: int, size: int, option: int) -> dict[str, Any]:
    """The request body of one point (the plot and sample points: what makes their plan)."""
    robot = chain(links, True)
    if kind == "dynamics":
        return {"robot": robot, "states": [{"q": [0.001 * k + 0.1 * j for j in range(links)],
                                            "dq": [0.1] * links, "ddq": [0.0] * links}
                                           for k in range(size)]}
    if kind == "coupling":
        points = [math.ceil(size ** (1 / links))] * links
        j = 0
        while _product(points) > size:  # one axis after the other, down to `size` or below
            points[j % links] -= 1
            j += 1
        return {"robot": robot, "threshold": 1e-3,
                "grid": {"lower": [-1.0] * links, "upper": [1.0] * links, "points": points}}
    if kind == "inverse-dynamics":
        return {"robot": robot, **_motion(links), "samples": size}
    if kind == "simulate":
        na = len(robot["links"]) - len(_passive(links))
        per = min(100, size - 1)
        intervals = max(1, (size - 1) // per)
        t = [2.0 * k / intervals for k in range(intervals + 1)]
        return {"robot": robot, "t": t, "tau": [[0.1] * na for _ in t],
                "samples_per_interval": per,
                "initial": {"q": [0.1] * links, "dq": [0.0] * links}}
    if kind.startswith("waves"):
        base = chain(links, True)
        for link in base["links"]:
            link.pop("wave", None)
        body: dict[str, Any] = {"robot": base, "amplitude_max": 0.04, "frequency_max": option,
                                "margin": 0.01, "certification_points": size}
        if kind == "waves-motion":
            return {**body, "motion": _motion(links)}
        free = 4 if links == 8 and option == 3 else links
        return {**body, "region": {"lower": [0.1 * k for k in range(links)],
                                   "upper": [0.1 * k + 0.2 * (k < free) for k in range(links)]}}
    raise ValueError(f"no such kind {kind!r}")


def _product(values: list[int]) -> int:
    out = 1
    for v in values:
        out *= v
    return out


def synthetic_plan(links: int, nodes: int) -> tuple[Any, Any]:
    """A plan of `nodes` nodes (linear in time, cubic polynomials between them) of
    `chain(links)` with the planner's dense sampling, and its robot: what a plot or a
    sample of a large stored plan draws on."""
    import numpy as np

    from planner.model import Robot
    from planner.service import Plan

    robot = Robot.model_validate(chain(links, True))
    na = len(robot.active)
    t = np.linspace(0.0, 1.0, nodes)
    q = np.outer(t, np.ones(links))
    dense_t = np.linspace(0.0, 1.0, max(2000, 4 * (nodes - 1)))
    dense_q = np.outer(dense_t, np.ones(links))
    cubic = [[[0.0] * links, [t[1] - t[0]] * links, [0.0] * links, [0.0] * links]
             for _ in range(nodes - 1)]
    torque = [[[0.0] * na] * 4 for _ in range(nodes - 1)]
    plan = Plan.model_validate({
        "t": t.tolist(), "q": q.tolist(), "dq": np.ones_like(q).tolist(),
        "ddq": np.zeros_like(q).tolist(), "tau": np.zeros((nodes, na)).tolist(),
        "dense": {"t": dense_t.tolist(), "q": dense_q.tolist(),
                  "tau": np.zeros((len(dense_t), na)).tolist()},
        "torque": {"breaks": t.tolist(), "coefficients": torque},
        "states": {"breaks": t.tolist(), "q": [[list(map(float, q[k])), *c[1:]]
                                               for k, c in enumerate(cubic)],
                   "dq": [[[1.0] * links, [0.0] * links, [0.0] * links, [0.0] * links]
                          for _ in cubic]},
        "duration": 1.0, "objective": 1.0, "waves": [],
        "solver": {"status": "Solve_Succeeded", "success": True, "message": "",
                   "iterations": 1, "build_time": 0.0, "solve_time": 0.0, "cache_hit": False},
        "verification": {"resimulation_error": 0.0, "resimulation_status": "completed",
                         "defect": 0.0, "min_sigma": 0.1, "waveless_min_sigma": 0.0,
                         "waveless_singular_crossings": [],
                         "sigma_min": [0.1] * len(dense_t),
                         "waveless_sigma_min": [0.05] * len(dense_t)}})
    return plan, robot


def point(kind: str, links: int, size: int, option: int) -> dict:
    """One point in this (fresh) process: peak and kept resident memory [MB], time [s]."""
    from app.procmem import status_mb
    from app.sync_memory import PLAN_SAMPLE_MB, PLOT_MB, estimate_mb
    from planner import coupling, evaluation, inverse, plots, simulate, waves
    from planner.budget import BudgetExceeded

    runs: dict[str, tuple[Callable[..., Any], type[BaseModel]]] = {
        "dynamics": (evaluation.evaluate, evaluation.DynamicsRequest),
        "coupling": (coupling.analyse, coupling.CouplingRequest),
        "inverse-dynamics": (inverse.solve, inverse.InverseDynamicsRequest),
        "simulate": (simulate.run, simulate.SimulationRequest),
        "waves-motion": (waves.design, waves.WaveDesignRequest),
        "waves-region": (waves.design, waves.WaveDesignRequest)}
    if kind in runs:
        function, model = runs[kind]
        body = model.model_validate(request(kind, links, size, option))
        estimate = estimate_mb(body)

        def compute() -> None:
            function(body, deadline=time.monotonic() + BUDGET)
    else:
        plan, robot = synthetic_plan(links, size)
        estimate = PLOT_MB if kind == "plot" else PLAN_SAMPLE_MB

        def compute() -> None:
            if kind == "plot":
                plots.plan_plot(plan, robot, "png")
            else:
                plan.sample(robot, [k / (option - 1) for k in range(option)])
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # VmHWM := VmRSS
    before, started, outcome = status_mb("VmRSS"), time.perf_counter(), "completed"
    try:
        compute()
    except BudgetExceeded:
        outcome = "budget-exceeded"
    return {"peak": status_mb("VmHWM") - before, "kept": status_mb("VmRSS") - before,
            "time": time.perf_counter() - started, "outcome": outcome, "estimate": estimate,
            "rss_imports": before}


COLUMNS = [("kind", "computation"), ("links", "links"), ("size", "size"),
           ("option", "option"), ("outcome", "outcome"), ("time", "time [s]"),
           ("peak", "peak [MB]"), ("kept", "kept [MB]"), ("estimate", "estimate [MB]"),
           ("ratio", "peak / estimate"), ("failure", "failure")]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench sync_memory", description=__doc__)
    parser.add_argument("--points", type=int, default=len(POINTS),
                        help="measure the first this many points")
    args = parser.parse_args(argv)
    started, note, rows = time.perf_counter(), harness.machine_note(), []
    for kind, links, size, option in POINTS[:args.points]:
        spec = {"kind": kind, "links": links, "size": size, "option": option}
        row = {**spec, "load": harness.load(), **harness.isolated("sync_memory", "point", spec,
                                                                 TIMEOUT)}
        if "peak" in row:
            row["ratio"] = row["peak"] / row["estimate"]
        rows.append(row)
        print(row, flush=True)
    harness.write_csv(harness.RESULTS / "sync_memory.csv", [{k: r.get(k) for k in [
        "kind", "links", "size", "option", "outcome", "time", "peak", "kept", "estimate",
        "ratio", "rss_imports", "load", "failure"]} for r in rows])
    text = "\n\n".join([
        ("Each point runs one synchronous computation as its route does, with the default "
         "budget of 20 s, in a fresh process with cold caches; *peak* is how far its "
         "resident memory rose above its size before, *kept* what stayed after it (built "
         "functions and NLPs in the library's caches). *Size*: states, grid points (the "
         "grid's product of axes is at most this), samples, returned samples, "
         "certification points, or the plan's nodes; *option*: "
         "a wave design's `frequency_max` (a region design frees every axis, but 4 of 8 at "
         "3; its last row screens 1.7 million configurations, beyond the server's "
         "`UNDERTOW_MAX_WAVE_SCREENING`), a sample's times. Robots: chains of 0.4 m, 1 kg "
         "links, even joints passive. *Estimate*: "
         "`app/sync_memory.py`, whose constants keep it at or above every measured peak: "
         "what a request reserves of `UNDERTOW_SYNC_MEMORY_MB` while it runs."),
        harness.table(rows, COLUMNS),
        f"Rows: `bench/results/sync_memory.csv`. "
        f"{harness.manifest('sync_memory', argv, started, note)}"])
    print(text)
    harness.write_section(harness.DOCS / "deploy.md", SECTION, text)
    return 0
