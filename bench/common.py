"""Shared pieces of the planner benchmarks: reference scenes, timing, machine note, output.

Scenes:
- "seed-hang" (`hanging_scene`): the seed's 4-link arm (tests/seed_printed.py SEED_ARM,
  g = 9.81) with its passive links 0 and 2 hanging at rest (q = 0), active link 1 swung
  in 1.6 s from 1.45 to 1.70 rad across the horizontal, where the waveless M_pa is
  singular, link 3 at -0.8 rad; coupling margin 0.005, effort objective (the built-in
  example `seed-arm-plan`, whose transcription the benches set themselves);
- "seed-4" (`seed_scene`): the same arm in a horizontal plane (g = 0), rest to rest in
  4 s between two configurations whose straight path crosses waveless coupling
  singularities, coupling margin 0.02, effort objective. Without gravity the passive base
  keeps the arm's angular momentum at zero, so every net turn of it needs a loop of the
  other joints: a far harder NLP;
- "arm-2": tests/test_ocp.py ARM (both joints active, under gravity) with that module's
  1 s task (0, 0.5) -> (0.6, 1.2) rad;
- "under-2": tests/test_ocp.py UNDERACTUATED (passive shoulder, g = 0), rest to rest in
  2 s from (0, 0.5) to (0.3, 1.0) rad. (test_ocp's 1 s task (0.6, 1.2) needs the passive
  shoulder to swing fast, and Ipopt then ends in a different local optimum at every N.)
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.interpolate import CubicSpline

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from seed_printed import SEED_ARM
from test_ocp import ARM, UNDERACTUATED

from planner.examples import example
from planner.ocp import Plan
from planner.ocp.problem import ProblemKey, problem
from planner.scene import Scene

RESULTS = ROOT / "bench" / "results"
DOCS = ROOT / "docs"
PYTHON = sys.executable

SEED_TASK = {"duration": 4.0,
             "initial": {"q": [0.766, -1.157, -1.148, -1.287], "dq": [0.0] * 4},
             "final": {"q": [0.676, -0.67, -1.306, -1.202], "dq": [0.0] * 4},
             "coupling_margin": 0.02, "objective": {"effort": 1.0}}
TWO_LINK_TASK = {"duration": 1.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
                 "final": {"q": [0.6, 1.2], "dq": [0.0, 0.0]}}
HANGING = example("seed-arm-plan").request
ROBOTS = {"seed-4": {**SEED_ARM, "gravity": 0.0}, "seed-hang": HANGING["robot"], "arm-2": ARM,
          "under-2": UNDERACTUATED}
UNDER_TASK = {"duration": 2.0, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
              "final": {"q": [0.3, 1.0], "dq": [0.0, 0.0]}}
TASKS = {"seed-4": SEED_TASK, "seed-hang": HANGING["task"], "arm-2": TWO_LINK_TASK,
         "under-2": UNDER_TASK}


def make_scene(name: str, method: str = "legendre", N: int = 50, degree: int = 3,
               solver: dict | None = None, **transcription) -> Scene:
    """The named reference scene ("seed-hang", "seed-4", "arm-2", "under-2") with a
    transcription."""
    return Scene.model_validate({
        "robot": ROBOTS[name], "task": TASKS[name],
        "transcription": {"method": method, "intervals": N, "degree": degree, **transcription},
        "solver": solver or {}})


def seed_scene(N: int = 100, degree: int = 3, **kw) -> Scene:
    """The seed's 4-link arm in a horizontal plane (Legendre collocation by default)."""
    return make_scene("seed-4", N=N, degree=degree, **kw)


def hanging_scene(N: int = 100, degree: int = 3, **kw) -> Scene:
    """The seed's 4-link arm hanging in gravity (Legendre collocation by default)."""
    return make_scene("seed-hang", N=N, degree=degree, **kw)


class CpuTimed:
    """Wraps a cached NLP's solver Function to record the CPU time [s] of its last call
    (CPU time is what other load on a shared machine disturbs least)."""

    def __init__(self, solver: ca.Function):
        self.solver, self.cpu = solver, math.nan

    def __call__(self, **kwargs):
        start = time.process_time()
        try:
            return self.solver(**kwargs)
        finally:
            self.cpu = time.process_time() - start

    def stats(self) -> dict:
        return self.solver.stats()


def build_instrumented(scene: Scene) -> tuple[float, CpuTimed]:
    """Build (or fetch) the scene's NLP; its build time [s] and its CPU-timed solver."""
    prob = problem(ProblemKey.of(scene))
    if not isinstance(prob.solver, CpuTimed):
        prob.solver = CpuTimed(prob.solver)
    return prob.build_time, prob.solver


def load() -> str:
    """The 1, 5 and 15 minute load averages, as `uptime` prints them."""
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f}, {five:.2f}, {fifteen:.2f}"


