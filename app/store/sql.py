"""The statements the SQL job stores share, written once.

They are in SQLite's parameter style (`?`); a store runs them through its `_rows` (reads)
and `_write` (writes) and converts its own JSON columns and rows (`_json`, `_from_json`,
`_record`). What differs between the databases (creating jobs within a limit, leases,
batches, migrations, integrity) stays with each store.
"""

from __future__ import annotations

import builtins
import time
from abc import abstractmethod
from typing import Any

from app.store.base import BUILDING, STATUSES, JobRecord, JobStatus, JobStore

COLUMNS = ("id, status, scene, progress, plan, error, cancel_requested, owner, "
           "created, started, finished, worker")
"""The columns of a job, in the order `_record` reads them."""
NO_WORKER_OR = "(CAST(? AS TEXT) IS NULL OR worker = ?)"
"""A condition that holds for any worker when the parameter is NULL, else for that one."""


class SqlJobStore(JobStore):
    """A job store on an SQL database: the statements its dialects share."""

    claim_lock = ""
    """Appended to the claim's row choice ("FOR UPDATE SKIP LOCKED" where rows lock)."""

    @abstractmethod
    def _rows(self, sql: str, params: tuple | dict = ()) -> builtins.list[tuple]:
        """Every row of one reading statement."""

    @abstractmethod
    def _write(self, sql: str, params: tuple | dict = ()) -> builtins.list[tuple]:
        """The rows of one writing statement (its RETURNING clause)."""

    @abstractmethod
    def _json(self, value: Any) -> Any:
        """A JSON value as this database takes it as a parameter (None stays NULL)."""

    @abstractmethod
    def _from_json(self, value: Any) -> Any:
        """A JSON column's value as read back."""

    @abstractmethod
    def _record(self, row: tuple) -> JobRecord:
        """A row of COLUMNS as a job."""

    def get(self, job_id: str) -> JobRecord | None:
        rows = self._rows(f"SELECT {COLUMNS} FROM jobs WHERE id = ?", (job_id,))
        return self._record(rows[0]) if rows else None

    def list(self, status: JobStatus | None = None, limit: int = 50,
             offset: int = 0) -> builtins.list[JobRecord]:
        where, params = ("WHERE status = ?", (status,)) if status else ("", ())
        rows = self._rows(
            f"SELECT {COLUMNS} FROM jobs {where} ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (*params, limit, offset))
        return [self._record(row) for row in rows]

    def count_by_status(self) -> dict[str, int]:
        counts: dict[str, int] = dict.fromkeys(STATUSES, 0)
        for status, count in self._rows("SELECT status, COUNT(*) FROM jobs GROUP BY status"):
            counts[status] = count
        return counts

    def claim(self, owner: str | None, worker: str, lease_until: float) -> JobRecord | None:
        mine, params = ("AND owner = ?", (owner,)) if owner is not None else ("", ())
        rows = self._write(
            "UPDATE jobs SET status = 'running', started = ?, worker = ?, lease_until = ?, "
            "progress = ?, attempts = attempts + 1 WHERE status = 'queued' AND id = "
            f"(SELECT id FROM jobs WHERE status = 'queued' {mine} ORDER BY created, id "
            f"LIMIT 1 {self.claim_lock}) RETURNING {COLUMNS}",
            (time.time(), worker, lease_until, self._json(BUILDING), *params))
        return self._record(rows[0]) if rows else None

    def release(self, job_id: str, worker: str) -> bool:
        rows = self._write(
            "UPDATE jobs SET status = CASE WHEN cancel_requested THEN 'cancelled' "
            "ELSE 'queued' END, finished = CASE WHEN cancel_requested THEN ? END, "
            "started = NULL, worker = NULL, lease_until = NULL, progress = NULL, "
            "attempts = attempts - 1 "
            "WHERE id = ? AND worker = ? AND status = 'running' RETURNING id",
            (time.time(), job_id, worker))
        return bool(rows)

    def report_progress(self, job_id: str, progress: dict[str, Any],
                        worker: str | None = None) -> bool:
        rows = self._write(
            "UPDATE jobs SET progress = ? WHERE id = ? AND status = 'running' "
            f"AND {NO_WORKER_OR} RETURNING cancel_requested",
            (self._json(progress), job_id, worker, worker))
        return bool(rows) and not rows[0][0]

    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None, solution: dict[str, Any] | None = None,
               worker: str | None = None) -> bool:
        rows = self._write(
            "UPDATE jobs SET status = ?, plan = ?, error = ?, finished = ?, solution = ? "
            f"WHERE id = ? AND status = 'running' AND {NO_WORKER_OR} RETURNING id",
            (status, self._json(plan), error, time.time(), self._json(solution), job_id,
             worker, worker))
        return bool(rows)

    def solution(self, job_id: str) -> dict[str, Any] | None:
        rows = self._rows("SELECT solution FROM jobs WHERE id = ?", (job_id,))
        return self._from_json(rows[0][0]) if rows else None

    def fail(self, job_id: str, error: str) -> bool:
        rows = self._write(
            "UPDATE jobs SET status = 'failed', error = ?, finished = ? "
            "WHERE id = ? AND status IN ('queued', 'running') RETURNING id",
            (error, time.time(), job_id))
        return bool(rows)

    def _fail_running(self, condition: str, params: tuple, error: str) -> builtins.list[str]:
        """Mark the running jobs that meet `condition` failed with `error`; their ids."""
        rows = self._write(
            "UPDATE jobs SET status = 'failed', error = ?, finished = ? "
            f"WHERE status = 'running' AND {condition} RETURNING id",
            (error, time.time(), *params))
        return [row[0] for row in rows]

    def fail_claimed(self, worker: str, error: str) -> builtins.list[str]:
        return self._fail_running("worker = ?", (worker,), error)
