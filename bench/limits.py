"""Torque limits on whole intervals: the delivered torque against a binding limit, with the
limit held at the torque variables only and on the whole of every interval.

Two time-optimal tasks whose limit binds, each planned by every transcription with the
planner's defaults (mesh refinement and retries on), twice: as the NLP stands (the limit
a bound on the torque variables and, where the delivered polynomial is more than those,
on its Bernstein coefficients: `TorqueLimit` in planner/ocp/terms.py), and with that term
switched off (the limit at the torque variables only, what the planner did before). For
each plan: the duration it reports, the Ipopt iterations over its solves, the largest
|tau| of its delivered polynomial (exact: every interval's ends and the real roots of its
derivative inside it, by numpy) and how far above the limit that is, and whether it
verifies. Writes bench/results/limits.csv and the section "Torque limits on whole
intervals" of docs/benchmarks.md.

    python -m bench limits [--methods legendre,radau,...]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from bench import harness
from planner.ocp import plan
from planner.ocp import problem as problem_module
from planner.ocp.terms import TorqueLimit
from planner.scene import Scene
from testbed.robots import chain

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Torque limits on whole intervals"
METHODS = "legendre,radau,hermite-simpson,trapezoidal,multiple-shooting"
TWO_LINK = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "active"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 9.81}


def tasks() -> dict[str, dict]:
    """The two tasks as scene requests without their transcription: the two-link arm of
    tests/test_delivered_torque.py (4 N m, 10 intervals) and three active links of
    `testbed.robots.chain` each turning 1 rad (6 N m, 30 intervals)."""
    start = [0.0, 0.1, 0.2]
    return {
        "two-link, 4 N m": {"robot": TWO_LINK, "intervals": 10, "task": {
            "duration": {"min": 0.2, "max": 3.0},
            "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
            "final": {"q": [0.6, 1.2], "dq": [0.0, 0.0]}, "torque_limit": 4.0,
            "objective": {"time": 1.0, "effort": 1e-3}}},
        "three-link, 6 N m": {"robot": chain(3, False), "intervals": 30, "task": {
            "duration": {"min": 0.1, "max": 3.0}, "initial": {"q": start, "dq": [0.0] * 3},
            "final": {"q": [s + 1.0 for s in start], "dq": [0.0] * 3}, "torque_limit": 6.0,
            "objective": {"time": 1.0, "effort": 1e-6}}},
    }


@contextmanager
def points_only(on: bool) -> Iterator[None]:
    """With on: the torque limit held at the torque variables only (the term that bounds
    the rest of each interval's polynomial switched off), in NLPs built apart from the
    cached ones."""
    caches = (problem_module.stages, problem_module.cached_problem)
    if not on:
        yield
        return
    wanted = TorqueLimit.wanted
    for cache in caches:
        cache.cache_clear()
    TorqueLimit.wanted = lambda self, key: False  # type: ignore[method-assign]
    try:
        yield
    finally:
        TorqueLimit.wanted = wanted  # type: ignore[method-assign]
        for cache in caches:
            cache.cache_clear()


def peak(coefficients: list) -> float:
    """The largest |value| of a piecewise polynomial (K, m, dim), ascending powers of s."""
    c = np.asarray(coefficients, float)
    P, best = np.polynomial.polynomial, 0.0
    for k in range(c.shape[0]):
        for d in range(c.shape[2]):
            roots = P.polyroots(P.polyder(c[k, :, d])) if c.shape[1] > 2 else np.zeros(0)
            inside = roots[(np.abs(roots.imag) < 1e-9) & (roots.real > 0) & (roots.real < 1)]
            values = P.polyval(np.concatenate([[0.0, 1.0], inside.real]), c[k, :, d])
            best = max(best, float(np.abs(values).max()))
    return best


def row(name: str, spec: dict, method: str, only_points: bool) -> dict:
    """One plan of a task by a method, with or without the whole-interval rows."""
    scene = Scene.model_validate({"robot": spec["robot"], "task": spec["task"],
                                  "transcription": {"method": method,
                                                    "intervals": spec["intervals"]}})
    limit = float(spec["task"]["torque_limit"])
    with points_only(only_points):
        started = time.perf_counter()
        result = plan(scene)
        elapsed = time.perf_counter() - started
    top = peak(result.torque.coefficients) if result.torque is not None else float("nan")
    return {"task": name, "method": method,
            "limit_held": "at the variables only" if only_points else "on whole intervals",
            "duration": result.duration, "T": f"{result.duration:.4f}",
            "iterations": result.solver.iterations, "intervals": len(result.t) - 1,
            "peak": top, "excess": top / limit - 1, "over": f"{top / limit - 1:+.2g}",
            "verified": "yes" if result.solver.success and result.verification.verified
            else "no", "time": elapsed}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench limits", description=__doc__)
    parser.add_argument("--methods", default=METHODS, help="comma-separated")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for name, spec in tasks().items():
        for method in args.methods.split(","):
            for only_points in (True, False):
                rows.append(row(name, spec, method, only_points))
                print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "limits.csv", rows)
    text = "\n\n".join([
        ("Two time-optimal tasks whose torque limit binds (objective time + a small effort, "
         "a free duration): the two-link arm of `tests/test_delivered_torque.py` (4 N m, 10 "
         "intervals, effort 1e-3) and three active links of `testbed.robots.chain` each "
         "turning 1 rad rest to rest (6 N m, 30 intervals, effort 1e-6), planned by every "
         "transcription with the defaults (refinement and retries on). `limit held`: at the "
         "torque variables only (the `TorqueLimit` term switched off, as before it existed), "
         "or on whole intervals (the NLP as it stands, docs/planner.md, \"Transcriptions\"). "
         "`peak`: the largest |tau| of the delivered polynomial, exact (every interval's "
         "ends and the roots of its derivative inside it), and how far above the limit "
         "(relative); `verified`: the plan's verdict, which now fails a plan beyond 1e-6 of its "
         "limit; `time`: the whole plan's wall time."),
        ("Held at the variables only, collocation's delivered torque passes the limit "
         "between and beyond its collocation points (Legendre degree 3 on the three-link "
         "task: 11.7 N m against 6), so the duration such a plan reports is that of a "
         "torque beyond the limit; trapezoidal and multiple shooting deliver their "
         "variables (linear between nodes, constant per interval), need no rows and plan "
         "the same either way. Held on whole intervals, every method keeps the limit to "
         "Ipopt's bound tolerance (1e-8 relative) and verifies. A time-optimal task may "
         "have several local optima (the durations of one task differ by method); the rows "
         "change which one a solve ends in, and the iterations by a few either way."),
        harness.table(rows, [("task", "task"), ("method", "method"),
                             ("limit_held", "limit held"), ("T", "T [s]"),
                             ("iterations", "iterations"), ("intervals", "intervals"),
                             ("peak", "peak [N m]"), ("over", "peak / limit - 1"),
                             ("verified", "verified"), ("time", "time [s]")]),
        f"Rows: `bench/results/limits.csv`. {harness.manifest('limits', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
