"""What a plan's checks cost, now and at an earlier commit, in one run.

For each scene and each setting of `solver.jit`, a fresh process of each version plans the
scene (building its NLP and, with jit, waiting for its compiled libraries), plans it again
`--repeats` times (median wall time of a plan, and its verdict) and then times, `--repeats`
times each (median CPU time), the checks the planner runs on a plan, each through the
public functions of `planner.ocp` called directly: the interval check
(`accuracy.interval_errors`: every interval re-integrated by CVODES), the open-loop replay
of the whole horizon (`verify.open_loop`), the feedback (`feedback.linearise`, `gains`,
`growth_factor` and the two closed-loop `replay`s) and all of `verify.verify` (the
feedback, the coupling along the plan, the waveless singular crossings, the defect). Both
versions check the same plan, this checkout's (its state and torque polynomials, passed to
the earlier version's process), so the largest interval error of both shows that they
check the same thing. The scenes keep their waves (no co-design): the scene's robot is
the plan's.

Scenes: `seed-arm-plan` as shipped (50 intervals) and the same task on 100 intervals with
one solve ("seed-hang", bench/scenes.py).

`--parts suite` measures instead what the checks after a plan's last solve cost against
the whole plan, on every task of the default suite (bench/checks_share.py says how).

    python -m bench verification [--before 40cfc2f] [--repeats 5]
        [--scenes seed-arm-plan,seed-hang] [--jit off,on]
    python -m bench verification --parts suite [--before f853d1f] [--repeats 1]
        [--count 48] [--seed 20261123] [--variants plain,uncertain]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
import time
from pathlib import Path

from bench import checks_share, harness
from bench.scenes import make_scene
from planner.examples import example

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Verification: what a plan's checks cost"
BEFORE = "40cfc2f"  # the last commit whose checks integrated by BDF only
SUITE_BEFORE = "f853d1f"  # the planner reporting its checks' time, before they were batched
JIT = {"off": False, "on": True}

_RUN = """
import inspect, json, statistics, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from planner import compiled
from planner.ocp import plan
from planner.ocp.accuracy import interval_errors
from planner.ocp.feedback import PERTURBATION, gains, growth_factor, linearise, replay
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import open_loop, verify
from planner.scene import Scene
scene = Scene.model_validate(json.loads(sys.argv[1]))
robot, jit, limit = scene.robot, scene.solver.jit, scene.task.torque_limit
result = plan(scene)
compiled.wait()
plans = []
for _ in range({repeats}):
    started = time.perf_counter()
    result = plan(scene)
    plans.append(time.perf_counter() - started)
checked = json.loads(open(sys.argv[2]).read()) if len(sys.argv) > 2 else {{
    "breaks": result.states.breaks, "q": result.states.q, "dq": result.states.dq,
    "tau": result.torque.coefficients, "dense": result.dense.t}}
breaks, dense = np.asarray(checked["breaks"]), np.asarray(checked["dense"])
interp = Interpolant(*(PiecewisePolynomial(breaks, np.asarray(checked[k]))
                       for k in ("q", "dq", "tau")))
errors, status = interval_errors(robot, interp, jit)
replayed = open_loop(robot, interp, jit)
# the earlier planner's linearise has no compiled Jacobians
linearised = {{"compiled": jit}} if "compiled" in inspect.signature(linearise).parameters else {{}}
scale = max(float(np.max(limit)) if limit is not None
            else float(np.abs(interp.tau.coeffs[:, 0]).max(initial=0.0)), 1.0)
start = np.concatenate([interp.q(breaks[:1])[0], interp.dq(breaks[:1])[0]])
def feedback():
    lin = linearise(robot, interp, **linearised)
    growth_factor(lin)
    fb = gains(lin, np.diff(breaks), scale)
    return replay(robot, interp, np.stack([start, start + PERTURBATION]),
                  np.asarray(fb.gains), compiled=jit)
def checks():
    # the planner's verify takes the task and settings since its verdict checks the task,
    # and replays the plan open loop itself since only the reported plan is replayed
    parameters = inspect.signature(verify).parameters
    if "replayed" not in parameters:
        return verify(robot, interp, dense, errors, status, scene.task, scene.solver, True)
    if "task" in parameters:
        return verify(robot, interp, dense, errors, status, replayed, scene.task,
                      scene.solver, True)
    return verify(robot, interp, dense, errors, status, replayed, 1e-3, limit, jit)
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
    "feedback": cpu(feedback),
    "verify": cpu(checks),
    "plan": statistics.median(plans), "local_error": float(errors.max()),
    "verified": bool(result.verification.verified), "checked": checked}}))
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


