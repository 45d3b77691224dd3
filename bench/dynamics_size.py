"""Size and speed of the derived dynamics for the seed's 4-link arm (and an 8-link chain).

For each variant (waves on/off, gravity on/off): expression nodes of M, h and forward
dynamics (CasADi Function.n_nodes), the time to build a structure's functions (derivation
and Function construction, uncached, median of `--builds`), the median time of one
evaluation of M and h (`--calls` calls, median of `--repeats`) through the raw CasADi
Function and through planner.dynamics.Dynamics, and the cost of a cache hit:
`functions(structure)` for a structure already built, and constructing `Dynamics` for a
second robot of that structure. Writes the section "The seed arm and an 8-link chain" of
docs/bench-dynamics.md.

    python -m bench dynamics_size [--calls 2000] [--repeats 7] [--builds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from bench import harness
from planner.dynamics import Dynamics, functions
from planner.examples import VERTICAL_SEED_ARM
from planner.model import Robot, Structure

DOC = harness.DOCS / "bench-dynamics.md"
SECTION = "The seed arm and an 8-link chain"
MAPPED = 1000  # states of one mapped call

clock = time.process_time  # CPU time of this process: steadier than wall time on a shared machine


def median_call(fn: Callable[[], object], calls: int, repeats: int) -> float:
    """Median over repeats of the mean CPU time of one call [s]."""
    times = []
    for _ in range(repeats):
        start = clock()
        for _ in range(calls):
            fn()
        times.append((clock() - start) / calls)
    return statistics.median(times)


def build_time(s: Structure, builds: int) -> float:
    """Median CPU time [s] to derive and build a structure's functions, bypassing the cache."""
    times = []
    for _ in range(builds):
        start = clock()
        functions.__wrapped__(s)
        times.append(clock() - start)
    return statistics.median(times)


def chain(n: int) -> Robot:
    """n links of 0.3 m, 0.5 kg, 0.005 kg m^2; odd joints active with wave (0.03 m, 3, 0.2)."""
    links = [{"length": 0.3, "mass": 0.5, "inertia": 0.005,
              "joint": "active" if k % 2 else "passive",
              **({"wave": {"amplitude": 0.03, "frequency": 3.0, "phase": 0.2}} if k % 2 else {})}
             for k in range(n)]
    return Robot.model_validate({"links": links, "gravity": 9.81})


def variants() -> list[tuple[str, Robot]]:
    seed = Robot.model_validate(VERTICAL_SEED_ARM)
    return [
        ("seed, waves, gravity", seed),
        ("seed, waves, g = 0", seed.model_copy(update={"gravity": 0.0})),
        ("seed, no waves, gravity", seed.without_waves()),
        ("seed, no waves, g = 0", seed.without_waves().model_copy(update={"gravity": 0.0})),
        ("8-link chain, waves, gravity", chain(8)),
    ]


def size_row(name: str, robot: Robot, builds: int) -> dict:
    s = Structure.of(robot)
    f = functions(s)
    return {"variant": name, **{f"nodes_{k}": f[k].n_nodes() for k in ("M", "h", "fd")},
            "build_ms": build_time(s, builds) * 1e3}


