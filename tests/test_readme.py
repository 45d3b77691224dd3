"""The README's examples run as written: its Python block, and its request within the
server's limits."""

from __future__ import annotations

import json
import re
import subprocess

from service_fixtures import ROOT

from app.settings import Settings
from testbed.service import LiveServer

README = (ROOT / "README.md").read_text()


def test_the_python_example_runs():
    (block,) = re.findall(r"```python\n(.*?)```", README, re.DOTALL)
    exec(compile(block, "README.md", "exec"), {})


def test_the_plan_request_waits_no_longer_than_the_server_allows():
    waits = [float(w) for w in re.findall(r"[?&]wait=([\d.]+)", README)]
    assert waits and max(waits) <= Settings().max_wait


def test_the_plan_request_prints_a_short_summary(tmp_path):
    """The README's HTTP session, run as written against a live server: the plan lands in
    job.json and the terminal shows a few lines, not the plan's numbers."""
    (block,) = [b for b in re.findall(r"```sh\n(.*?)```", README, re.DOTALL)
                if "/v1/plans" in b and "make serve &" in b]
    script = block.replace("make serve &\n", "")
    with LiveServer(tmp_path / "jobs.sqlite3") as live:
        script = script.replace("localhost:8000", f"127.0.0.1:{live.port}")
        done = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True,
                              text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    assert len(done.stdout) < 2000, done.stdout
    job = json.loads((tmp_path / "job.json").read_text())
    summary = done.stdout.splitlines()[-1].split()
    assert summary[:4] == [job["id"], "succeeded", "iterations",
                           str(job["plan"]["solver"]["iterations"])]
    assert summary[4:] == ["verified", "True", "objective", repr(job["plan"]["objective"])]
