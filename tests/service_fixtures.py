"""Helpers for the service tests: an in-process client, uvicorn in a thread, robots (the
service in a process of its own: `testbed.service`)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.main import create_app
from app.server import HeadTimeoutProtocol
from app.settings import Settings
from testbed.service import free_port

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
