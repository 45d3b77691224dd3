"""The adversarial suite: is a plan ever called verified without doing its task, is an
infeasible verdict ever contradicted, is its evidence true?

The generated adversarial suite (`testbed.suites.adversarial`: budgets far too short, tips
at the edge of the reach, energy-starved moves, coupling margins and durations across their
ranges), one plan each at default settings. Each plan is then checked by code of this
bench, apart from the planner's own checks:

- a `verified` plan must do its task: its first and last states within 1e-6 x max(1,
  |value|) of the task's, its final tip (summed link by link from the model's definition)
  within 1e-6 m of the target, its dense torques within the limit (1e-6 relative), sigma_min
  of M_pa (numpy's SVD of the dynamics' mass matrix) above the margin (1e-6 relative) at
  its dense samples, its duration within the task's, and every interval re-simulated by
  `planner.simulate` from the plan's state at its start within the plan's tolerance of the
  plan's state at its end;
- an `infeasible` verdict of the duration probe is challenged by a second plan with twice
  the intervals and twice the budget: a verified one contradicts it (those of the checks
  before a solve are proofs and are only counted); so is a solver failure whose starts
  agreed the task locally infeasible, to show how often that sign misleads;
- the evidence of a `duration` verdict, its `shortest_duration`, must be a duration the
  task can be done in: the task planned at it must verify.

    python -m bench adversarial [--seed 20261127] [--count 40]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench import harness
from planner.dynamics import Dynamics
from planner.ocp import plan
from planner.ocp.result import Plan
from planner.scene import Scene
from planner.simulate import simulate
from testbed.robots import tip_of
from testbed.suites import adversarial

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Adversarial suite: verdicts that never lie"
RTOL = 1e-6


def _states(scene: Scene, result: Plan) -> list[str]:
    """What the plan's end states miss of the task."""
    task, out = scene.task, []
    for which, state, wanted in (("initial", 0, task.initial), ("final", -1, task.final)):
        got = [*result.q[state], *result.dq[state]]
        for k, value in enumerate([*wanted.q, *wanted.dq]):
            if value is not None and abs(got[k] - value) > RTOL * max(1.0, abs(value)):
                out.append(f"{which} state entry {k} off by {abs(got[k] - value):.3g}")
    target = task.tip_target
    if target is not None:
        gap = float(np.hypot(*(tip_of(result.robot_of(scene.robot), np.asarray(result.q[-1]))
                               - [target.x, target.y])))
        if gap > RTOL:
            out.append(f"tip {gap:.3g} m from its target")
    shortest, longest = task.duration_span
    if not shortest * (1 - RTOL) <= result.duration <= longest * (1 + RTOL):
        out.append(f"duration {result.duration:.6g} s outside the task's")
    return out


def _limits(scene: Scene, result: Plan) -> list[str]:
    """What the plan's dense samples miss of the torque limit and the coupling margin."""
    task, out = scene.task, []
    if task.torque_limit is not None:
        peak = float(np.abs(np.asarray(result.dense.tau)).max())
        if peak > float(np.min(task.torque_limit)) * (1 + RTOL) + 1e-12:
            out.append(f"torque {peak:.6g} N m beyond the limit")
    if task.coupling_margin is not None:
        robot = result.robot_of(scene.robot)
        dyn, p, a = Dynamics(robot), list(robot.passive), list(robot.active)
        least = min(float(np.linalg.svd(dyn.mass_matrix(q)[np.ix_(p, a)],
                                        compute_uv=False).min())
                    for q in np.asarray(result.dense.q))
        if least < task.coupling_margin * (1 - RTOL):
            out.append(f"sigma_min {least:.6g} below the margin")
    return out


def _accuracy(scene: Scene, result: Plan) -> list[str]:
    """Intervals whose re-simulation departs from the plan's next node beyond its
    tolerance."""
    assert result.torque is not None
    robot = result.robot_of(scene.robot)
    breaks = np.asarray(result.torque.breaks)
    coeffs = np.asarray(result.torque.coefficients)
    tolerance = scene.solver.resimulation_tolerance
    worst = 0.0
    for k in range(len(breaks) - 1):
        x0 = np.concatenate([result.q[k], result.dq[k]])
        run = simulate(robot, breaks[k:k + 2], coeffs[k:k + 1], x0)
        h = breaks[k + 1] - breaks[k]
        error = max(float(np.abs(np.asarray(run.q[-1]) - result.q[k + 1]).max()),
                    h * float(np.abs(np.asarray(run.dq[-1]) - result.dq[k + 1]).max()))
        worst = max(worst, error)
    return [f"an interval re-simulates {worst:.3g} rad off"] if worst > 1.01 * tolerance \
        else []


def _challenge(scene: Scene) -> Plan:
    """The task planned again with twice the intervals and twice the budget."""
    data = scene.model_dump(exclude_unset=True)
    data.setdefault("transcription", {})["intervals"] = 2 * scene.transcription.intervals
    data.setdefault("solver", {})["max_wall_time"] = 2 * scene.solver.max_wall_time
    return plan(Scene.model_validate(data))


