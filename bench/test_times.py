"""`make test` from a fresh clone, on a quiet machine and with every core kept busy by
another process: does it pass, and how long does it take.

Each run clones this repository's HEAD into a temporary folder, builds its virtualenv
once (`make install`, not timed; `--venv` reuses one instead) and then times `make test`
(the README's command). A
loaded run first starts one busy process per core (`nice 0` Python loops), as a build
server or another job would, and stops them afterwards. The busy processes take CPU
time only, so the test suite's tests that depend on how fast something runs would fail
here; none should.

Writes bench/results/test_times.csv (a row per run: how it ran, passed or not, the
counts pytest printed, the failed tests' ids, wall time) and the section "make test, quiet
and loaded" of docs/benchmarks.md.

    python -m bench test_times [--runs quiet,loaded,loaded] [--pytest-args ARGS]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path

from bench import harness

CSV = harness.RESULTS / "test_times.csv"
DOC = harness.DOCS / "benchmarks.md"
SECTION = "make test, quiet and loaded"
TIMEOUT = 3600.0  # [s] a run still going then has hung


def _busy() -> None:
    """Spin forever: one core's worth of load."""
    while True:
        pass


def _clone(folder: Path, venv: str | None) -> list[str]:
    """A fresh clone of HEAD with its virtualenv built (or `venv` reused): the make command
    that tests it."""
    work = folder / "clone"
    subprocess.run(["git", "clone", "--quiet", str(harness.ROOT), str(work)], check=True)
    make = ["make", "-C", str(work)] + ([f"VENV={venv}"] if venv else [])
    subprocess.run([*make, "install"], check=True, capture_output=True)
    return make


def _reinstall(venv: str) -> None:
    """Point a reused virtualenv's editable install back at this checkout: the clone's
    `make install` pointed it at the clone, which is gone once the runs end (the
    `undertow` command then finds no package)."""
    subprocess.run([str(Path(venv) / "bin" / "python"), "-m", "pip", "install", "--quiet",
                    "--no-deps", "-e", str(harness.ROOT)], check=True, capture_output=True)


def _counts(output: str) -> str:
    """pytest's last summary line, e.g. "1374 passed, 3 skipped in 480.1s"."""
    lines = [line.strip("= ") for line in output.splitlines() if re.search(r" in [\d.]+s", line)]
    return lines[-1] if lines else "no summary"


def _failed(output: str) -> str:
    """The ids of the tests pytest reported as failed or in error, `;`-separated."""
    ids = re.findall(r"^(?:FAILED|ERROR) (\S+)", output, flags=re.MULTILINE)
    return ";".join(dict.fromkeys(ids))


def _run(make: list[str], loaded: bool, pytest_args: str) -> dict:
    """One timed `make test`, with one busy process per core when `loaded`."""
    busy = [multiprocessing.Process(target=_busy, daemon=True)
            for _ in range(os.cpu_count() or 1)] if loaded else []
    for proc in busy:
        proc.start()
    started = time.perf_counter()
    try:
        run = subprocess.run([*make, "test", f"PYTEST_ARGS={pytest_args}"],
                             capture_output=True, text=True, timeout=TIMEOUT, check=False)
    finally:
        elapsed = time.perf_counter() - started
        for proc in busy:
            proc.terminate()
    return {"run": "loaded" if loaded else "quiet", "busy_processes": len(busy),
            "passed": run.returncode == 0, "pytest": _counts(run.stdout + run.stderr),
            "failed": _failed(run.stdout + run.stderr), "wall_s": elapsed}


def text(rows: list[dict], argv: list[str], started: float, note: str) -> str:
    setup = ("`make test` (the README's command) from a fresh clone of the commit below, its "
             "virtualenv built first and not timed; a loaded run with one busy process per "
             "core started before it and stopped after it.")
    columns = [("run", "run"), ("busy_processes", "busy processes"), ("passed", "passed"),
               ("pytest", "pytest's summary"), ("failed", "failed tests"), ("wall_s", "wall [s]")]
    return "\n\n".join([setup, harness.table(rows, columns),
                        f"Rows: `bench/results/test_times.csv`. "
                        f"{harness.manifest('test_times', argv, started, note)}"])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench test_times", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", default="quiet,loaded,loaded",
                        help="comma-separated: quiet or loaded, in order")
    parser.add_argument("--pytest-args", default="",
                        help="PYTEST_ARGS for make test (the smoke run selects one file)")
    parser.add_argument("--venv", default=None,
                        help="reuse this virtualenv instead of building one in the clone")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    try:
        with tempfile.TemporaryDirectory(prefix="undertow-test-times-") as folder:
            make = _clone(Path(folder), args.venv)
            rows = [_run(make, kind == "loaded", args.pytest_args)
                    for kind in args.runs.split(",")]
    finally:
        if args.venv:
            _reinstall(args.venv)
    for row in rows:
        print(row, flush=True)
    harness.write_csv(CSV, rows)
    harness.write_section(DOC, SECTION, text(rows, argv, started, note))
    return 0 if all(row["passed"] for row in rows) else 1
