"""The service in a process of its own: uvicorn serving app.main:app on a free loopback
port with its own store, as `make serve` runs it; and waiting for a plan job to end."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Self, TypeVar

import httpx

from app.server import PROTOCOL

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]



class LiveServer:
    """uvicorn serving app.main:app on 127.0.0.1 in a subprocess, with its own store; the
    app of the checkout at `root` (this one by default)."""

    def __init__(self, db_path: Path, port: int | None = None, *, root: Path | str = ROOT,
                 **env: str):
        self.db_path, self.port, self.root = db_path, port or free_port(), Path(root)
        self.env = {**os.environ, "UNDERTOW_DB_PATH": str(db_path),
                    "UNDERTOW_INSTANCE": "e2e", "UNDERTOW_LOG_LEVEL": "WARNING", **env}
        self.proc: subprocess.Popen | None = None
        self.log = db_path.with_suffix(".log")

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _spawn(self) -> subprocess.Popen:
        """The server's process, started (its output appended to `log`)."""
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "uvicorn", "app.main:app", "--host", "127.0.0.1",
                 "--port", str(self.port), "--no-access-log", "--http", PROTOCOL],
                cwd=self.root, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)
        return self.proc

    def start(self, timeout: float = 60.0) -> Self:
        proc = self._spawn()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert proc.poll() is None, f"server exited: {self.log.read_text()[-3000:]}"
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return self
            time.sleep(0.1)
        raise AssertionError(f"server did not come up: {self.log.read_text()[-3000:]}")

    def refused(self, timeout: float = 60.0) -> int:
        """Start the server and wait for it to exit on its own (a start that is refused);
        its exit status (AssertionError if it is still running after `timeout` s)."""
        proc = self._spawn()
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise AssertionError(
                f"the server kept running: {self.log.read_text()[-3000:]}") from None

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> None:
        """Send `sig` to the server process only (its workers are left to notice)."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
        if self.proc is not None:  # leave no worker behind
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)


T = TypeVar("T")


def wait_for(predicate: Callable[[], T], timeout: float, what: str) -> T:
    """The first true value of `predicate()` within `timeout` seconds (AssertionError
    saying `what` did not happen otherwise)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what} did not happen within {timeout} s")


def wait_final(http: httpx.Client, job_id: str, timeout: float = 120.0) -> dict:
    """Poll GET /v1/plans/{id} until the job ends."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/plans/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not end in {timeout} s")
