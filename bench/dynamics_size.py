"""Size and speed of the derived dynamics for the seed's 4-link arm (and an 8-link chain).

For each variant (waves on/off, gravity on/off): expression nodes of M, h and forward
dynamics (CasADi Function.n_nodes), the time to build a structure's functions (derivation
and Function construction, uncached, median of 5), the median time of one evaluation of
M and h (2000 calls, median of 7 repeats) through the raw CasADi Function and through
planner.dynamics.Dynamics, and the cost of a cache hit: `functions(structure)` for a
structure already built, and constructing `Dynamics` for a second robot of that structure.

Run: .venv/bin/python bench/dynamics_size.py   (writes docs/bench-dynamics.md)
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from seed_printed import SEED_ARM

from planner.dynamics import Dynamics, functions
from planner.model import Robot, Structure

OUTPUT = ROOT / "docs" / "bench-dynamics.md"
CALLS, REPEATS, BUILDS, MAPPED = 2000, 7, 5, 1000


clock = time.process_time  # CPU time of this process: steadier than wall time on a shared machine


def median_call(fn: Callable[[], object], calls: int = CALLS, repeats: int = REPEATS) -> float:
    """Median over repeats of the mean CPU time of one call [s]."""
    times = []
    for _ in range(repeats):
        start = clock()
        for _ in range(calls):
            fn()
        times.append((clock() - start) / calls)
    return statistics.median(times)


def build_time(s: Structure) -> float:
    """Median CPU time [s] to derive and build a structure's functions, bypassing the cache."""
    times = []
    for _ in range(BUILDS):
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
    seed = Robot.model_validate(SEED_ARM)
    return [
        ("seed, waves, gravity", seed),
        ("seed, waves, g = 0", seed.model_copy(update={"gravity": 0.0})),
        ("seed, no waves, gravity", seed.without_waves()),
        ("seed, no waves, g = 0", seed.without_waves().model_copy(update={"gravity": 0.0})),
        ("8-link chain, waves, gravity", chain(8)),
    ]


def size_row(name: str, robot: Robot) -> str:
    s = Structure.of(robot)
    f = functions(s)
    cells = [name, *(str(f[k].n_nodes()) for k in ("M", "h", "fd")), f"{build_time(s) * 1e3:.1f}"]
    return "| " + " | ".join(cells) + " |"


def speed_row(name: str, robot: Robot, rng: np.random.Generator) -> str:
    s = Structure.of(robot)
    f, dyn = functions(s), Dynamics(robot)
    q, dq = rng.uniform(-np.pi, np.pi, s.n), rng.uniform(-2, 2, s.n)
    Q, dQ = rng.uniform(-np.pi, np.pi, (s.n, MAPPED)), rng.uniform(-2, 2, (s.n, MAPPED))
    M_map, h_map = f["M"].map(MAPPED), f["h"].map(MAPPED)
    p = dyn.p
    us = 1e6
    cells = [
        name,
        f"{median_call(lambda: f['M'](q, p)) * us:.1f}",
        f"{median_call(lambda: f['h'](q, dq, p)) * us:.1f}",
        f"{median_call(lambda: dyn.mass_matrix(q)) * us:.1f}",
        f"{median_call(lambda: dyn.bias(q, dq)) * us:.1f}",
        f"{median_call(lambda: M_map(Q, p), calls=20) / MAPPED * us:.2f}",
        f"{median_call(lambda: h_map(Q, dQ, p), calls=20) / MAPPED * us:.2f}",
    ]
    return "| " + " | ".join(cells) + " |"


def cache_rows() -> list[str]:
    """Cost of a cache hit for a second robot of the seed arm's structure."""
    first = Robot.model_validate(SEED_ARM)
    second = first.model_copy(update={"links": [
        link.model_copy(update={"length": 1.1 * link.length}) for link in first.links]})
    s = Structure.of(second)
    assert s == Structure.of(first)
    functions(s)
    before = functions.cache_info()
    lookup = median_call(lambda: functions(s))
    construct = median_call(lambda: Dynamics(second), calls=500)
    after = functions.cache_info()
    assert after.misses == before.misses
    return [f"| `functions(structure)`, structure already built | {lookup * 1e6:.2f} |",
            f"| `Dynamics(robot)`, second robot of a built structure | {construct * 1e6:.1f} |"]


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0]
    return (f"{cpu}, {os.cpu_count()} CPUs (load average {load:.1f} at the start); "
            f"Python {platform.python_version()}, CasADi {ca.__version__}, NumPy {np.__version__}")


def report() -> str:
    rng = np.random.default_rng(7)
    lines = [
        "# Dynamics: expression size and evaluation cost",
        "",
        "Generated by `.venv/bin/python bench/dynamics_size.py` on " + machine() + ".",
        "",
        ("The seed's 4-link arm (lengths 0.5, 0.4, 0.4, 0.3 m; masses 1.0, 0.8, 0.6, 0.4 kg; "
        "inertias 0.01, 0.008, 0.006, 0.004 kg m^2; waves (0.05 m, 3, 0.3) on joint 1 and "
        "(0.04 m, 4, 0.1) on joint 3, 0-based; g = 9.81 m/s^2), with and without its waves "
        "and gravity, and an 8-link chain for scale (0.3 m, 0.5 kg, 0.005 kg m^2 per link, "
        "odd joints active with wave (0.03 m, 3, 0.2))."),
        "",
        ("Nodes: `Function.n_nodes()` of M, h and forward dynamics `fd` (M^-1 (B tau - h), solved "
        "symbolically). Build: derivation plus construction of all of a structure's functions, "
        f"uncached, median of {BUILDS}. All times are CPU time of the benchmark process "
        "(`time.process_time`), which other load on the machine disturbs less than wall time."),
        "",
        "| variant | nodes M | nodes h | nodes fd | build [ms] |",
        "|---|---:|---:|---:|---:|",
        *(size_row(name, robot) for name, robot in variants()),
        "",
        (f"Evaluation at one random state: mean of {CALLS} calls, median of {REPEATS} repeats, "
        "in microseconds per call. `Function`: the raw CasADi call with NumPy arguments; "
        "`Dynamics`: the NumPy-facing method (conversion included); `map`: the Function "
        f"mapped over {MAPPED} states in one call, per state."),
        "",
        ("| variant | M Function | h Function | Dynamics.mass_matrix | Dynamics.bias | "
        "M map, per state | h map, per state |"),
        "|---|---:|---:|---:|---:|---:|---:|",
        *(speed_row(name, robot, rng) for name, robot in variants()),
        "",
        "Cache hit (a second robot with other numbers but the same structure):",
        "",
        "| operation | time [us] |",
        "|---|---:|",
        *cache_rows(),
        "",
        ("Reading: a single call costs tens of microseconds whatever the structure, mostly "
        "CasADi's call overhead; the expression size shows in the mapped, per-state cost. "
        "Batch evaluations (grids, trajectories) should go through `Function.map`."),
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    text = report()
    OUTPUT.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
