"""Every benchmark runs: its small mode (`python -m bench NAME --smoke`, bench/smoke.py) goes
through the same code as its real run on the smallest inputs, in a process of its own, and
must end without an error and write its results under the folder it is given (never over
the committed ones). Also: `python -m bench list` names every benchmark with its last
committed run, and the headline table of docs/benchmarks.md is the one the committed
results give.

A benchmark whose small mode needs what this machine lacks (docker and the image, a
PostgreSQL server, the opty virtualenv) is skipped, saying why; those whose small mode
takes over SLOW_AFTER are `slow` (`make test-slow`).
"""

from __future__ import annotations

import fnmatch
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bench import headline, runs, smoke
from bench.__main__ import BENCHES
from bench.harness import ROOT

SLOW_AFTER = 20.0
"""[s] A small mode that takes longer on this 2-core machine is `slow`."""
SLOW = frozenset({"blas_threads", "cluster_ops", "container", "faults", "iteration_cost",
                  "job_latency", "peer_opty", "pickup",
                  "planner_internals", "refined_tails", "reliability", "replan", "scale_out",
                  "seed_iterations", "stress", "suite", "test_times"})
"""The benchmarks whose small mode takes over SLOW_AFTER (bench/smoke.py says what they
run): live servers and clusters, faults and their recovery, compiled NLPs (jit), peers
in processes of their own, the horizontal seed arm, hard tasks in two checkouts, make
test itself."""
TIMEOUT = 900.0  # [s] a small mode still running then has hung


def _params() -> list:
    return [pytest.param(name, marks=pytest.mark.slow) if name in SLOW else name
            for name in BENCHES]


def _written(folder: Path) -> list[Path]:
    return sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())


@pytest.mark.parametrize("name", _params())
def test_small_mode_runs_and_writes_its_results_elsewhere(name: str, tmp_path: Path):
    reason = smoke.missing(name)
    if reason is not None:
        pytest.skip(reason)
    run = subprocess.run([sys.executable, "-m", "bench", name, "--smoke", "--out", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT, check=False)
    if run.returncode != 0:
        output = "\n".join((run.stdout + run.stderr).splitlines()[-30:])
        pytest.fail(f"python -m bench {name} --smoke ended {run.returncode}:\n{output}")
    written = _written(tmp_path)
    assert any(p.suffix == ".md" for p in written), f"no document section written: {written}"
    for path in written:
        if path.suffix == ".md":
            assert (ROOT / path).exists(), f"{path}: a document the checkout does not have"
        else:  # `python -m bench list` reads the run's commit off these files
            assert any(fnmatch.fnmatch(str(path), p) for p in runs.RESULTS[name]), \
                f"{path}: not among bench/runs.py's results of {name}"


def test_every_benchmark_has_a_small_mode_and_results():
    assert set(smoke.SMALL) == set(BENCHES)
    assert set(runs.RESULTS) == set(BENCHES)
    assert set(SLOW) <= set(BENCHES)


def test_list_names_each_benchmark_with_its_last_run():
    run = subprocess.run([sys.executable, "-m", "bench", "list"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=True)
    lines = run.stdout.splitlines()
    assert [line.split()[0] for line in lines] == list(BENCHES)
    for line, (_, what) in zip(lines, BENCHES.values(), strict=True):
        assert re.match(r"\S+\s+([0-9a-f]{7,} \d{4}-\d\d-\d\d|never)\s+", line), line
        assert line.endswith(what)


def test_the_headline_table_is_the_committed_results():
    doc = (ROOT / "docs" / "benchmarks.md").read_text()
    section = re.search(rf"^## {headline.SECTION}\n\n(.*?)\n(?=^## )", doc,
                        re.DOTALL | re.MULTILINE)
    assert section is not None, f"docs/benchmarks.md has no section {headline.SECTION!r}"
    assert section.group(1).strip() == headline.text().strip(), \
        "the headline table is not the committed results': run `python -m bench headline`"
    assert len(headline.FIGURES) <= 15
