"""How a server run as `make serve` runs it ends on SIGTERM (docs/deploy.md, "Stop"): it
drains and stops cleanly, then uvicorn raises the signal it caught again, so outside a
container the process ends by SIGTERM (a shell's exit status 143), while as a
container's PID 1, where the kernel ignores a signal that has no handler, it exits 0."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from app.server import PROTOCOL
from testbed.service import ROOT, LiveServer, free_port

CLEAN = "Application shutdown complete."
"""uvicorn's last line of a stop that ran the app's whole shutdown."""


def test_outside_a_container_sigterm_ends_the_server_by_the_signal(tmp_path):
    with LiveServer(tmp_path / "jobs.sqlite3", UNDERTOW_LOG_LEVEL="INFO") as server:
        server.stop(signal.SIGTERM)
    assert server.proc is not None and server.proc.returncode == -signal.SIGTERM  # 143
    assert CLEAN in server.log.read_text()


def _child(pid: int, timeout: float = 10.0) -> int:
    """The first child of process `pid`."""
    path = Path(f"/proc/{pid}/task/{pid}/children")
    deadline = time.monotonic() + timeout
    while not path.read_text().split():
        assert time.monotonic() < deadline, "unshare started no child"
        time.sleep(0.05)
    return int(path.read_text().split()[0])


@pytest.mark.skipif(shutil.which("unshare") is None or os.geteuid() != 0,
                    reason="a PID namespace of its own needs unshare and root")
def test_as_a_containers_pid_1_the_server_exits_0_on_sigterm(tmp_path):
    port = free_port()
    env = {**os.environ, "UNDERTOW_DB_PATH": str(tmp_path / "jobs.sqlite3"),
           "UNDERTOW_INSTANCE": "pid1", "UNDERTOW_LOG_LEVEL": "INFO"}
    proc = subprocess.Popen(
        ["unshare", "--pid", "--fork", "--kill-child", sys.executable, "-m", "uvicorn",
         "app.main:app", "--host", "127.0.0.1", "--port", str(port), "--http", PROTOCOL],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                    break
            time.sleep(0.1)
        os.kill(_child(proc.pid), signal.SIGTERM)  # unshare passes no signal on
        output, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, output.decode()[-2000:]
    assert CLEAN in output.decode()