def _evidence(scene: Scene, result: Plan) -> str:
    """Whether a duration verdict's shortest duration is one the task can be done in."""
    found = result.infeasibility
    if found is None or found.shortest_duration is None:
        return ""
    data = scene.model_dump(exclude_unset=True)
    data["task"]["duration"] = found.shortest_duration
    at = plan(Scene.model_validate(data))
    return "true" if at.status == "verified" else f"not shown ({at.status})"


def _row(name: str, scene: Scene) -> dict:
    cpu, wall = harness.cpu_time(), time.perf_counter()
    result = plan(scene)
    wall, cpu = time.perf_counter() - wall, harness.cpu_time() - cpu
    found = result.infeasibility
    row = {"task": name, "category": name.rsplit("-", 1)[0], "status": result.status,
           "solver_status": result.solver.status, "time": wall, "cpu": cpu,
           "past_budget": wall - scene.solver.max_wall_time,
           "source": "" if found is None else found.source, "missed": "",
           "contradicted": "", "evidence": ""}
    if result.status == "verified":
        row["missed"] = "; ".join(_states(scene, result) + _limits(scene, result)
                                  + _accuracy(scene, result))
    if found is not None and found.source != "checks":
        row["contradicted"] = "yes" if _challenge(scene).status == "verified" else "no"
        row["evidence"] = _evidence(scene, result)
    return row


def _summary(rows: list[dict]) -> list[dict]:
    out = []
    for category in dict.fromkeys(r["category"] for r in rows):
        group = [r for r in rows if r["category"] == category]
        out.append({"category": category, "tasks": len(group),
                    **{s: sum(r["status"] == s for r in group)
                       for s in ("verified", "unverified", "infeasible", "out-of-budget",
                                 "solver-failure")},
                    "missed": sum(bool(r["missed"]) for r in group),
                    "contradicted": sum(r["contradicted"] == "yes" for r in group),
                    "median": harness.median(r["time"] for r in group)})
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench adversarial")
    parser.add_argument("--seed", type=int, default=adversarial.SEED)
    parser.add_argument("--count", type=int, default=adversarial.COUNT)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for name, scene in adversarial.tasks(args.count, args.seed):
        rows.append(_row(name, scene))
        print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "adversarial.csv", rows)
    harness.write_section(DOC, SECTION, _text(rows, args, argv, started, note))
    return 0


def _text(rows: list[dict], args: argparse.Namespace, argv: list[str], started: float,
          note: str) -> str:
    verified = [r for r in rows if r["status"] == "verified"]
    challenged = [r for r in rows if r["contradicted"] and r["status"] == "infeasible"]
    signs = [r for r in rows if r["contradicted"] and r["status"] != "infeasible"]
    evidence = [r for r in rows if r["evidence"]]
    latest = max(r["past_budget"] for r in rows)
    return "\n\n".join([
        f"The generated adversarial suite (`testbed.suites.adversarial`, {args.count} tasks "
        f"of seed {args.seed}), one plan each, checked by this bench's own code (see "
        f"`bench/adversarial.py`). **{sum(bool(r['missed']) for r in verified)} of "
        f"{len(verified)} verified plans miss their task**; "
        f"{sum(r['contradicted'] == 'yes' for r in challenged)} of {len(challenged)} "
        f"infeasible verdicts of the duration probe are contradicted by a verified plan "
        f"with twice the intervals and budget (of {len(signs)} solver failures whose starts "
        f"agreed the task locally infeasible, {sum(r['contradicted'] == 'yes' for r in signs)} "
        f"then planned so); "
        f"{sum(r['evidence'] == 'true' for r in evidence)} of {len(evidence)} shortest "
        f"durations given as evidence are durations a plan verifies at; "
        f"{sum(r['source'] == 'checks' for r in rows)} tasks are refused by a proof before "
        f"any solve. The latest plan returned {latest:.3g} s "
        + ("past its budget." if latest > 0 else "within its budget (negative: before it)."),
        harness.table(_summary(rows), [
            ("category", "category"), ("tasks", "tasks"), ("verified", "verified"),
            ("unverified", "unverified"), ("infeasible", "infeasible"),
            ("out-of-budget", "out of budget"), ("solver-failure", "solver failure"),
            ("missed", "verified, task missed"), ("contradicted", "challenged, then planned"),
            ("median", "median wall [s]")]),
        harness.table(rows, [("task", "task"), ("status", "status"),
                             ("solver_status", "last solve"), ("source", "infeasible by"),
                             ("evidence", "evidence"), ("contradicted", "contradicted"),
                             ("missed", "missed"), ("time", "wall [s]"), ("cpu", "CPU [s]")]),
        f"Rows: `bench/results/adversarial.csv`. "
        f"{harness.manifest('adversarial', argv, started, note)}"])
