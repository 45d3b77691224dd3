"""The statements the SQL job stores share, written once.

They name their parameters (`:name`, SQLite's style; the PostgreSQL store rewrites them as
psycopg's `%(name)s`); a store runs them through its `_rows` (reads) and `_write` (writes)
and converts its own JSON columns and rows (`_json`, `_from_json`, `_record`), and appends
to a job's history with its own JSON functions (`_push`). What differs between the
databases (creating jobs within a limit, batches, integrity, and the queue: claims,
renewals and expiry are SQLite's own statements and procrastinate's on PostgreSQL, where
the database derives a job's status from the queue's, so that the statements' writes of
it, `_status`, are SQLite's alone: `QUEUE_COLUMNS`) stays with each store; the
migrations of both are one list (`app.store.migrations`).
"""

from __future__ import annotations

import builtins
import math
import time
from abc import abstractmethod
from typing import Any

from app.store import json_text
from app.store.base import (
    BUILDING,
    CANCELLED_ON_REQUEST,
    DEAD_LETTER,
    SILENCE,
    STATUSES,
    JobRecord,
    JobStatus,
    JobStore,
    WorkerRecord,
)

COLUMNS = ("id, status, scene, progress, plan, error, cancel_requested, owner, "
           "created, started, finished, worker, attempts, infra_failures, dead_letter, "
           "history, admission")
"""The columns of a job, in the order `_record` reads them."""
SUMMARY_COLUMNS = COLUMNS.replace("scene,", "NULL,").replace("plan,", "NULL,") \
    .replace("history,", "NULL,").replace("admission", "NULL")
"""The same without scene, plan, history and admission (read as an empty scene and None):
what a listing shows."""
NO_WORKER_OR = "(CAST(:worker AS TEXT) IS NULL OR worker = :worker)"
"""A condition that holds for any worker when the parameter is NULL, else for that one."""
_NOW = "CAST(:now AS DOUBLE PRECISION)"
LEASE_RAN_OUT = "its lease ran out: its worker or node was lost"
"""The reason of an infrastructure failure found by `JobStore.expire`."""
_REQUEUE = "(NOT cancel_requested AND infra_failures < :max)"
"""A running job that fails for an infrastructure reason goes back to the queue."""
_RUNNING, _QUEUED, _FAILED = "'running'", "'queued'", "'failed'"
"""Statuses as SQL literals, for `SqlJobStore._status`."""
_RELEASED = "CASE WHEN cancel_requested THEN 'cancelled' ELSE 'queued' END"
"""The status a released job takes: queued again, or cancelled when that was asked."""
_REQUEUED = "CASE WHEN cancel_requested THEN 'cancelled' WHEN dead_letter THEN 'failed' " \
    "ELSE 'queued' END"
"""The status a job takes by an infrastructure failure, read from the row as the failure
left it (its `dead_letter` written): queued again, a dead letter, or cancelled."""


def event(kind: str, worker: str = "worker", reason: str | None = None) -> str:
    """The key-value list of a history entry (`worker`, `reason`: SQL expressions)."""
    pairs = f"'at', {_NOW}, 'event', '{kind}', 'worker', {worker}"
    return pairs + (f", 'reason', {reason}" if reason else "")