def _checked(root: Path, request: dict, repeats: int, plan: Path | None) -> dict:
    """The checks' times of one version (the checkout at `root`) in a fresh process, on the
    plan whose polynomials the JSON file `plan` holds or, without one, on its own plan."""
    code = _RUN.format(root=str(root), repeats=repeats)
    out = harness.run_at(root, code, [json.dumps(request), *([str(plan)] if plan else [])], 900)
    if "failure" in out:
        raise RuntimeError(f"{root}: {out['failure']}")
    return out


def _row(name: str, jit: bool, version: str, out: dict) -> dict:
    ms = {k: 1000 * out[k] for k in ("intervals", "open_loop", "feedback", "verify", "plan")}
    return {"scene": name, "jit": jit, "version": version, **ms,
            "local_error": out["local_error"], "verified": out["verified"]}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench verification", description=__doc__)
    parser.add_argument("--parts", default="checks",
                        help="comma-separated: checks (each check of two scenes), suite (the "
                             "checks' share of a plan on the task suite)")
    parser.add_argument("--before", default=None,
                        help=f"the earlier commit (default: {BEFORE} for checks, "
                             f"{SUITE_BEFORE} for suite; none: only this checkout)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="checks: times each check runs (5); suite: measured plans a "
                             "task (1)")
    parser.add_argument("--scenes", default=",".join(n.split(",")[0] for n in scenes()),
                        help="comma-separated, from: " + ", ".join(scenes()))
    parser.add_argument("--jit", default=",".join(JIT), help="comma-separated: off, on")
    parser.add_argument("--count", type=int, default=checks_share.COUNT,
                        help="suite: the suite's first tasks")
    parser.add_argument("--seed", type=int, default=checks_share.SEED, help="suite: its seed")
    parser.add_argument("--variants", default=",".join(checks_share.VARIANTS),
                        help="suite: comma-separated, from: " + ", ".join(checks_share.VARIANTS))
    args = parser.parse_args(argv)
    for part in args.parts.split(","):
        started, note = time.perf_counter(), harness.machine_note()
        if part == "suite":
            before = _before(args.before, SUITE_BEFORE)
            text, rows = checks_share.run(before, args.count, args.seed, args.repeats or 1,
                                          args.variants.split(","))
            harness.write_csv(checks_share.CSV, rows)
            section, csv = checks_share.SECTION, checks_share.CSV
        else:
            text = _per_check(args, _before(args.before, BEFORE), args.repeats or 5)
            section, csv = SECTION, harness.RESULTS / "verification.csv"
        text += (f"\n\nRows: `{csv.relative_to(harness.ROOT)}`. "
                 + harness.manifest("verification", argv, started, note))
        harness.write_section(DOC, section, text)
    return 0


def _before(given: str | None, default: str) -> str | None:
    """The earlier commit to measure: the one given, else `default`; None for "none"."""
    chosen = default if given is None else given
    return None if chosen == "none" else chosen


def _per_check(args: argparse.Namespace, before: str | None, repeats: int) -> str:
    """Each check's cost (median of `repeats`) on the chosen scenes, now and at `before`
    (None: now only): the section's text; its rows are written."""
    chosen = {name: request for name, request in scenes().items()
              if name.split(",")[0] in args.scenes.split(",")}
    rows = []
    earlier = harness.checkout(before) if before else contextlib.nullcontext(None)
    with earlier as old, tempfile.TemporaryDirectory() as folder:
        checked = Path(folder) / "plan.json"
        for name, request in chosen.items():
            for jit in (JIT[j] for j in args.jit.split(",")):
                body = {**request, "solver": {**request.get("solver", {}), "jit": jit}}
                outs = {"now": _checked(harness.ROOT, body, repeats, None)}
                checked.write_text(json.dumps(outs["now"]["checked"]))
                if old is not None and before:
                    outs[before] = _checked(old, body, repeats, checked)
                for version, out in outs.items():
                    rows.append(_row(name, jit, version, out))
                    print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "verification.csv", rows)
    return "\n\n".join([
        "CPU time of each check of one plan (median of "
        f"{repeats}), and the median wall time of the whole plan, with this checkout "
        f"and with {before} (checks by BDF only), in fresh processes of one run; both "
        "versions check this checkout's plan. Now "
        "CVODES integrates by Adams-Moulton with functional iteration and falls back to BDF "
        "where Adams fails, and with `solver.jit` the linearisation's Jacobians are "
        "compiled too (`planner.ocp.flow`, `planner.ocp.feedback`).",
        harness.table(rows, COLUMNS)])
