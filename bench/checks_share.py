"""The checks' share of a plan on the task suite: `python -m bench verification --parts
suite` (bench/verification.py).

Every task of the default suite (`testbed.suites.ordinary`), as the suite generates it
("plain") and as `python -m bench suite` states it for the default planner, with its
`task.uncertainty`, so that the robustness replays run ("uncertain"), is planned in a
fresh process of each version, BLOCK tasks a process, the versions taking turns: once to
build its NLPs (as a service worker keeps them),
then `--repeats` times measured, with core tokens of its own (`UNDERTOW_CORE_DIR`: a
plan with passive joints forks its companion whatever else holds the machine's tokens,
in both versions alike). Per plan:
its wall time and CPU time (the process and its waited-for children, the companion
among them), its solves' time (`solver.solve_time`) and its checks after the last solve
(`solver.checks_time`, `solver.checks_cpu_time`: that solve's interval errors and
open-loop replay, the verification with the feedback, closed-loop replays and
robustness, and assembling the plan), and their share of the plan; of the checks, the
time this process spent re-integrating in CVODES (every `planner.ocp.flow.quiet` call
after the last solve ended; none for a version without it) and, of that, the one replay
run of all lanes (`planner.ocp.replays.replays` as `planner.ocp.verify` calls it), timed
as it runs beside the other checks.
"""

from __future__ import annotations

import contextlib
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench import harness
from bench.suite import UNCERTAINTY
from testbed.suites.ordinary import COUNT, SEED, tasks

SECTION = "Verification: the checks' share of a plan on the task suite"
BLOCK = 6
"""Tasks one process plans before the other version's process plans the same ones."""
CSV = harness.RESULTS / "verification_suite.csv"

_RUN = """
import json, os, resource, sys, tempfile, time
os.environ["UNDERTOW_CORE_DIR"] = tempfile.mkdtemp(prefix="undertow-cores-")
sys.path.insert(0, {root!r})
import importlib
from planner import compiled
from planner.ocp import plan
from planner.scene import Scene
calls, runs = [], []
def timed(call, into):
    def wrapped(*args, **kwargs):
        started = time.perf_counter()
        try:
            return call(*args, **kwargs)
        finally:
            into.append((started, time.perf_counter() - started))
    return wrapped
for name in ("planner.ocp.flow", "planner.ocp.replays"):  # an older version may lack either
    try:
        module = importlib.import_module(name)
    except ImportError:
        continue
    if hasattr(module, "quiet"):
        module.quiet = timed(module.quiet, calls)
try:
    checking = importlib.import_module("planner.ocp.verify")
except ImportError:  # a version before the verification had a module of its own
    checking = None
if hasattr(checking, "replays"):  # the one replay run of every lane, where a version has it
    checking.replays = timed(checking.replays, runs)
def after_solve(records, checks, ended):  # the records begun after the last solve, summed
    inside = [d for t, d in records if checks is not None and t >= ended - checks]
    return sum(inside) if inside else None
def cpu():
    child = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + child.ru_utime + child.ru_stime
chosen = [(name, Scene.model_validate(body)) for name, body in json.load(open(sys.argv[1]))]
for _, scene in chosen:
    plan(scene)
compiled.wait()
rows = []
for _ in range({repeats}):
    for name, scene in chosen:
        calls.clear()
        runs.clear()
        started, used = time.perf_counter(), cpu()
        result = plan(scene)
        ended = time.perf_counter()
        wall, spent = ended - started, cpu() - used
        s = result.solver
        checks = getattr(s, "checks_time", None)
        rows.append({{"task": name, "verified": bool(s.success and result.verification.verified),
                      "intervals": len(result.t) - 1, "solves": len(result.mesh_passes),
                      "wall": wall, "cpu": spent, "solve": s.solve_time,
                      "checks": checks,
                      "checks_cpu": getattr(s, "checks_cpu_time", None),
                      "reintegrations": after_solve(calls, checks, ended),
                      "replays": after_solve(runs, checks, ended)}})
print("RESULT " + json.dumps({{"rows": rows}}))
"""
VARIANTS = {"plain": "as the suite generates them",
            "uncertain": "as `python -m bench suite` states them for the default planner, "
                         "with its task.uncertainty"}