class SqlJobStore(JobStore):
    """A job store on an SQL database: the statements its dialects share."""

    QUEUE_COLUMNS = True
    """Whether the jobs rows are the queue too: a job's status, a claim's end
    (`lease_until`, renewed) and a requeued job's retry time (`not_before`) are kept in
    them (SQLite); False where a queue engine keeps all three (PostgreSQL's procrastinate):
    the status is then derived from the engine's by the database, and the columns stay
    NULL."""
    SMALLER = "MIN"
    """The dialect's SQL function of the smaller of two values (PostgreSQL's LEAST)."""

    def _status(self, value: str) -> str:
        """The SET item that writes a job's new status, the SQL expression `value`, and its
        separator; nothing where a queue engine keeps the status (`QUEUE_COLUMNS`)."""
        return f"status = {value}, " if self.QUEUE_COLUMNS else ""

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
    def _packed(self, value: Any) -> Any:
        """A plan or an NLP solution, the bulk of a job, as this database stores it (None
        stays NULL); read back by `_from_json`."""

    @abstractmethod
    def _record(self, row: tuple) -> JobRecord:
        """A row of COLUMNS as a job."""

    @abstractmethod
    def _push(self, pairs: str) -> str:
        """The SQL of the job's history with one entry appended, an object of the
        key-value list `pairs` (SQL expressions)."""

    def get(self, job_id: str) -> JobRecord | None:
        rows = self._rows(f"SELECT {COLUMNS} FROM jobs WHERE id = ?", (job_id,))
        return self._record(rows[0]) if rows else None

    def status(self, job_id: str) -> JobStatus | None:
        rows = self._rows("SELECT status FROM jobs WHERE id = ?", (job_id,))
        return rows[0][0] if rows else None

    def list(self, status: JobStatus | None = None, limit: int = 50,
             offset: int = 0, dead_letter: bool | None = None,
             summaries: bool = False) -> builtins.list[JobRecord]:
        conditions, params = [], []
        if status:
            conditions.append("status = ?")
            params.append(status)
        if dead_letter is not None:
            conditions.append("dead_letter" if dead_letter else "NOT dead_letter")
        where = f"WHERE {' AND '.join(conditions)}" if conditions else ""
        columns = SUMMARY_COLUMNS if summaries else COLUMNS
        rows = self._rows(
            f"SELECT {columns} FROM jobs {where} ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (*params, limit, offset))
        return [self._record(row) for row in rows]

    def count_by_status(self) -> dict[str, int]:
        counts: dict[str, int] = dict.fromkeys(STATUSES, 0)
        for status, count in self._rows("SELECT status, COUNT(*) FROM jobs GROUP BY status"):
            counts[status] = count
        return counts

    @abstractmethod
    def _stored_bytes(self) -> str:
        """The SQL of the bytes a job's row holds of its scene, progress, plan and NLP
        solution, as this database stores them (not its history, a few hundred bytes
        that SQLite keeps after the plan, so that reading it reads the plan too)."""

    def purge(self, before: float, keep: int, size: int | None = None) -> int:
        final = "status IN ('succeeded', 'failed', 'cancelled')"
        rows = self._write(
            f"DELETE FROM jobs WHERE {final} AND (finished < :before OR id IN (SELECT id "
            f"FROM jobs WHERE {final} ORDER BY finished DESC, id LIMIT :all OFFSET :keep) "
            f"OR id IN (SELECT id FROM (SELECT id, SUM({self._stored_bytes()}) OVER (ORDER BY "
            f"finished DESC, id ROWS UNBOUNDED PRECEDING) AS held FROM jobs WHERE {final}) "
            "AS newest WHERE held > :size)) RETURNING id",
            {"before": before, "keep": keep, "all": 2**62,
             "size": 2**62 if size is None else size})
        if rows:
            self._write("DELETE FROM batches WHERE NOT EXISTS (SELECT 1 FROM jobs "
                        "WHERE jobs.batch = batches.id) RETURNING id")
        return len(rows)

    def heartbeat(self, name: str, processes: int, busy: int, started: float) -> None:
        now = time.time()
        self._write("INSERT INTO workers (name, processes, busy, started, seen) VALUES "
                    "(:name, :processes, :busy, :started, :now) ON CONFLICT (name) DO UPDATE "
                    "SET processes = :processes, busy = :busy, seen = :now RETURNING name",
                    {"name": name, "processes": processes, "busy": busy, "started": started,
                     "now": now})
        self._write("DELETE FROM workers WHERE seen < :old RETURNING name", {"old": now - 3600})

    def forget_worker(self, name: str) -> None:
        self._write("DELETE FROM workers WHERE name = ? RETURNING name", (name,))

    def workers(self, since: float) -> builtins.list[WorkerRecord]:
        rows = self._rows("SELECT name, processes, busy, started, seen FROM workers "
                          "WHERE seen >= ? ORDER BY name", (since,))
        return [WorkerRecord(*row) for row in rows]

    def find_key(self, key: str) -> str | None:
        rows = self._rows("SELECT id FROM jobs WHERE idem_key = ?", (key,))
        return rows[0][0] if rows else None

    def succeeded_scenes(self, limit: int) -> builtins.list[tuple[str, dict[str, Any]]]:
        rows = self._rows("SELECT id, scene FROM jobs WHERE status = 'succeeded' "
                          "ORDER BY finished DESC, id LIMIT ?", (limit,))
        return [(job_id, self._from_json(scene)) for job_id, scene in rows]

    def _claiming(self) -> str:
        """The SET list that turns a queued job into a claimed one (parameters :now,
        :worker, :until, :lease, :progress: `_claim_params`)."""
        until = ":until" if self.QUEUE_COLUMNS else "NULL"
        return (f"{self._status(_RUNNING)}started = :now, worker = :worker, "
                f"lease_until = {until}, lease = :lease, not_before = NULL, "
                "progress = :progress, "
                "attempts = attempts + 1, "
                f"history = {self._push(event('claimed', 'CAST(:worker AS TEXT)'))}")

    def _claim_params(self, worker: str, lease_until: float) -> dict[str, Any]:
        """The parameters of `_claiming` for a claim by `worker` until `lease_until` [s]."""
        now = time.time()
        return {"now": now, "worker": worker, "until": lease_until, "lease": lease_until - now,
                "progress": self._json(BUILDING)}

    def _release(self, condition: str, params: dict[str, Any]) -> dict[str, JobStatus]:
        """Release the running jobs that meet `condition`: {job id: its new status}."""
        rows = self._write(
            f"UPDATE jobs SET {self._status(_RELEASED)}"
            "error = CASE WHEN cancel_requested THEN :cancelled END, "
            "finished = CASE WHEN cancel_requested THEN :now END, "
            "started = NULL, worker = NULL, lease_until = NULL, progress = NULL, "
            "attempts = attempts - 1, "
            f"history = {self._push(event('released', reason='CAST(:reason AS TEXT)'))} "
            f"WHERE status = 'running' AND {condition} RETURNING id, {_RELEASED}",
            {"now": time.time(), "cancelled": CANCELLED_ON_REQUEST, **params})
        return dict(rows)

    def release(self, job_id: str, worker: str, reason: str = "released") -> bool:
        return bool(self._release("id = :id AND worker = :worker",
                                  {"id": job_id, "worker": worker, "reason": reason}))

    def release_claimed(self, worker: str, reason: str) -> builtins.list[str]:
        return builtins.list(self._release("worker = :worker",
                                           {"worker": worker, "reason": reason}))

    def _requeue(self, condition: str, params: dict[str, Any],
                 reason: str) -> dict[str, JobStatus]:
        """An infrastructure failure of the running jobs that meet `condition`."""
        policy = self.policy
        retry_at = self._retry_at() if self.QUEUE_COLUMNS else "NULL"
        dead = (f"{DEAD_LETTER}: {reason}; it failed for infrastructure reasons "
                f"{policy.max_retries + 1} times (UNDERTOW_MAX_RETRIES={policy.max_retries})")
        rows = self._write(
            "UPDATE jobs SET " + self._status(
                "CASE WHEN cancel_requested THEN 'cancelled' "
                "WHEN infra_failures < :max THEN 'queued' ELSE 'failed' END") +
            "error = CASE WHEN cancel_requested THEN :cancelled "
            "WHEN infra_failures < :max THEN NULL ELSE :dead END, "
            "dead_letter = (NOT cancel_requested AND infra_failures >= :max), "
            f"finished = CASE WHEN {_REQUEUE} THEN NULL ELSE :now END, "
            f"started = CASE WHEN {_REQUEUE} THEN NULL ELSE started END, "
            f"progress = CASE WHEN {_REQUEUE} THEN NULL ELSE progress END, "
            f"worker = CASE WHEN {_REQUEUE} THEN NULL ELSE worker END, "
            f"not_before = {retry_at}, "
            "lease_until = NULL, infra_failures = infra_failures + 1, "
            "history = "
            f"{self._push(event('infrastructure-failure', reason='CAST(:reason AS TEXT)'))} "
            f"WHERE status = 'running' AND {condition} RETURNING id, {_REQUEUED}",
            {"now": time.time(), "max": policy.max_retries, "cancelled": CANCELLED_ON_REQUEST,
             "dead": dead, "reason": reason, **params})
        return dict(rows)

    def _lease_ended(self, now: float) -> tuple[str, dict[str, Any]]:
        """The condition (and its parameters) of a claim whose lease end, as the claim wrote
        and renewed it (`lease_until`), comes before `now`, and that has been silent since
        its last renewal (`lease_until - lease`) for `SILENCE` at least (its whole lease if
        shorter)."""
        return (f"lease_until < :expired AND lease_until - COALESCE(lease, 0) < :now - "
                f"{self.SMALLER}(COALESCE(lease, :silence), :silence)",
                {"expired": now, "now": time.time(), "silence": SILENCE})

    def _retry_at(self) -> str:
        """The SQL of a requeued job's retry time: now plus the policy's pause for its
        infrastructure failures so far (NULL for a job that is not requeued)."""
        policy = self.policy
        delays = " ".join(f"WHEN {n} THEN {policy.delay(n + 1)!r}"
                          for n in range(policy.max_retries))
        delay = f"CASE infra_failures {delays} ELSE 0.0 END" if delays else "0.0"
        return f"CASE WHEN {_REQUEUE} THEN {_NOW} + {delay} END"

    def requeue(self, job_id: str, worker: str | None, reason: str) -> JobStatus | None:
        done = self._requeue(f"id = :id AND {NO_WORKER_OR}",
                             {"id": job_id, "worker": worker}, reason)
        return done.get(job_id)

    def requeue_claimed(self, worker: str, reason: str) -> dict[str, JobStatus]:
        return self._requeue("worker = :worker", {"worker": worker}, reason)

    def recover(self, owner: str) -> dict[str, JobStatus]:
        return self._requeue(
            "owner = :owner AND substr(worker, 1, length(CAST(:prefix AS TEXT))) = :prefix",
            {"owner": owner, "prefix": owner + "/"},
            "the server stopped while it ran")

    def _retry_statement(self, limited: bool) -> str:
        held = ("AND (SELECT COUNT(*) FROM jobs WHERE owner = :owner AND status IN "
                "('queued', 'running')) < :limit" if limited else "")
        return (
            f"UPDATE jobs SET {self._status(_QUEUED)}owner = :owner, error = NULL, "
            "plan = NULL, "
            "solution = NULL, verified = NULL, objective = NULL, progress = NULL, "
            "started = NULL, finished = NULL, "
            "worker = NULL, lease_until = NULL, not_before = NULL, "
            "cancel_requested = (1 = 0), dead_letter = (1 = 0), infra_failures = 0, "
            f"history = {self._push(event('retried', 'CAST(NULL AS TEXT)'))} "
            f"WHERE id = :id AND status IN ('failed', 'cancelled') {held} RETURNING id")

    def retry(self, job_id: str, owner: str, limit: int | None = None) -> bool:
        params = {"id": job_id, "owner": owner, "limit": limit, "now": time.time()}
        return bool(self._write(self._retry_statement(limit is not None), params))

    def report_progress(self, job_id: str, progress: dict[str, Any],
                        worker: str | None = None) -> bool:
        rows = self._write(
            "UPDATE jobs SET progress = :progress WHERE id = :id AND status = 'running' "
            f"AND {NO_WORKER_OR} RETURNING cancel_requested",
            {"progress": self._json(progress), "id": job_id, "worker": worker})
        return bool(rows) and not rows[0][0]

    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None, solution: dict[str, Any] | None = None,
               worker: str | None = None) -> bool:
        rows = self._write(
            f"UPDATE jobs SET {self._status(':status')}plan = :plan, error = :error, "
            "finished = :now, "
            "solution = :solution, lease_until = NULL, verified = :verified, "
            "objective = :objective, "
            f"history = {self._push(event('finished', reason='CAST(:status AS TEXT)'))} "
            f"WHERE id = :id AND status = 'running' AND {NO_WORKER_OR} RETURNING id",
            {"status": status, "plan": self._packed(plan), "error": error, "now": time.time(),
             "solution": self._packed(solution), "id": job_id, "worker": worker,
             **figures(plan)})
        return bool(rows)

    def solution(self, job_id: str) -> dict[str, Any] | None:
        rows = self._rows("SELECT solution FROM jobs WHERE id = ?", (job_id,))
        return self._from_json(rows[0][0]) if rows else None

    def fail(self, job_id: str, error: str) -> bool:
        rows = self._write(
            f"UPDATE jobs SET {self._status(_FAILED)}error = ?, finished = ? "
            "WHERE id = ? AND status IN ('queued', 'running') RETURNING id",
            (error, time.time(), job_id))
        return bool(rows)


def figures(plan: dict[str, Any] | None) -> dict[str, Any]:
    """The plan's verdict and objective, as the columns `verified` and `objective` keep
    them (None without a plan, or where the plan has no finite one)."""
    verification = (plan or {}).get("verification") or {}
    verified, objective = verification.get("verified"), (plan or {}).get("objective")
    return {"verified": verified if isinstance(verified, bool) else None,
            "objective": objective if isinstance(objective, (int, float))
            and math.isfinite(objective) else None}


def history(value: Any) -> builtins.list[dict[str, Any]] | None:
    """A history column's value (JSON text or already decoded) as a list."""
    if value is None:
        return None
    return json_text.loads(value) if isinstance(value, str) else value
