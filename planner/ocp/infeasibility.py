"""When the planner holds a task infeasible, and the evidence it gives.

Three ways (docs/planner.md, "Limits and failures"):

- before any solve, a check of `planner.feasibility` fails: `plan()` returns at once a
  plan without a trajectory whose `infeasibility` (source "checks") names the fields;
- during the retries, `AGREEING` attempts from different starts end with a status of
  `INFEASIBLE` (Ipopt's Infeasible_Problem_Detected, Local_Infeasibility,
  Restoration_Failed): the retries stop, and the plan is the iterate of the most
  informative of them, the one whose largest row violation is least (the closest the
  solver came to feasibility), with its violated NLP rows grouped by kind (`violated`);
- after the task's first attempts gave no converged plan, a time-optimal solve under the
  task's limits ends at a duration longer than the task allows (`planner.ocp.shortest`,
  source "duration"): the plan is its best attempt's iterate, with its violated rows.

A plan whose attempts do not agree keeps the verdict it had (its best outcome's status),
and its message names an attempt that reported infeasibility, if any, rather than only
the last one.
"""

from __future__ import annotations

import math
import time

import numpy as np

from planner.feasibility import Issue
from planner.ocp.attempt import Attempt
from planner.ocp.evidence import Infeasibility, InfeasibleField, ViolatedRows
from planner.ocp.outcome import Outcome
from planner.ocp.problem import Problem
from planner.ocp.result import DenseTrajectory, Plan, SolverReport, waves_of
from planner.ocp.row_kinds import row_kinds
from planner.ocp.shortest import Probe
from planner.ocp.solve import INFEASIBLE
from planner.ocp.verification import Verification
from planner.scene import DurationRange, Scene

AGREEING = 2
"""Attempts from different starts that must report infeasibility to stop the retries."""
VIOLATION_TOL = 1e-6
"""A row violated by less is not listed."""
CHECKS_STATUS = "Infeasible_Task"
"""`solver.status` of a plan refused by the checks before any solve."""


def reported(outcome: Outcome) -> bool:
    """Whether a solve of the task's own NLP ended saying that its constraints cannot all
    hold (one that held a reserve above the task's coupling margin,
    `planner.ocp.margin_reserve`, asked more than the task and is no witness)."""
    return outcome.finite and outcome.solution.status in INFEASIBLE \
        and outcome.record.margin_reserve is None


def _reporting(attempts: list[Attempt]) -> list[tuple[Outcome, Attempt]]:
    """The solves on an attempt's own mesh (not its preliminary ones: a coarse mesh or a
    relaxed NLP) that reported infeasibility, with their attempt."""
    return [(o, a) for a in attempts for o in a.outcomes if reported(o)]


def agreed(attempts: list[Attempt]) -> bool:
    """Whether attempts from at least AGREEING different starts (a restart from an
    earlier attempt's last iterate not counted) reported infeasibility, and none converged
    (a converged solve, accurate or not, shows the NLP feasible)."""
    if any(o.solution.success for a in attempts for o in a.outcomes):
        return False
    starts = {a.start.name for _, a in _reporting(attempts) if not a.start.continues}
    return len(starts) >= AGREEING


def _largest(outcome: Outcome) -> float:
    found = violated(outcome)
    return found[0].largest if found else math.inf


def most_informative(attempts: list[Attempt]) -> tuple[Outcome, Attempt] | None:
    """The reporting solve with the least largest violation, and its attempt (None when
    no solve reported infeasibility)."""
    found = _reporting(attempts)
    return min(found, key=lambda pair: _largest(pair[0])) if found else None


def violated(outcome: Outcome) -> list[ViolatedRows]:
    """The constraint rows the outcome's iterate violates beyond VIOLATION_TOL, by kind,
    the largest violation first (empty when the solver gave no rows)."""
    g = outcome.solution.g
    if g is None:
        return []
    problem = outcome.inst.problem
    if g.size != problem.lbg.size:
        return []
    violation = np.maximum(problem.lbg - g, 0.0) + np.maximum(g - problem.ubg, 0.0)
    violation = np.nan_to_num(violation, nan=np.inf)
    kinds, stage_rows = row_kinds(problem)
    N = outcome.inst.mesh.intervals
    out = []
    for kind in dict.fromkeys(kinds):
        rows = np.flatnonzero((kinds == kind) & (violation > VIOLATION_TOL))
        if rows.size == 0:
            continue
        worst = int(rows[np.argmax(violation[rows])])
        at = float(outcome.inst.mesh.breaks[_node(problem, worst, stage_rows, N)] * outcome.T)
        out.append(ViolatedRows(kind=str(kind), rows=int(rows.size),
                                largest=float(violation[worst]), time=at))
    return sorted(out, key=lambda v: -v.largest)