"""The ways the suite's tasks are stated: plain (no uncertainty: no robustness replays)
and uncertain (every link's mass off both ways: the robustness replays run)."""
SUMMARY = [("variant", "tasks"), ("version", "version"), ("plans", "plans"),
           ("verified", "verified"), ("wall", "median plan [s]"),
           ("checks", "median checks [s]"), ("share", "median checks / plan [%]"),
           ("p90", "90th percentile [%]"), ("worst", "worst [%]"),
           ("total", "all checks / all plans [%]"),
           ("cpu_share", "median checks CPU / plan CPU [%]"), ("cpu_worst", "worst, CPU [%]"),
           ("reint_share", "median re-integrations / plan [%]"),
           ("replay_share", "median replay run / plan [%]")]


def columns(versions: Sequence[str]) -> list[tuple[str, str]]:
    """The per-task table's columns: each version's plan, checks and shares side by side."""
    out = [("task", "task"), ("variant", "tasks"), ("intervals", "intervals"),
           ("solves", "solves")]
    for v in versions:
        out += [(f"wall {v}", f"{v}: plan [s]"), (f"checks {v}", "checks [s]"),
                (f"share {v}", "checks / plan [%]"),
                (f"cpu_share {v}", "checks CPU / plan CPU [%]"),
                (f"reint_share {v}", "re-integrations / plan [%]"),
                (f"replay_share {v}", "replay run / plan [%]")]
    return out


def scenes(count: int, seed: int, variant: str) -> list[tuple[str, dict]]:
    """The suite's tasks, plain or with the suite bench's UNCERTAINTY (`VARIANTS`)."""
    out = []
    for name, scene in tasks(count, seed):
        body = scene.model_dump(mode="json")
        if variant == "uncertain":
            body = {**body, "task": {**body["task"], "uncertainty": UNCERTAINTY}}
        out.append((name, body))
    return out


def measured(root: Path, chosen: list[tuple[str, dict]], repeats: int) -> list[dict]:
    """The rows of one version (the checkout at `root`), in a fresh process."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tasks.json"
        path.write_text(json.dumps(chosen))
        out = harness.run_at(root, _RUN.format(root=str(root), repeats=repeats), [str(path)],
                             3600)
    if "failure" in out:
        raise RuntimeError(f"{root}: {out['failure']}")
    return [{**row, "share": _ratio(row["checks"], row["wall"]),
             "cpu_share": _ratio(row["checks_cpu"], row["cpu"]),
             "reint_share": _ratio(row["reintegrations"], row["wall"]),
             "replay_share": _ratio(row.get("replays"), row["wall"])} for row in out["rows"]]


def _ratio(part: float | None, whole: float) -> float | None:
    """part / whole [%] (None without the part)."""
    return None if part is None or whole <= 0 else 100.0 * part / whole


def summary(variant: str, version: str, rows: Sequence[dict]) -> dict:
    """Medians, the 90th percentile and the worst of the checks' share over the plans."""
    shares = [r["share"] for r in rows if r["share"] is not None]
    cpu = [r["cpu_share"] for r in rows if r["cpu_share"] is not None]
    checks = [r["checks"] for r in rows if r["checks"] is not None]
    again = [r["reint_share"] for r in rows if r["reint_share"] is not None]
    replayed = [r["replay_share"] for r in rows if r["replay_share"] is not None]
    return {"variant": variant, "version": version, "plans": len(rows),
            "verified": sum(r["verified"] for r in rows),
            "wall": harness.median(r["wall"] for r in rows), "checks": harness.median(checks),
            "share": harness.median(shares),
            "p90": float(np.percentile(shares, 90)) if shares else None,
            "worst": max(shares, default=None),
            "total": _ratio(sum(checks), sum(r["wall"] for r in rows)) if checks else None,
            "cpu_share": harness.median(cpu), "cpu_worst": max(cpu, default=None),
            "reint_share": harness.median(again) if again else None,
            "replay_share": harness.median(replayed) if replayed else None}


