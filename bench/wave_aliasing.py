"""Where a coarse plan's interval errors come from on the hard suite's slowest tasks: the
wave's phase across an interval.

Each task (TASKS, stated as `python -m bench suite --suite hard` states it) is planned on
uniform meshes of each number of intervals with mesh refinement off, in this process with
no companion (UNDERTOW_SOLVER_PROCESSES=1), capped at CAP seconds. Of the plan returned,
every interval is re-integrated (`planner.ocp.accuracy.interval_errors`, the planner's own
check) and its wave phase advance taken: n h max|dq| over the interval for each wavy joint
(n its wave's frequency, h the interval's width, the rate sampled at SAMPLES points of the
plan's rate polynomial), the largest over the joints. Per plan: the intervals whose phase
advance exceeds HALF_PERIOD (about half a wave period: more than an interval's cubic can
follow) and those within it, each with its median and largest error, and the rank
correlation of error and phase advance over all intervals.

    python -m bench wave_aliasing [--tasks NAME:SEED,...] [--intervals 50,100,200]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from scipy.stats import spearmanr

from bench import harness

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Hard suite: interval errors against the wave's phase across an interval"
CSV = harness.RESULTS / "wave_aliasing.csv"
TASKS = ("bounds-19:31415926", "co-design-20:31415926", "co-design-08:20261125")
INTERVALS = (50, 100, 200)
CAP = 30.0  # [s] each plan's max_wall_time
SAMPLES = 9
HALF_PERIOD = 3.0  # [rad]


def phase_advance(robot, interp) -> np.ndarray:
    """(N,) the largest n h max|dq| over the wavy joints of each interval [rad] (zeros
    without a wave)."""
    breaks = interp.dq.breaks
    widths = np.diff(breaks)
    s = np.linspace(0.0, 1.0, SAMPLES)
    t = (breaks[:-1, None] + widths[:, None] * s[None, :]).ravel()
    rates = np.abs(interp.dq(t)).reshape(widths.size, SAMPLES, -1).max(axis=1)  # (N, n)
    advance = np.zeros(widths.size)
    for j, link in enumerate(robot.links):
        if link.wave is not None and link.wave.amplitude != 0.0:
            advance = np.maximum(advance, link.wave.frequency * widths * rates[:, j])
    return advance


def _median(values: np.ndarray) -> float:
    return float(np.median(values)) if values.size else float("nan")


def _largest(values: np.ndarray) -> float:
    return float(values.max()) if values.size else float("nan")


def one(name: str, seed: int, intervals: int) -> dict:
    """The row of one task planned on `intervals` uniform intervals (see the module)."""
    from bench.suite import with_uncertainty
    from planner.ocp import plan
    from planner.ocp.accuracy import interval_errors
    from planner.scene import Scene
    from testbed.suites import hard

    data = with_uncertainty(hard.hard_task(hard.index_of(name), seed)[1].model_dump(mode="json"))
    data["transcription"].update({"intervals": intervals, "breaks": None})
    data["transcription"]["refinement"] = {**data["transcription"].get("refinement", {}),
                                           "enabled": False}
    data["solver"]["max_wall_time"] = CAP
    scene = Scene.model_validate(data)
    started = time.perf_counter()
    result = plan(scene)
    elapsed = time.perf_counter() - started
    row = {"task": name, "seed": seed, "intervals": intervals, "status": result.solver.status,
           "iterations": result.solver.iterations, "wall": elapsed}
    try:
        interp = result.interpolant()
    except ValueError:
        return row
    robot = result.robot_of(scene.robot)
    errors, _ = interval_errors(robot, interp, scene.solver.jit)
    advance = phase_advance(robot, interp)
    fast = advance > HALF_PERIOD
    finite = np.isfinite(errors)
    rho = spearmanr(errors[finite], advance[finite]).statistic if finite.sum() > 2 else np.nan
    return {**row, "largest_error": float(errors.max()), "largest_advance": float(advance.max()),
            "fast_intervals": int(fast.sum()),
            "fast_median_error": _median(errors[fast]),
            "fast_largest_error": _largest(errors[fast]),
            "slow_median_error": _median(errors[~fast]),
            "slow_largest_error": _largest(errors[~fast]),
            "rank_correlation": float(rho)}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench wave_aliasing", description=__doc__)
    parser.add_argument("--tasks", default=",".join(TASKS),
                        help="comma-separated NAME:SEED of the hard suite")
    parser.add_argument("--intervals", default=",".join(map(str, INTERVALS)),
                        help="comma-separated numbers of uniform intervals")
    args = parser.parse_args(argv)
    os.environ["UNDERTOW_SOLVER_PROCESSES"] = "1"
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for item in args.tasks.split(","):
        name, seed = item.split(":")
        for intervals in (int(n) for n in args.intervals.split(",")):
            rows.append(one(name, int(seed), intervals))
            print(rows[-1], flush=True)
    harness.write_csv(CSV, rows)
    text = "\n\n".join([
        "Tasks of `testbed.suites.hard` (with the suite's mass uncertainty), each planned on "
        "uniform meshes with refinement off, one process and no companion, capped at "
        f"{CAP:g} s. Every interval of the plan returned is re-integrated as the planner "
        "checks it; its phase advance is n h max|dq| of its wavy joints (the wave's "
        "frequency n, the interval's width h, the rate along the plan's polynomial). "
        f"\"Fast\" intervals advance a wave by more than {HALF_PERIOD:g} rad, about half "
        "its period, more than an interval's cubic can follow.",
        harness.table(rows, [
            ("task", "task"), ("seed", "seed"), ("intervals", "intervals"),
            ("status", "status"), ("iterations", "iterations"),
            ("largest_error", "largest interval error [rad]"),
            ("largest_advance", "largest phase advance [rad]"),
            ("fast_intervals", "fast intervals"),
            ("fast_median_error", "fast: median error [rad]"),
            ("fast_largest_error", "fast: largest error [rad]"),
            ("slow_median_error", "others: median error [rad]"),
            ("slow_largest_error", "others: largest error [rad]"),
            ("rank_correlation", "rank correlation of error and advance")]),
        "Rows: `bench/results/wave_aliasing.csv`. "
        + harness.manifest("wave_aliasing", argv, started, note)])
    harness.write_section(DOC, SECTION, text)
    return 0
