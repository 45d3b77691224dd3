"""What every benchmark shares: the run manifest, timing, isolation, and writers.

A benchmark is a module of this package with `main(argv)`, registered in
`bench.__main__.BENCHES` and run as `python -m bench NAME [options]`. It writes its rows
as CSV under bench/results/ and its table (and plot) into a section of a document under
docs/, which ends with the manifest: the command that regenerates it, the commit of the
code measured and the machine. Every output goes through `output`, so that a run given
another folder (`--out DIR`, or `--smoke`: `bench.smoke`) writes there instead.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import platform
import re
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from planner.ocp.problem import ProblemKey, cached_problem, problem
from planner.ocp.solvers.ipopt import IPOPT, IPOPT_OPTIONS
from planner.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
DOCS = ROOT / "docs"
PYTHON = sys.executable
_TIMEOUT = "timeout after"  # how a child's failure says it was stopped
_outputs: list[Path] = []  # the folder every output goes to instead of ROOT, while one is set


def output(path: Path) -> Path:
    """Where an output meant for `path` (under ROOT: docs/, bench/results/) is written: the
    path itself, or its place under the folder `outputs_to` set; its folder exists."""
    target = _outputs[-1] / Path(path).resolve().relative_to(ROOT) if _outputs else Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    return target


@contextlib.contextmanager
def outputs_to(folder: Path) -> Iterator[Path]:
    """Within, every output (`output`) goes under `folder`, laid out as under ROOT."""
    _outputs.append(Path(folder).resolve())
    try:
        yield _outputs[-1]
    finally:
        _outputs.pop()


def shared_arguments(argv: Sequence[str]) -> tuple[argparse.Namespace, list[str]]:
    """The options every benchmark takes, `--smoke` and `--out DIR`, and the arguments left
    for the benchmark's own parser."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--smoke", action="store_true",
                        help="the smallest inputs (bench.smoke), outputs to a temporary folder")
    parser.add_argument("--out", type=Path, default=None,
                        help="write the outputs under this folder instead of docs/ and "
                             "bench/results/")
    return parser.parse_known_args(list(argv))


class CpuTimed:
    """Wraps a cached NLP's solver Function to record the CPU time [s] of its last call
    (CPU time is what other load on a shared machine disturbs least), the part of it spent
    in the kernel on the process's behalf [s] and the page faults it took."""

    def __init__(self, solver: ca.Function):
        self.solver, self.cpu, self.kernel, self.faults = solver, math.nan, math.nan, 0

    def __call__(self, **kwargs):
        start, usage = time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
        try:
            return self.solver(**kwargs)
        finally:
            self.cpu = time.process_time() - start
            after = resource.getrusage(resource.RUSAGE_SELF)
            self.kernel = after.ru_stime - usage.ru_stime
            self.faults = after.ru_minflt - usage.ru_minflt

    def stats(self) -> dict:
        return self.solver.stats()

    def __getattr__(self, name: str) -> object:
        """Everything else of the wrapped solver (its derivative functions, for instance)."""
        return getattr(self.solver, name)


def build_instrumented(scene: Scene) -> tuple[float, CpuTimed]:
    """Build (or fetch) the NLP of the scene's first mesh; its build time [s] and its
    solver, wrapped to record the CPU time of each solve."""
    prob = problem(ProblemKey.of(scene), wait=True)
    timed = prob.solver if isinstance(prob.solver, CpuTimed) else CpuTimed(prob.solver)
    prob.solver = timed  # type: ignore[assignment]  # a stand-in with the Function's calls
    return prob.build_time, timed


@contextlib.contextmanager
def ipopt_options(options: dict, idle: bool | None = None) -> Iterator[None]:
    """NLPs built within use `planner.ocp.solvers.ipopt.IPOPT_OPTIONS` updated with `options`
    and, unless idle is None, have the idle variable or not (`Ipopt.idle_variable`); the
    cache of built NLPs is cleared on entry and on exit (a solver holds its options)."""
    saved, saved_idle = dict(IPOPT_OPTIONS), IPOPT.idle_variable
    IPOPT_OPTIONS.update(options)
    if idle is not None:
        IPOPT.idle_variable = idle
    cached_problem.cache_clear()
    try:
        yield
    finally:
        IPOPT_OPTIONS.clear()
        IPOPT_OPTIONS.update(saved)
        IPOPT.idle_variable = saved_idle
        cached_problem.cache_clear()


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
            f"at the start); Python {platform.python_version()}, CasADi {ca.CasadiMeta.version()}, "
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