def run(before: str | None, count: int, seed: int, repeats: int,
        variants: Sequence[str]) -> tuple[str, list[dict]]:
    """The section's text and the rows of this checkout and, unless None, of `before`, for
    each variant of the tasks."""
    rows: list[dict] = []
    with harness.checkout(before) if before else contextlib.nullcontext(None) as old:
        for variant in variants:
            chosen = scenes(count, seed, variant)
            for first in range(0, len(chosen), BLOCK):  # the versions in turn, block by
                # block: both meet the machine's other work alike
                for version, root in (("now", harness.ROOT), (before, old)):
                    if root is not None:
                        rows += [{**r, "variant": variant, "version": version} for r in
                                 measured(root, chosen[first:first + BLOCK], repeats)]
    versions = list(dict.fromkeys(r["version"] for r in rows))
    table = [summary(a, v, [r for r in rows if (r["variant"], r["version"]) == (a, v)])
             for a in variants for v in versions]
    return _text(before, count, seed, repeats, variants, table, _side_by_side(rows)), rows


def _side_by_side(rows: Sequence[dict]) -> list[dict]:
    """One row per task and variant, each version's figures in columns of their own."""
    out: dict[tuple[str, str], dict] = {}
    for r in rows:
        row = out.setdefault((r["task"], r["variant"]), {
            "task": r["task"], "variant": r["variant"], "intervals": r["intervals"],
            "solves": r["solves"]})
        row.update({f"{k} {r['version']}": r[k] for k in ("wall", "checks", "share",
                                                           "cpu_share", "reint_share",
                                                           "replay_share")})
    return [out[k] for k in sorted(out)]


def _text(before: str | None, count: int, seed: int, repeats: int, variants: Sequence[str],
          table: list[dict], tasks_table: list[dict]) -> str:
    suite = "" if (count, seed) == (COUNT, SEED) else f" ({count} tasks, seed {seed})"
    stated = "; ".join(f"{v}: {VARIANTS[v]}" for v in variants)
    return "\n\n".join([
        f"Every task of the default suite{suite} ({stated}; uncertainty: every link's mass "
        f"±{UNCERTAINTY['mass']:.0%}), planned in fresh processes of each version of one "
        f"run, {BLOCK} tasks a process, the versions taking turns: once to build its NLPs, "
        f"then measured ({repeats} plan(s) a task). The "
        "checks are everything after the plan's last solve (`solver.checks_time`): that "
        "solve's interval errors and open-loop replay, the verification with the feedback "
        "and its closed-loop replays (and the robustness replays, with an uncertainty), "
        "and assembling the plan; CPU times count the process and its companion (each "
        "process has core tokens of its own, so every plan whose continuation applies "
        "forks one). Re-integrations: what the plan's process spent in CVODES after the "
        "last solve ended (that solve's interval errors, the open-loop, closed-loop and "
        "robustness replays: every call of `planner.ocp.flow.quiet` then), as a share of "
        "the plan's wall time; none where that process made none (the companion's plan, "
        "checked in the companion's process). Replay run: of those, the one whole-horizon "
        "run of every lane (`planner.ocp.replays.replays` as the verification calls it: "
        "the open-loop, closed-loop and robustness replays), which the other checks run "
        "beside; none for a version without it."
        + (f" {before}: the planner of that commit, in the same run." if before else ""),
        harness.table(table, SUMMARY),
        harness.table(tasks_table, columns([c for c in ("now", before) if c]))])
