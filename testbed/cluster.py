"""Several undertow processes on one machine, sharing one PostgreSQL job store, as on
several machines: API-only servers (`testbed.service.LiveServer` with UNDERTOW_WORKERS=0)
and worker nodes (`undertow worker`), each in a process group of its own so that one can
be killed whole, as a lost machine would be."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Self

import psycopg

from app.store import JobStore
from testbed.service import ROOT, LiveServer, wait_for

UNDERTOW = Path(sys.executable).with_name("undertow")
FAKE_SOLVER = "testbed.fake_solvers:fake_plan"


def api_server(folder: Path, db_url: str, instance: str, **extra: str) -> LiveServer:
    """An API-only server (no workers of its own) on the PostgreSQL store at `db_url`; its
    log in `folder`."""
    env = {"UNDERTOW_DB_URL": db_url, "UNDERTOW_INSTANCE": instance, "UNDERTOW_WORKERS": "0",
           **extra}
    return LiveServer(folder / f"{instance}.sqlite3", None, **env)  # the file is never opened


class WorkerNode:
    """`undertow worker --processes N`, in its own process group."""

    def __init__(self, folder: Path, instance: str, processes: int = 1, **settings: str):
        """`settings`: UNDERTOW_* variables, the store's among them. `args`, set before
        `start`, adds options of `undertow worker`; `of_version` sets the code it runs."""
        self.instance, self.processes, self.root = instance, processes, ROOT
        self.args: tuple[str, ...] = ()
        self.env = {**os.environ, "UNDERTOW_INSTANCE": instance, "UNDERTOW_LOG_LEVEL": "WARNING",
                    **settings, "PYTHONPATH": str(ROOT)}  # testbed's fake solver
        self.log = folder / f"{instance}.log"
        self.proc: subprocess.Popen | None = None

    def of_version(self, root: Path) -> Self:
        """Run the code of the checkout at `root` (another version's, for a rolling
        upgrade) from the next `start` on."""
        self.root, self.env["PYTHONPATH"] = root, str(root)
        return self

    def start(self) -> Self:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [str(UNDERTOW), "worker", "--processes", str(self.processes), *self.args],
                cwd=self.root,
                env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        return self

    def check(self) -> None:
        """AssertionError, with the end of its log, when the node has exited."""
        assert self.proc is not None and self.proc.poll() is None, (
            f"worker node {self.instance} exited: {self.log.read_text()[-3000:]}")

    def wait_up(self, db_url: str, timeout: float = 60.0) -> None:
        """Wait until the node's supervisor wrote its first heartbeat in the store at
        `db_url`, read with plain SQL so that no process of this version migrates the
        store first (a node of an earlier version refuses a schema newer than its own)."""
        def heard() -> bool:
            self.check()
            with contextlib.suppress(psycopg.Error), psycopg.connect(db_url) as conn:
                return conn.execute("SELECT 1 FROM workers WHERE name LIKE %s",
                                    (f"{self.instance}:worker:%",)).fetchone() is not None
            return False

        wait_for(heard, timeout, f"worker node {self.instance} up")

    def owns(self, worker: str | None) -> bool:
        """Whether a job's `worker` is one of this node's processes."""
        return worker is not None and worker.startswith(f"{self.instance}:worker:")

    def kill(self) -> None:
        """SIGKILL the node and its solver processes at once: nothing of it runs on."""
        if self.proc is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(30)

    def stop(self, timeout: float = 30.0) -> None:
        """SIGTERM, then SIGKILL what is left after `timeout` seconds."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout)
        self.kill()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def solving_on(store: JobStore, node: WorkerNode) -> str | None:
    """A job the node is solving (past its first iteration), or None."""
    node.check()
    for record in store.list(status="running", limit=100):
        if node.owns(record.worker) and (record.progress or {}).get("phase") == "solving":
            return record.id
    return None
