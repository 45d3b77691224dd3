"""Helpers for the service tests: an in-process client, a live uvicorn server, robots."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Self

import httpx
import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.main import create_app
from app.server import PROTOCOL, HeadTimeoutProtocol
from app.settings import Settings

ROOT = Path(__file__).resolve().parents[1]

TWO_LINK = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
                      {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
                       "wave": {"amplitude": 0.05, "frequency": 3.0, "phase": 0.3}}],
            "gravity": 9.81, "rotational_inertia": "cumulative"}


def two_link_scene(iterations: int = 3, tol: float = 1e-8, duration: float = 1.0,
                   wall_time: float | None = None) -> dict:
    """A two-link scene (the fake solver runs `iterations` x 20 ms; `tol` picks its outcome;
    `wall_time` sets solver.max_wall_time)."""
    solver = {"max_iter": iterations, "tol": tol}
    if wall_time is not None:
        solver["max_wall_time"] = wall_time
    return {"robot": TWO_LINK, "solver": solver,
            "task": {"duration": duration, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                     "final": {"q": [1.0, None], "dq": [0.0, 0.0]}},
            "transcription": {"intervals": 10}}


@contextlib.contextmanager
def client(tmp_path: Path, solve=None, **settings) -> Iterator[TestClient]:
    """A TestClient of a fresh app with a temporary store (lifespan run)."""
    config = Settings(**{"db_path": str(tmp_path / "jobs.sqlite3"), "workers": 1,
                         "instance": "test", **settings})
    with TestClient(create_app(config, solve=solve)) as c:
        yield c


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serving(app: FastAPI) -> Iterator[int]:
    """uvicorn serving `app` on 127.0.0.1 in a thread of this process, with the service's
    protocol (`app.server`); yields the port."""
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_config=None,
                            http=HeadTimeoutProtocol)
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "server did not start"
        time.sleep(0.05)
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(30)


class LiveServer:
    """uvicorn serving app.main:app on 127.0.0.1 in a subprocess, with its own store."""

    def __init__(self, db_path: Path, port: int | None = None, **env: str):
        self.db_path, self.port = db_path, port or free_port()
        self.env = {**os.environ, "UNDERTOW_DB_PATH": str(db_path),
                    "UNDERTOW_INSTANCE": "e2e", "UNDERTOW_LOG_LEVEL": "WARNING", **env}
        self.proc: subprocess.Popen | None = None
        self.log = db_path.with_suffix(".log")

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 60.0) -> Self:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "uvicorn", "app.main:app", "--host", "127.0.0.1",
                 "--port", str(self.port), "--no-access-log", "--http", PROTOCOL],
                cwd=ROOT, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, f"server exited: {self.log.read_text()[-3000:]}"
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return self
            time.sleep(0.1)
        raise AssertionError(f"server did not come up: {self.log.read_text()[-3000:]}")

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


def wait_final(http: httpx.Client, job_id: str, timeout: float = 120.0) -> dict:
    """Poll GET /v1/plans/{id} until the job ends."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/plans/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not end in {timeout} s")
