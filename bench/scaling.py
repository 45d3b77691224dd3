"""How the planner's cost grows: against the number of intervals N and of links.

- N from 10 to 2000, Legendre degree 3, the fully actuated 2-link arm with its 1 s task
  (bench/scenes.py "arm-2");
- links from 1 to 8 at N = 50, Legendre degree 3: a chain of 0.4 m, 1 kg links, every
  joint active, g = 9.81, waves on odd joints, each joint moving +0.5 rad rest to rest in
  1 s (`testbed.robots.chain_scene`).

Each point runs in a fresh process, one solve per plan (mesh refinement and retries off,
so that N stays what the point says): build time, median Ipopt wall and CPU time of 3
solves, iterations, and peak resident memory (getrusage ru_maxrss) of the process, also
net of the memory after the imports. Growth exponents: least-squares slopes in log-log.

Writes bench/results/scaling.csv, docs/img/scaling_N.png, docs/img/scaling_links.png and
the section "Scaling" of docs/benchmarks.md.

    python -m bench scaling [--N 10 20 ...] [--links 1 2 ...]
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

from bench import harness
from bench.scenes import ONE_SOLVE, make_scene
from planner.ocp import plan
from testbed.robots import chain_scene

SECTION = "Scaling"
N_GRID = [10, 20, 50, 100, 200, 500, 1000, 2000]
LINKS = [1, 2, 3, 4, 5, 6, 7, 8]
LINKS_N = 50
REPEATS = 3
TIMEOUT = 1800.0


def _maxrss() -> float:
    """Peak resident memory of this process so far [MB]."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def point(kind: str, size: int) -> dict:
    """One point in this (fresh) process: kind "N" (arm-2 at N = size) or "links"."""
    base = _maxrss()
    transcription, settings = ONE_SOLVE
    scene = (make_scene("arm-2", N=size, one_solve=True) if kind == "N"
             else chain_scene(size, False, "", settings, intervals=LINKS_N, **transcription))
    build_time, solver = harness.build_instrumented(scene)
    after_build = _maxrss()
    walls, cpus, plans = [], [], []
    for _ in range(REPEATS):
        plans.append(plan(scene))
        walls.append(plans[-1].solver.solve_time)
        cpus.append(solver.cpu)
    p = plans[0]
    return {"build": build_time, "solve": harness.median(walls),
            "solve_cpu": harness.median(cpus),
            "iterations": p.solver.iterations, "status": p.solver.status,
            "per_iteration": harness.median(walls) / max(1, p.solver.iterations),
            "interval_error": p.verification.local_error,
            "rss_imports": base, "rss_build": after_build, "rss_peak": _maxrss(),
            "rss_net": _maxrss() - base}


def sweep(kind: str, sizes: list[int]) -> list[dict]:
    rows = []
    for size in sizes:
        started = time.perf_counter()
        out = harness.isolated("scaling", "point", {"kind": kind, "size": size}, TIMEOUT)
        rows.append({"kind": kind, "size": size, "load": harness.load(),
                     "wall": time.perf_counter() - started, **out})
        print(rows[-1], flush=True)
    return rows


def exponents(rows: list[dict]) -> dict[str, float]:
    ok = [r for r in rows if "failure" not in r and r["status"] == "Solve_Succeeded"]
    x = [r["size"] for r in ok]
    return {key: harness.loglog_slope(x, [r[key] for r in ok]) if len(ok) > 1 else float("nan")
            for key in ("build", "solve", "solve_cpu", "per_iteration", "rss_net")}


def plot(rows: list[dict], label: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if "failure" not in r]
    x = [r["size"] for r in ok]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    slopes = exponents(rows)
    for key, name in (("build", "build"), ("solve", "solve (median)"),
                      ("solve_cpu", "solve CPU"), ("per_iteration", "per Ipopt iteration")):
        ax1.plot(x, [r[key] for r in ok], "o-", label=f"{name}, slope {slopes[key]:.2f}")
    ax1.set(xscale="log", yscale="log", xlabel=label, ylabel="time [s]")
    ax1.legend(fontsize=8)
    ax1.grid(True, which="both", alpha=0.3)
    ax2.plot(x, [r["rss_peak"] for r in ok], "o-", label="peak RSS of the process")
    ax2.plot(x, [r["rss_net"] for r in ok], "s--",
             label=f"net of imports, slope {slopes['rss_net']:.2f}")
    ax2.set(xscale="log", yscale="log", xlabel=label, ylabel="memory [MB]")
    ax2.legend(fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(harness.output(path), dpi=110)
    plt.close(fig)


COLUMNS = [("size", "size"), ("status", "status"), ("iterations", "iterations"),
           ("build", "build [s]"), ("solve", "solve [s]"), ("solve_cpu", "solve CPU [s]"),
           ("per_iteration", "per iteration [s]"), ("rss_peak", "peak RSS [MB]"),
           ("rss_net", "net of imports [MB]"), ("interval_error", "interval error [rad]"),
           ("load", "load average"), ("failure", "failure")]


def report(by_n: list[dict], by_links: list[dict]) -> str:
    fits = [{"against": "N (arm-2, Legendre 3)", **exponents(by_n)},
            {"against": f"links (chain, N = {LINKS_N})", **exponents(by_links)}]
    return "\n\n".join([
        ("Each point in a fresh process, one solve per plan (refinement and retries off): "
         f"build from a cold cache, median of {REPEATS} solves (wall and CPU), peak resident "
         "memory (`getrusage` ru_maxrss) and the same net of the memory after the imports. "
         "Exponents: least-squares slope of log(value) against log(size) over the points "
         "that solved."),
        harness.table(fits, [("against", "growth against"), ("build", "build"),
                             ("solve", "solve"), ("solve_cpu", "solve CPU"),
                             ("per_iteration", "per iteration"), ("rss_net", "memory, net")]),
        "### Against N",
        "![scaling against N](img/scaling_N.png)",
        harness.table(by_n, [("size", "N"), *COLUMNS[1:]]),
        "### Against the number of links",
        "![scaling against links](img/scaling_links.png)",
        harness.table(by_links, [("size", "links"), *COLUMNS[1:]]),
    ])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench scaling", description=__doc__)
    parser.add_argument("--N", type=int, nargs="+", default=N_GRID)
    parser.add_argument("--links", type=int, nargs="+", default=LINKS)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    by_n = sweep("N", args.N)
    by_links = sweep("links", args.links)
    harness.write_csv(harness.RESULTS / "scaling.csv", [
        {k: r.get(k) for k in ["kind", "size", *[c for c, _ in COLUMNS[1:]], "rss_imports", "wall"]}
        for r in by_n + by_links])
    plot(by_n, "intervals N", harness.DOCS / "img" / "scaling_N.png")
    plot(by_links, "links", harness.DOCS / "img" / "scaling_links.png")
    text = "\n\n".join([
        report(by_n, by_links),
        f"Rows: `bench/results/scaling.csv`. {harness.manifest('scaling', argv, started, note)}"])
    harness.write_section(harness.DOCS / "benchmarks.md", SECTION, text)
    print(text)
    return 0
