"""SQLite job store (stdlib sqlite3, WAL mode): one file shared by threads and processes.

Each thread of each process opens its own connection on first use. Writes are single
conditional UPDATE statements, so they are atomic without explicit transactions; the
busy timeout makes concurrent writers queue instead of failing.
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

from app.store.base import INTERRUPTED, STATUSES, JobRecord, JobStatus, JobStore

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id               TEXT PRIMARY KEY,
    status           TEXT NOT NULL,
    scene            TEXT NOT NULL,
    progress         TEXT,
    plan             TEXT,
    error            TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    owner            TEXT NOT NULL,
    created          REAL NOT NULL,
    started          REAL,
    finished         REAL
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status);
CREATE INDEX IF NOT EXISTS jobs_created ON jobs (created);
"""

_COLUMNS = ("id, status, scene, progress, plan, error, cancel_requested, owner, "
            "created, started, finished")


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _record(row: tuple) -> JobRecord:
    (id_, status, scene, progress, plan, error, cancel, owner, created, started,
     finished) = row
    return JobRecord(id=id_, status=status, scene=_loads(scene), progress=_loads(progress),
                     plan=_loads(plan), error=error, cancel_requested=bool(cancel),
                     owner=owner, created=created, started=started, finished=finished)


def _dumps(value: Any) -> str | None:
    return None if value is None else json.dumps(value, allow_nan=False, separators=(",", ":"))


class SqliteJobStore(JobStore):
    """Jobs in one SQLite file (created with its directory if missing)."""

    def __init__(self, path: str | os.PathLike, busy_timeout: float = 30.0):
        self.path = str(path)
        self.busy_timeout = busy_timeout
        self._local = threading.local()
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        self._connection().executescript(_SCHEMA)

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "busy_timeout": self.busy_timeout}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path, self.busy_timeout = state["path"], state["busy_timeout"]
        self._local = threading.local()

    def _connection(self) -> sqlite3.Connection:
        """This thread's connection (a new one after a fork)."""
        local = self._local
        if getattr(local, "pid", None) != os.getpid():
            conn = sqlite3.connect(self.path, timeout=self.busy_timeout,
                                   isolation_level=None, check_same_thread=False)
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=NORMAL")
            local.conn, local.pid = conn, os.getpid()
        return local.conn

    def _execute(self, sql: str, params: tuple = ()) -> sqlite3.Cursor:
        return self._connection().execute(sql, params)

    @property
    def journal_mode(self) -> str:
        """The journal mode in force ("wal")."""
        return self._execute("PRAGMA journal_mode").fetchone()[0]

    def create(self, job_id: str, scene: dict[str, Any], owner: str) -> JobRecord:
        self._execute(
            "INSERT INTO jobs (id, status, scene, owner, created) VALUES (?, 'queued', ?, ?, ?)",
            (job_id, _dumps(scene), owner, time.time()))
        record = self.get(job_id)
        assert record is not None
        return record

    def get(self, job_id: str) -> JobRecord | None:
        row = self._execute(f"SELECT {_COLUMNS} FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return None if row is None else _record(row)

    def list(self, status: JobStatus | None = None, limit: int = 50,
             offset: int = 0) -> list[JobRecord]:
        where, params = ("WHERE status = ?", (status,)) if status else ("", ())
        rows = self._execute(
            f"SELECT {_COLUMNS} FROM jobs {where} ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (*params, limit, offset)).fetchall()
        return [_record(row) for row in rows]

    def count_by_status(self) -> dict[str, int]:
        counts = dict.fromkeys(STATUSES, 0)
        for status, count in self._execute("SELECT status, COUNT(*) FROM jobs GROUP BY status"):
            counts[status] = count
        return counts

    def claim(self, job_id: str) -> JobRecord | None:
        cursor = self._execute(
            "UPDATE jobs SET status = 'running', started = ? WHERE id = ? AND status = 'queued'",
            (time.time(), job_id))
        return self.get(job_id) if cursor.rowcount == 1 else None

    def report_progress(self, job_id: str, progress: dict[str, Any]) -> bool:
        row = self._execute(
            "UPDATE jobs SET progress = ? WHERE id = ? AND status = 'running' "
            "RETURNING cancel_requested", (_dumps(progress), job_id)).fetchone()
        return row is not None and not row[0]

    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None) -> bool:
        cursor = self._execute(
            "UPDATE jobs SET status = ?, plan = ?, error = ?, finished = ? "
            "WHERE id = ? AND status = 'running'",
            (status, _dumps(plan), error, time.time(), job_id))
        return cursor.rowcount == 1

    def fail(self, job_id: str, error: str) -> bool:
        cursor = self._execute(
            "UPDATE jobs SET status = 'failed', error = ?, finished = ? "
            "WHERE id = ? AND status IN ('queued', 'running')", (error, time.time(), job_id))
        return cursor.rowcount == 1

    def request_cancel(self, job_id: str) -> JobRecord | None:
        self._execute(
            "UPDATE jobs SET status = 'cancelled', cancel_requested = 1, finished = ? "
            "WHERE id = ? AND status = 'queued'", (time.time(), job_id))
        self._execute("UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND status = 'running'",
                      (job_id,))
        return self.get(job_id)

    def interrupt(self, owner: str) -> list[str]:
        rows = self._execute(
            "UPDATE jobs SET status = 'failed', error = ?, finished = ? "
            "WHERE owner = ? AND status = 'running' RETURNING id",
            (INTERRUPTED, time.time(), owner)).fetchall()
        return [row[0] for row in rows]

    def queued(self, owner: str) -> list[str]:
        rows = self._execute("SELECT id FROM jobs WHERE owner = ? AND status = 'queued' "
                             "ORDER BY created, id", (owner,)).fetchall()
        return [row[0] for row in rows]

    def close(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None and self._local.pid == os.getpid():
            conn.close()
        self._local = threading.local()
