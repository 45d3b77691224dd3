"""The headline figures: one table at the top of docs/benchmarks.md, made from the committed
benchmark results (bench/results/*.csv) alone.

Each row is one figure: what it is, its goal where one is set, the value the results give,
the benchmark that produced them and the commit of their last committed run
(`bench.runs.committed`). `python -m bench headline` rewrites the section `SECTION`;
`--out DIR` writes it under DIR instead.

    python -m bench headline [--out DIR]
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass

from bench import harness, runs
from bench.suite import NEVER_MET

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Headline figures"
Rows = list[dict]


@dataclass(frozen=True)
class Figure:
    """One headline figure: `measure` turns the rows of each of `results` (CSV files under
    bench/results/, in order) into the value shown."""

    what: str
    goal: str
    bench: str
    results: tuple[str, ...]
    measure: Callable[..., str]


def _ours(rows: Rows) -> Rows:
    """The default planner's rows of a suite's CSV."""
    return [r for r in rows if r["config"] == "undertow"]


def _share(rows: Rows, key: str = "verified") -> str:
    """How many rows have `key` true, "k of n (p %)"."""
    done = sum(bool(r[key]) for r in rows)
    return f"{done} of {len(rows)} ({100 * done / len(rows):.0f} %)"


def _rank_never(rows: Rows, share: float = 0.5) -> float:
    """The nearest-rank `share` quantile of the time to a verified plan [s] (default the
    median), unverified counted as never."""
    every = sorted(r["time_to_verified"] if r["verified"] else math.inf for r in rows)
    return every[max(math.ceil(share * len(every)) - 1, 0)]


def _finite(values) -> list[float]:
    return [float(v) for v in values if v not in (None, "") and math.isfinite(float(v))]


def suite_verified(rows: Rows) -> str:
    return _share(_ours(rows))


def suite_median(rows: Rows) -> str:
    ours = _ours(rows)
    return f"{harness.median(r['time_to_verified'] for r in ours if r['verified']):.3g} s"


def hard_verified(*seeds: Rows) -> str:
    return _share([r for rows in seeds for r in _ours(rows)])


def hard_median(rows: Rows) -> str:
    return (f"{_rank_never(_ours(rows)):.3g} s; on a service that has built only the "
            f"examples' kernels ({NEVER_MET}): {never_met(rows)}")


def never_met(rows: Rows) -> str:
    """The median, 90th percentile and worst time to a verified plan of the configuration
    that starts with only the examples' kernels compiled (unverified counted as never)."""
    mine = [r for r in rows if r["config"] == NEVER_MET]
    if not mine:
        return "–"
    verified = sum(1 for r in mine if r["verified"])
    return (f"{_rank_never(mine):.3g} s, 90th percentile {_rank_never(mine, 0.9):.3g} s, "
            f"worst {_rank_never(mine, 1.0):.3g} s ({verified} of {len(mine)} verified)")


def co_design(*seeds: Rows) -> str:
    return _share([r for rows in seeds for r in _ours(rows) if r["category"] == "co-design"])


def crossing_iterations(rows: Rows) -> str:
    mine = [r["iterations"] for r in _ours(rows) if r["category"] == "seed-g0-cross"]
    return f"{harness.median(mine):.0f} ({len(mine)} tasks)"


def against_opti(rows: Rows) -> str:
    """The planner's median time to a verified plan against the Opti script's median time
    to its own plan, on the tasks the script can state."""
    script = [r for r in rows if r["config"] == "Opti script"]
    tasks = {r["task"] for r in script}
    ours = harness.median(r["time_to_verified"] for r in _ours(rows)
                          if r["task"] in tasks and r["verified"])
    theirs = harness.median(r["time"] for r in script)
    return f"{ours:.3g} s against {theirs:.3g} s: {theirs / ours:.1f}x"


def iteration_cost(rows: Rows) -> str:
    at = {r["solver"]: r for r in rows if r["N"] == 100}
    default = at["Ipopt, compiled (jit, the default)"]
    before = next(r for name, r in at.items() if name.startswith("before"))
    fatrop_50 = next(r for r in rows if r["N"] == 50 and r["solver"] == "fatrop, compiled")
    return (f"{default['cpu_per_iteration']:.3g} ms, compiled, the default "
            f"({default['factorizations_per_iteration']:.3g} KKT factorizations per "
            f"iteration; {before['solver'].split(':')[0]} {before['cpu_per_iteration']:.3g} "
            f"in the same run; interpreted {at['Ipopt, interpreted']['cpu_per_iteration']:.3g}, "
            f"fatrop on the same compiled kernels {at['fatrop, compiled']['cpu_per_iteration']:.3g}"
            f", at N = 50 {fatrop_50['cpu_per_iteration']:.3g})")


def replan(rows: Rows) -> str:
    mine = [r for r in rows if r["kind"] == "service, warm"]
    return (f"{harness.median(r['time'] for r in mine if r['verified']):.3g} s "
            f"({sum(r['verified'] for r in mine)} of {len(mine)} verified)")


def impossible(rows: Rows) -> str:
    return _share([{**r, "quick": r["within_quarter"] == "yes"} for r in rows], "quick")


