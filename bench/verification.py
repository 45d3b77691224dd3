"""What a plan's checks cost, now and at an earlier commit, in one run.

For each scene and each setting of `solver.jit`, a fresh process of each version plans the
scene (building its NLP and, with jit, waiting for its compiled libraries), plans it again
and then times, `--repeats` times each (median CPU time), the checks the planner runs on
that plan: the interval check (every interval re-integrated by CVODES), the open-loop
replay of the whole horizon, the feedback (linearisation, LQR gains and the two closed-loop
replays) and all of `verify` (the feedback, the coupling along the plan, the waveless
singular crossings, the defect); and the median wall time of `--repeats` plans. The largest
interval error of both versions is reported to show that they check the same thing.

Scenes: `seed-arm-plan` as shipped (50 intervals) and the same task on 100 intervals with
one solve ("seed-hang", bench/scenes.py).

    python -m bench verification [--before 40cfc2f] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import time

from bench import harness
from bench.scenes import make_scene
from planner.examples import example

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Verification: what a plan's checks cost"
BEFORE = "40cfc2f"  # the last commit whose checks integrated by BDF only

_RUN = """
import json, math, statistics, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from planner import compiled
from planner.ocp import planner as planner_module
from planner.ocp.accuracy import interval_errors
from planner.ocp.verify import _feedback, open_loop, verify
from planner.scene import Scene
scene = Scene.model_validate(json.loads(sys.argv[1]))
jit, limit = scene.solver.jit, scene.task.torque_limit
seen = {{}}
def keep(robot, interp, jit):
    seen["plan"] = robot, interp
    return interval_errors(robot, interp, jit)
planner_module.interval_errors = keep
planner_module.plan(scene)
compiled.wait()
plans = []
for _ in range({repeats}):
    started = time.perf_counter()
    result = planner_module.plan(scene)
    plans.append(time.perf_counter() - started)
robot, interp = seen["plan"]
errors, status = interval_errors(robot, interp, jit)
replayed = open_loop(robot, interp, jit)
breaks = interp.q.breaks
per = planner_module.REPLAY_SAMPLES * max(1, math.ceil(
    planner_module.DENSE_POINTS / (planner_module.REPLAY_SAMPLES * len(breaks))))
dense = np.concatenate([np.linspace(a, b, per, endpoint=False)
                        for a, b in zip(breaks[:-1], breaks[1:])] + [breaks[-1:]])
def cpu(fn):
    times = []
    for _ in range({repeats}):
        started = time.process_time()
        fn()
        times.append(time.process_time() - started)
    return statistics.median(times)
print("RESULT " + json.dumps({{
    "intervals": cpu(lambda: interval_errors(robot, interp, jit)),
    "open_loop": cpu(lambda: open_loop(robot, interp, jit)),
    "feedback": cpu(lambda: _feedback(robot, interp, limit, jit)),
    "verify": cpu(lambda: verify(robot, interp, dense, errors, status, replayed, 1e-3, limit,
                                 jit)),
    "plan": statistics.median(plans), "local_error": float(errors.max()),
    "verified": bool(result.verification.verified)}}))
"""
COLUMNS = [("scene", "scene"), ("jit", "jit"), ("version", "version"),
           ("intervals", "interval check [ms]"), ("open_loop", "open-loop replay [ms]"),
           ("feedback", "feedback [ms]"), ("verify", "verify [ms]"),
           ("plan", "whole plan [ms]"), ("local_error", "largest interval error [rad]"),
           ("verified", "verified")]


def scenes() -> dict[str, dict]:
    """The measured requests, by name."""
    shipped = example("seed-arm-plan").request
    return {"seed-arm-plan": shipped,
            "seed-hang, N = 100": make_scene("seed-hang", N=100, one_solve=True).model_dump()}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench verification", description=__doc__)
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    with harness.checkout(args.before) as old:
        for name, request in scenes().items():
            for jit in (False, True):
                body = {**request, "solver": {**request.get("solver", {}), "jit": jit}}
                for version, root in (("now", harness.ROOT), (args.before, old)):
                    code = _RUN.format(root=str(root), repeats=args.repeats)
                    out = harness.run_at(root, code, [json.dumps(body)], 900)
                    if "failure" in out:
                        raise RuntimeError(f"{name}, {version}: {out['failure']}")
                    ms = {k: 1000 * out[k] for k in ("intervals", "open_loop", "feedback",
                                                     "verify", "plan")}
                    rows.append({"scene": name, "jit": jit, "version": version, **ms,
                                 "local_error": out["local_error"],
                                 "verified": out["verified"]})
                    print(rows[-1])
    harness.write_csv(harness.RESULTS / "verification.csv", rows)
    text = "\n\n".join([
        "CPU time of each check of one plan (median of "
        f"{args.repeats}), and the median wall time of the whole plan, with this checkout "
        f"and with {args.before} (checks by BDF only), in fresh processes of one run. Now "
        "CVODES integrates by Adams-Moulton with functional iteration and falls back to BDF "
        "where Adams fails, and with `solver.jit` the linearisation's Jacobians are "
        "compiled too (`planner.ocp.flow`, `planner.ocp.feedback`).",
        harness.table(rows, COLUMNS),
        "Rows: `bench/results/verification.csv`. "
        + harness.manifest("verification", argv, started, note)])
    harness.write_section(DOC, SECTION, text)
    return 0