def cpu_time() -> float:
    """CPU time [s] of this process and its waited-for children (solver companions, peers
    run in processes of their own)."""
    child = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + child.ru_utime + child.ru_stime


def median(values: Iterable[float]) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(values) if values else math.nan


def isolated(module: str, function: str, kwargs: dict, timeout: float) -> dict:
    """Run bench.<module>.<function>(**kwargs) -> dict in a fresh Python process (module
    may be dotted: "peers.opti").

    Returns its dict, or {"failure": "exit ...: ..."} or `timed_out(timeout)`: a point that
    hangs or crashes is recorded as such instead of ending the run.
    """
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); "
            f"from bench.{module} import {function} as f; "
            f"out = f(**json.loads(sys.argv[1])); print('RESULT ' + json.dumps(out))")
    return run_at(ROOT, code, [json.dumps(kwargs)], timeout)


def run_at(root: Path, code: str, args: Sequence[str], timeout: float) -> dict:
    """Run the Python `code` with `args` in a fresh process whose working directory is
    `root` (a checkout); the dict of its last "RESULT {json}" line, or {"failure": ...}."""
    try:
        run = subprocess.run([PYTHON, "-c", code, *args], cwd=root, check=False,
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return timed_out(timeout)
    results = result_lines(run.stdout)
    return results[-1] if results else {"failure": f"exit {run.returncode}: {last_error(run)}"}


def timed_out(timeout: float) -> dict:
    """What a child stopped after `timeout` [s] returns in place of its result."""
    return {"failure": f"{_TIMEOUT} {timeout:g} s"}


def stopped(out: dict) -> bool:
    """Whether a child's dict is `timed_out`'s (it was stopped, rather than crashed)."""
    return str(out.get("failure", "")).startswith(f"{_TIMEOUT} ")


def result_lines(stdout: str) -> list[dict]:
    """The dicts of a child's "RESULT {json}" lines, in order."""
    return [json.loads(line[len("RESULT "):]) for line in stdout.splitlines()
            if line.startswith("RESULT ")]


def last_error(run: subprocess.CompletedProcess) -> str:
    """The last line a child wrote to stderr (200 characters at most)."""
    return (run.stderr.strip().splitlines() or ["no output"])[-1][:200]


@contextlib.contextmanager
def checkout(commit: str) -> Iterator[Path]:
    """This repository at `commit`, as a temporary git worktree removed on exit."""
    with tempfile.TemporaryDirectory() as work:
        path = Path(work) / "checkout"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path),
                        commit], check=True, capture_output=True)
        try:
            yield path
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)],
                           check=False, capture_output=True)


def read_csv(path: Path) -> list[dict]:
    """Rows written by `write_csv`, with booleans, numbers and NaN read back as such."""
    def value(text: str) -> object:
        if text in ("True", "False"):
            return text == "True"
        try:
            return int(text)
        except ValueError:
            pass
        try:
            return float(text)
        except ValueError:
            return text

    with open(path, newline="") as f:
        return [{k: value(v) for k, v in row.items()} for row in csv.DictReader(f)]


def write_csv(path: Path, rows: Sequence[dict]) -> None:
    """Rows as CSV, every key of any row a column (empty where a row has none, as rows kept
    from a run before a column existed); floats with 6 significant digits."""
    with open(output(path), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
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
    path = output(path)
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


def manifest(name: str, argv: Sequence[str], started: float, machine: str) -> str:
    """The closing line of a benchmark's doc section: how to regenerate it, how long it ran,
    and `machine` (its `machine_note()` taken at the start)."""
    command = " ".join(["python -m bench", name, *map(shlex.quote, argv)])
    return (f"Regenerate: `{command}` ({time.perf_counter() - started:.0f} s). "
            f"Measured on {machine}.")