def _node(problem: Problem, row: int, stage_rows: int, N: int) -> int:
    """The mesh node a row belongs to: its stage's start; the final node for the
    terminal's rows (and every row where a stage's rows are not known); the node between
    the two copies of the globals that a copy row keeps equal."""
    copies_at = problem.lbg.size - problem.layout.copy_rows
    if row >= copies_at:
        return (row - copies_at) // problem.layout.globals_size + 1
    return min(row // stage_rows, N) if stage_rows else N


def durations(scene: Scene) -> list[float]:
    d = scene.task.duration
    return [d.min, d.max] if isinstance(d, DurationRange) else [float(d)]


def _within(scene: Scene) -> str:
    d = scene.task.duration
    if isinstance(d, DurationRange):
        return f"with a free duration in [{d.min:g}, {d.max:g}] s"
    return f"in {float(d):g} s"


def evidence(scene: Scene, attempts: list[Attempt], best: Outcome,
             attempt: Attempt) -> Infeasibility:
    """The infeasibility the agreeing attempts establish, at `best` (the most informative)."""
    found = _reporting(attempts)
    names = list(dict.fromkeys(f"{a.start.name}: {o.solution.status}" for o, a in found))
    rows = violated(best)
    largest = ", ".join(f"{v.kind} by {v.largest:.3g} (t = {v.time:.3g} s)" for v in rows[:3])
    starts = len({a.start.name for _, a in found if not a.start.continues})
    summary = (f"no plan {_within(scene)}: attempts from {starts} different starts ended "
               f"locally infeasible, their constraints unable to hold near where they went "
               f"({'; '.join(names)}); the closest, '{attempt.start.name}', still violates "
               + (largest if largest else "rows it did not report")
               + ": a sign, not a proof, that the task cannot be done")
    return Infeasibility(source="solver", summary=summary, attempts=names,
                         attempt=attempt.start.name, violations=rows,
                         durations=durations(scene))


def too_short(scene: Scene, attempts: list[Attempt], best: Outcome, attempt: Attempt,
              probe: Probe) -> Infeasibility:
    """The infeasibility a duration probe establishes (`planner.ocp.shortest`): the task's
    attempts gave no converged plan, and a time-optimal solve under its limits ends at a
    longer duration; the plan is `best`'s iterate, its violated rows listed."""
    names = list(dict.fromkeys(f"{a.start.name}: {o.solution.status}"
                               for a in attempts for o in a.outcomes))
    summary = (f"the task cannot be done {_within(scene)}: its attempts gave no converged "
               f"plan ({'; '.join(names)}), and {probe.note}")
    return Infeasibility(source="duration", summary=summary, attempts=names,
                         attempt=attempt.start.name, violations=violated(best),
                         durations=durations(scene), shortest_duration=probe.shortest)


def annotate(plan: Plan, scene: Scene, attempts: list[Attempt], best: Outcome,
             attempt: Attempt, probe: Probe | None = None) -> Plan:
    """The plan with its infeasibility when the duration probe shows the duration too
    short or the attempts agree (its message says so); otherwise, for a plan that did not
    converge, a message that also names the attempt that reported infeasibility, if any."""
    if plan.solver.success:
        return plan
    found: Infeasibility | None = None
    if probe is not None and probe.too_short:
        found = too_short(scene, attempts, best, attempt, probe)
    elif agreed(attempts):
        found = evidence(scene, attempts, best, attempt)
        if probe is not None and probe.shortest is not None:
            found = found.model_copy(update={
                "shortest_duration": probe.shortest,
                "summary": f"{found.summary}; {probe.note}"})
    if found is not None:
        report = plan.solver.model_copy(update={"message": found.summary})
        return plan.model_copy(update={"infeasibility": found, "solver": report})
    informative = most_informative(attempts)
    if informative is None or informative[0] is best:
        return plan
    outcome, other = informative
    rows = violated(outcome)
    worst = f" (largest violation: {rows[0].kind} by {rows[0].largest:.3g})" if rows else ""
    note = (f"{plan.solver.message}; the attempt '{other.start.name}' ended "
            f"{outcome.solution.status}{worst}")
    return plan.model_copy(update={"solver": plan.solver.model_copy(update={"message": note})})


def refused(scene: Scene, issues: list[Issue], started: float, T: float) -> Plan:
    """The plan of a task that the checks before a solve hold infeasible: no trajectory
    (empty lists), no solve, the issues as `infeasibility.fields`."""
    listed = "; ".join(str(issue) for issue in issues)
    summary = f"the task is infeasible before any solve: {listed}"
    return Plan(
        status="infeasible", message=f"infeasible: {summary}",
        t=[], q=[], dq=[], ddq=[], tau=[], dense=DenseTrajectory(t=[], q=[], tau=[]),
        torque=None, duration=T, objective=None,
        waves=waves_of(scene.robot),
        solver=SolverReport(status=CHECKS_STATUS, success=False, message=summary,
                            iterations=0, build_time=0.0, solve_time=0.0,
                            total_time=time.perf_counter() - started, cache_hit=False,
                            initial_guess="none: no solve ran", strategy="checks before a solve"),
        mesh_passes=[], feedback=None,
        verification=Verification(
            resimulation_error=None, resimulation_status="not run: the task is infeasible",
            verified=False, converged=False, tolerance=scene.solver.resimulation_tolerance,
            defect=None, min_sigma=None, waveless_min_sigma=None,
            waveless_singular_crossings=[]),
        infeasibility=Infeasibility(
            source="checks", summary=summary,
            fields=[InfeasibleField(field=i.field, kind=i.kind, message=i.message)
                    for i in issues],
            durations=durations(scene)))