def speed_row(name: str, robot: Robot, rng: np.random.Generator, calls: int,
              repeats: int) -> dict:
    s = Structure.of(robot)
    f, dyn = functions(s), Dynamics(robot)
    q, dq = rng.uniform(-np.pi, np.pi, s.n), rng.uniform(-2, 2, s.n)
    Q, dQ = rng.uniform(-np.pi, np.pi, (s.n, MAPPED)), rng.uniform(-2, 2, (s.n, MAPPED))
    M_map, h_map = f["M"].map(MAPPED), f["h"].map(MAPPED)
    p = dyn.p
    us = 1e6
    mapped = max(1, calls // 100)
    return {"variant": name,
            "M": median_call(lambda: f["M"](q, p), calls, repeats) * us,
            "h": median_call(lambda: f["h"](q, dq, p), calls, repeats) * us,
            "mass_matrix": median_call(lambda: dyn.mass_matrix(q), calls, repeats) * us,
            "bias": median_call(lambda: dyn.bias(q, dq), calls, repeats) * us,
            "M_map": median_call(lambda: M_map(Q, p), mapped, repeats) / MAPPED * us,
            "h_map": median_call(lambda: h_map(Q, dQ, p), mapped, repeats) / MAPPED * us}


def cache_rows(calls: int, repeats: int) -> list[dict]:
    """Cost [us] of a cache hit for a second robot of the seed arm's structure."""
    first = Robot.model_validate(VERTICAL_SEED_ARM)
    second = first.model_copy(update={"links": [
        link.model_copy(update={"length": 1.1 * link.length}) for link in first.links]})
    s = Structure.of(second)
    assert s == Structure.of(first)
    functions(s)
    before = functions.cache_info()
    lookup = median_call(lambda: functions(s), calls, repeats)
    construct = median_call(lambda: Dynamics(second), max(1, calls // 4), repeats)
    after = functions.cache_info()
    assert after.misses == before.misses
    return [{"operation": "`functions(structure)`, structure already built", "time": lookup * 1e6},
            {"operation": "`Dynamics(robot)`, second robot of a built structure",
             "time": construct * 1e6}]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench dynamics_size", description=__doc__)
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--builds", type=int, default=5)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rng = np.random.default_rng(7)
    sizes = [size_row(name, robot, args.builds) for name, robot in variants()]
    speeds = [speed_row(name, robot, rng, args.calls, args.repeats)
              for name, robot in variants()]
    cache = cache_rows(args.calls, args.repeats)
    text = "\n\n".join([
        ("The seed's 4-link arm (lengths 0.5, 0.4, 0.4, 0.3 m; masses 1.0, 0.8, 0.6, 0.4 kg; "
         "inertias 0.01, 0.008, 0.006, 0.004 kg m^2; waves (0.05 m, 3, 0.3) on joint 1 and "
         "(0.04 m, 4, 0.1) on joint 3, 0-based; g = 9.81 m/s^2), with and without its waves "
         "and gravity, and an 8-link chain for scale (0.3 m, 0.5 kg, 0.005 kg m^2 per link, "
         "odd joints active with wave (0.03 m, 3, 0.2))."),
        ("Nodes: `Function.n_nodes()` of M, h and forward dynamics `fd` (M^-1 (B tau - h), "
         "solved symbolically). Build: derivation plus construction of all of a structure's "
         f"functions, uncached, median of {args.builds}. All times are CPU time of the "
         "benchmark process (`time.process_time`), which other load on the machine disturbs "
         "less than wall time."),
        harness.table(sizes, [("variant", "variant"), ("nodes_M", "nodes M"),
                              ("nodes_h", "nodes h"), ("nodes_fd", "nodes fd"),
                              ("build_ms", "build [ms]")]),
        (f"Evaluation at one random state: mean of {args.calls} calls, median of "
         f"{args.repeats} repeats, in microseconds per call. `Function`: the raw CasADi call "
         "with NumPy arguments; `Dynamics`: the NumPy-facing method (conversion included); "
         f"`map`: the Function mapped over {MAPPED} states in one call, per state."),
        harness.table(speeds, [("variant", "variant"), ("M", "M Function"),
                               ("h", "h Function"), ("mass_matrix", "Dynamics.mass_matrix"),
                               ("bias", "Dynamics.bias"), ("M_map", "M map, per state"),
                               ("h_map", "h map, per state")]),
        "Cache hit (a second robot with other numbers but the same structure):",
        harness.table(cache, [("operation", "operation"), ("time", "time [us]")]),
        ("Reading: a single call costs tens of microseconds whatever the structure, mostly "
         "CasADi's call overhead; the expression size shows in the mapped, per-state cost. "
         "Batch evaluations (grids, trajectories) should go through `Function.map`."),
        harness.manifest("dynamics_size", argv, started, note)])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