def machine_note() -> str:
    """CPU, core count, load, and versions: the line every benchmark output starts with."""
    cpu = platform.processor() or platform.machine()
    with open("/proc/cpuinfo") as f:
        names = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
    if names:
        cpu = names[0]
    return (f"{cpu}, {os.cpu_count()} cores shared with other work (load average {load()} "
            f"at the start); Python {platform.python_version()}, CasADi {ca.__version__}, "
            f"NumPy {np.__version__}; planner/ at commit {planner_commit()}")


def last_commit(path: Path) -> str:
    """The last commit (short hash) that changed a file or folder, 'unknown' outside a checkout."""
    return subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h", "--", str(path)],
                          check=False, capture_output=True, text=True).stdout.strip() or "unknown"


def planner_commit() -> str:
    """The last commit that touched planner/ (the code measured), '+ local changes' if any."""
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "planner"],
                           check=False, capture_output=True, text=True).stdout.strip()
    return last_commit(ROOT / "planner") + (" + local changes" if dirty else "")


def timed(fn: Callable[[], object]) -> tuple[object, float, float]:
    """fn(), its wall time [s] and the CPU time [s] of this process."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def median(values: Iterable[float]) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(values) if values else math.nan


def verified(plan: Plan) -> bool:
    """Ipopt succeeded and the plan passed its re-simulation check (`verification.verified`)."""
    return plan.solver.success and bool(plan.verification.verified)


def dense_error(plan: Plan, reference: Plan) -> float:
    """max |q_plan - q_ref| [rad] over the plan's dense samples, the reference's dense output
    interpolated by a not-a-knot cubic spline (its own error is below 1e-9 rad here)."""
    t, q = np.asarray(plan.dense.t), np.asarray(plan.dense.q)
    spline = CubicSpline(np.asarray(reference.dense.t), np.asarray(reference.dense.q))
    return float(np.abs(q - spline(t)).max())


def spline_floor(reference: Plan) -> float:
    """Interpolation error of `dense_error`'s spline: fit every other dense sample of the
    reference, compare at the ones left out [rad] (an upper estimate of the floor)."""
    t, q = np.asarray(reference.dense.t), np.asarray(reference.dense.q)
    spline = CubicSpline(t[::2], q[::2])
    return float(np.abs(spline(t[1::2]) - q[1::2]).max())


def isolated(module: str, function: str, kwargs: dict, timeout: float) -> dict:
    """Run bench.<module>.<function>(**kwargs) -> dict in a fresh Python process.

    Returns its dict, or {"failure": "timeout after ... s" | "exit ...: ..."}: a point that
    hangs or crashes is recorded as such instead of ending the run.
    """
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); "
            f"from bench.{module} import {function} as f; "
            f"out = f(**json.loads(sys.argv[1])); print('RESULT ' + json.dumps(out))")
    try:
        run = subprocess.run([PYTHON, "-c", code, json.dumps(kwargs)], cwd=ROOT, check=False,
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"failure": f"timeout after {timeout:g} s"}
    for line in run.stdout.splitlines()[::-1]:
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    tail = (run.stderr.strip().splitlines() or ["no output"])[-1]
    return {"failure": f"exit {run.returncode}: {tail[:200]}"}


def write_csv(path: Path, rows: Sequence[dict]) -> None:
    """Rows (dicts with the same keys) as CSV; floats with 6 significant digits."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})


def fmt(value: object, digits: int = 3) -> str:
    """A table cell: floats with `digits` significant digits, None and NaN as a dash."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def table(rows: Sequence[dict], columns: Sequence[tuple[str, str]]) -> str:
    """A Markdown table of rows; columns are (key, heading)."""
    head = "| " + " | ".join(h for _, h in columns) + " |"
    rule = "|" + "|".join("---" if i == 0 else "---:" for i in range(len(columns))) + "|"
    body = ["| " + " | ".join(fmt(row.get(k)) for k, _ in columns) + " |" for row in rows]
    return "\n".join([head, rule, *body])


def write_section(path: Path, heading: str, text: str) -> None:
    """Replace (or append) the `## heading` section of a Markdown file with text."""
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = path.read_text() if path.exists() else ""
    block = f"## {heading}\n\n{text.strip()}\n"
    pattern = re.compile(rf"^## {re.escape(heading)}\n.*?(?=^## |\Z)", re.DOTALL | re.MULTILINE)
    if pattern.search(doc):
        doc = pattern.sub(lambda _: block + "\n", doc).rstrip() + "\n"
    else:
        doc = doc.rstrip() + ("\n\n" if doc else "") + block
    path.write_text(doc)


def loglog_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log y against log x (the growth exponent)."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(lx, ly, 1)[0])