def moved_goals(rows: Rows) -> str:
    feasible = [r for r in rows if r["feasible"]]
    times = [r["time"] if r["verified"] else math.inf for r in feasible]
    return f"{_share(feasible)}, median {harness.median(times):.3g} s"


def torque_excess(*suites: Rows) -> str:
    excess = _finite(r["torque_excess"] for rows in suites for r in _ours(rows)
                     if r["verified"] and r["status"] == "Solve_Succeeded")
    return f"{max(excess):.2g} of the limit"


def robust_tracking(rows: Rows) -> str:
    ours = _ours(rows)
    tracking, alone = (harness.median(_finite(r[k] for r in ours))
                       for k in ("robust_tracking_error", "open_loop_final_error"))
    return f"{tracking:.2g} rad (the torque alone ends {alone:.2g} from the goal)"


def memory(rows: Rows) -> str:
    near = [r for r in rows if r["move"] == 0.05 and r["feasible"]]
    warm, cold = ([r[f"{k}_time"] if r[f"{k}_verified"] else math.inf for r in near]
                  for k in ("warm", "cold"))
    return f"{harness.median(warm):.3g} s against {harness.median(cold):.3g} s from scratch"


def adversarial(rows: Rows) -> str:
    verified = [r for r in rows if r["status"] == "verified"]
    verdicts = [r for r in rows if r["status"] == "infeasible" and r["contradicted"]]
    missed = sum(bool(r["missed"]) for r in verified)
    contradicted = sum(r["contradicted"] == "yes" for r in verdicts)
    return (f"{missed} of {len(verified)} verified plans miss their task; {contradicted} of "
            f"{len(verdicts)} infeasible verdicts contradicted")


HARD = ("hard-suite.csv", "hard-suite-seed-31415926.csv", "hard-suite-seed-27182818.csv")
FIGURES = (
    Figure("Task suite (48 tasks): plans verified", "", "suite", ("suite.csv",),
           suite_verified),
    Figure("Task suite: median time to a verified plan", "", "suite", ("suite.csv",),
           suite_median),
    Figure("Hard suite, three seeds: plans verified", "", "suite", HARD, hard_verified),
    Figure("Hard suite, its seed: median time to a verified plan (unverified: never)", "",
           "suite", HARD[:1], hard_median),
    Figure("Wave co-design with a coupling margin (hard suite, three seeds): verified",
           "90 %", "suite", HARD, co_design),
    Figure("Seed arm across a singularity, g = 0: median Ipopt iterations (hard suite)",
           "100", "suite", HARD[:1], crossing_iterations),
    Figure("Against the plain Opti script, tasks it can state (hard suite, seed 27182818): "
           "median time to a verified plan against the script's to its plan", "10x",
           "suite", HARD[2:], against_opti),
    Figure("CPU per Ipopt iteration, seed arm, N = 100", "5 ms", "iteration_cost",
           ("iteration_cost.csv",), iteration_cost),
    Figure("Warm replanning through the service, goal moved by up to 0.05 rad: median time "
           "to a verified plan", "0.1 s", "replan", ("replan.csv",), replan),
    Figure("Impossible tasks said infeasible within a quarter of the 60 s budget", "",
           "impossible", ("impossible.csv",), impossible),
    Figure("Built-in plan examples, goals moved by up to 0.05 rad: verified", "",
           "moved_goals", ("moved_goals.csv",), moved_goals),
    Figure("Delivered torque beyond its limit, worst verified plan (task and hard suites)",
           "1e-6 of the limit", "suite", ("suite.csv", *HARD), torque_excess),
    Figure("Every link's mass 10 % off: median deviation from the plan under its feedback "
           "(task suite)", "", "suite", ("suite.csv",), robust_tracking),
    Figure("Planned from a neighbour 0.05 rad away: median time to a verified plan", "",
           "memory", ("memory.csv",), memory),
    Figure("Adversarial suite: verified plans that miss their task, infeasible verdicts a "
           "plan contradicts", "0", "adversarial", ("adversarial.csv",), adversarial),
)
"""The rows of the table, in order (at most 15)."""


def row(figure: Figure) -> dict:
    """A figure's row of the table, measured on the committed results."""
    paths = [harness.RESULTS / name for name in figure.results]
    return {"figure": figure.what, "goal": figure.goal or "–",
            "measured": figure.measure(*(harness.read_csv(p) for p in paths)),
            "bench": f"`{figure.bench}`", "commit": runs.committed(paths).split()[0]}


def text() -> str:
    """The section: the table and where its numbers come from."""
    return "\n\n".join([
        harness.table([row(f) for f in FIGURES],
                      [("figure", "figure"), ("goal", "goal"), ("measured", "measured"),
                       ("bench", "bench"), ("commit", "commit of its results")]),
        "Made by `python -m bench headline` from the committed results "
        "(`bench/results/*.csv`); the commit is the last one that changed them, the run's "
        "(`python -m bench list` gives every benchmark's). What each figure means, and "
        "the ones this table leaves out: [benchmark findings](bench-findings.md) and the "
        "sections below."])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench headline", description=__doc__)
    parser.parse_args(argv)
    harness.write_section(DOC, SECTION, text())
    return 0
