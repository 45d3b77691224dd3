"""SQLite job store: one file shared by threads and processes, through the connections of
`app.store.sqlite_file` (WAL mode; a file deleted, replaced or overwritten under the
service is reported, never recreated). Writes are single conditional statements, so they
are atomic without explicit transactions; the busy timeout makes concurrent writers queue
instead of failing.

A plan and its NLP solution, the bulk of a job (about 0.55 MB of JSON for a plan of the
seed's 4-link arm), are stored as their JSON compressed by zlib (`PACK_LEVEL`); the
plans of earlier versions, stored as JSON text, are read as they are. A plan's verdict
and objective, which a batch's summary reads, have columns of their own.

Its queue is its own: a claim is one conditional UPDATE of the oldest queued job, holding a
lease until the time it writes, which the supervisor renews; `expire` requeues the claims
whose lease ended. Nothing announces a queued job to another process (`listen`).

Opening the store checks its integrity (`app.store.sqlite_integrity`: `PRAGMA
integrity_check`) and brings its schema up to date (`app.store.migrations`; `PRAGMA
user_version` counts the migrations applied; a newer schema than the code knows is
refused, `NewerSchema`); a job is accepted (`create`, `create_batch`,
`retry`) and the store's health checked (`check`) only after `verify`, the same module's
check of the file as it is now. The
write-ahead log is moved into the database file at least every `checkpoint_interval`
seconds of writes and entirely on shutdown, so the `-wal` file never holds more than that
interval's jobs.
"""

from __future__ import annotations

import builtins
import contextlib
import logging
import os
import sqlite3
import time
import zlib
from collections.abc import Sequence
from typing import Any

from app.store import json_text
from app.store.base import (
    CANCELLED_ON_REQUEST,
    BatchRecord,
    DuplicateKey,
    JobRecord,
    JobStatus,
    MemberRecord,
    RetryPolicy,
    StoreUnavailable,
)
from app.store.migrations import migrate, version
from app.store.sql import COLUMNS, LEASE_RAN_OUT, SqlJobStore, history
from app.store.sqlite_file import SqliteFile
from app.store.sqlite_integrity import Integrity
from app.store.sqlite_locks import NameLock

log = logging.getLogger("undertow.store")

_MEMBER_COLUMNS = "id, member, status, error, verified, objective, started, finished"
PACK_LEVEL = 1
"""zlib's level for plans and NLP solutions: its fastest, since every job's verdict waits
for it; zlib's default, 6, keeps a plan a few per cent smaller (docs/bench-service.md,
"Plan jobs through the service: submit to answer")."""


def _loads(value: str | bytes | None) -> Any:
    """A JSON column's value: JSON text, or JSON compressed by zlib (`_pack`: plans and
    NLP solutions since schema version 9; those of earlier versions are text)."""
    if value is None:
        return None
    return json_text.loads(zlib.decompress(value) if isinstance(value, bytes) else value)


def _pack(value: Any) -> bytes | None:
    """A plan or NLP solution as the store keeps it: its JSON compressed by zlib."""
    return None if value is None else zlib.compress(json_text.dumps(value), PACK_LEVEL)


def _job(row: tuple) -> JobRecord:
    (id_, status, scene, progress, plan, error, cancel, owner, created, started,
     finished, worker, attempts, infra, dead, events, admission) = row
    return JobRecord(id=id_, status=status, scene=_loads(scene) or {}, progress=_loads(progress),
                     plan=_loads(plan), error=error, cancel_requested=bool(cancel),
                     owner=owner, created=created, started=started, finished=finished,
                     worker=worker, attempts=attempts, infra_failures=infra,
                     dead_letter=bool(dead), history=history(events),
                     admission=_loads(admission))


def _member(row: tuple) -> MemberRecord:
    id_, index, status, error, verified, objective, started, finished = row
    return MemberRecord(job_id=id_, index=index, status=status, error=error,
                        verified=None if verified is None else bool(verified),
                        objective=objective, started=started, finished=finished)


def _dumps(value: Any) -> str | None:
    return None if value is None else json_text.dumps(value).decode()


class SqliteJobStore(SqlJobStore):
    """Jobs in one SQLite file (created with its directory if missing); `busy_timeout`
    [s]: how long a writer waits for another.

    Raises StoreDamaged when the file fails its integrity check."""

    def __init__(self, path: str | os.PathLike, busy_timeout: float = 30.0,
                 checkpoint_interval: float = 60.0, policy: RetryPolicy | None = None,
                 integrity_interval: float = 300.0):
        self.file = SqliteFile(path, busy_timeout)
        self.path = self.file.path
        self.policy = policy or RetryPolicy()
        self.checkpoint_interval = checkpoint_interval
        self._checkpointed = time.monotonic()
        self.integrity = Integrity(self.file, integrity_interval)
        self.integrity.at_start()
        self._migrate()
        self.file.check_header = True

    def __getstate__(self) -> dict[str, Any]:
        return {"file": self.file, "checkpoint_interval": self.checkpoint_interval,
                "policy": self.policy, "integrity_interval": self.integrity.interval}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.file, self.path = state["file"], state["file"].path
        self.checkpoint_interval, self.policy = state["checkpoint_interval"], state["policy"]
        self._checkpointed = time.monotonic()
        self.integrity = Integrity(self.file, state["integrity_interval"])

    def verify(self) -> None:
        self.integrity.verify()

    def _migrate(self) -> None:
        """Apply the migrations (`app.store.migrations`) this file has not had yet, in one
        transaction; NewerSchema, changing nothing, when a newer version migrated it."""
        conn = self.file.connection()
        try:
            conn.execute("BEGIN IMMEDIATE")
            migrate(lambda sql: conn.execute(sql).fetchall(), "sqlite",
                    where=f"the job store {self.path}")
            conn.execute("COMMIT")
        except sqlite3.Error as exc:
            raise StoreUnavailable(f"the job store {self.path} could not be migrated: "
                                   f"{exc}") from exc
        finally:  # a refusal (NewerSchema) or a failure leaves the file as it was
            if conn.in_transaction:
                conn.execute("ROLLBACK")

    @property
    def schema_version(self) -> int:
        """The version of the schema the file has (`app.store.migrations`)."""
        return version(self._rows, "sqlite")

    def _rows(self, sql: str, params: tuple | dict = (), fresh: bool = False) -> list[tuple]:
        """Every row of one statement (`SqliteFile.rows`)."""
        return self.file.rows(sql, params, fresh)

    def _write(self, sql: str, params: tuple | dict = (), fresh: bool = False) -> list[tuple]:
        """Rows of a writing statement (its RETURNING clause); checkpoints when due."""
        rows = self._rows(sql, params, fresh)
        if time.monotonic() - self._checkpointed >= self.checkpoint_interval:
            self.checkpoint()
        return rows

    def _json(self, value: Any) -> str | None:
        return _dumps(value)

    def _from_json(self, value: Any) -> Any:
        return _loads(value)

    def _packed(self, value: Any) -> bytes | None:
        return _pack(value)

    def _stored_bytes(self) -> str:
        """length() of each column: bytes of a compressed plan or solution (a blob's
        length is read without its content), characters of JSON text, which are ASCII."""
        return ("length(scene) + COALESCE(length(progress), 0) + COALESCE(length(plan), 0) "
                "+ COALESCE(length(solution), 0)")

    def _record(self, row: tuple) -> JobRecord:
        return _job(row)

    @property
    def journal_mode(self) -> str:
        """The journal mode in force ("wal")."""
        return self._rows("PRAGMA journal_mode")[0][0]

    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None, key: str | None = None,
               admission: dict[str, Any] | None = None) -> JobRecord | None:
        self.integrity.verify()
        values = (job_id, _dumps(scene), owner, time.time(), key, _dumps(admission))
        held = ("" if limit is None else "WHERE (SELECT COUNT(*) FROM jobs WHERE owner = ? "
                "AND status IN ('queued', 'running')) < ?")
        try:
            rows = self._write(
                "INSERT INTO jobs (id, status, scene, owner, created, idem_key, admission) "
                f"SELECT ?, 'queued', ?, ?, ?, ?, ? {held} RETURNING {COLUMNS}",
                values if limit is None else (*values, owner, limit), fresh=True)
        except sqlite3.IntegrityError as exc:
            raise DuplicateKey(key) from exc
        return _job(rows[0]) if rows else None

    def request_cancel(self, job_id: str) -> JobRecord | None:
        self._write(
            "UPDATE jobs SET status = 'cancelled', cancel_requested = 1, finished = ? "
            "WHERE id = ? AND status = 'queued'", (time.time(), job_id))
        self._write("UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND status = 'running'",
                    (job_id,))
        return self.get(job_id)

    def cancel_batch(self, batch_id: str) -> bool:
        if not self._rows("SELECT 1 FROM batches WHERE id = ?", (batch_id,)):
            return False
        with self.file.transaction() as conn:
            conn.execute("UPDATE jobs SET status = 'cancelled', cancel_requested = 1, "
                         "finished = ?, error = ? WHERE batch = ? AND status = 'queued'",
                         (time.time(), CANCELLED_ON_REQUEST, batch_id))
            conn.execute("UPDATE jobs SET cancel_requested = 1 WHERE batch = ? "
                         "AND status = 'running'", (batch_id,))
        return True

    def _push(self, pairs: str) -> str:
        return f"json_insert(COALESCE(history, '[]'), '$[#]', json_object({pairs}))"

    def claim(self, owner: str | None, worker: str, lease_until: float) -> JobRecord | None:
        mine = "AND owner = :owner" if owner is not None else ""
        rows = self._write(
            f"UPDATE jobs SET {self._claiming()} "
            "WHERE status = 'queued' AND id = (SELECT id FROM jobs WHERE status = 'queued' "
            f"{mine} AND (not_before IS NULL OR not_before <= :now) ORDER BY created, id "
            f"LIMIT 1) RETURNING {COLUMNS}",
            {**self._claim_params(worker, lease_until), "owner": owner})
        return self._record(rows[0]) if rows else None

    def renew(self, claims: builtins.list[tuple[str, str]],
              lease_until: float) -> dict[str, bool]:
        if not claims:
            return {}
        pairs = ", ".join(["(?, ?)"] * len(claims))
        rows = self._write(
            "UPDATE jobs SET lease_until = ? WHERE status = 'running' AND (id, worker) IN "
            f"(VALUES {pairs}) RETURNING id, cancel_requested",
            (lease_until, *(v for claim in claims for v in claim)))
        return {job_id: bool(cancel) for job_id, cancel in rows}

    def expire(self, now: float) -> dict[str, JobStatus]:
        return self._requeue(*self._lease_ended(now), LEASE_RAN_OUT)

    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None,
                     admissions: Sequence[dict[str, Any] | None] | None = None) -> bool:
        self.integrity.verify()
        now, decided = time.time(), admissions or [None] * len(members)
        with self.file.transaction(fresh=True) as conn:
            if limit is not None:
                (held,) = conn.execute(
                    "SELECT COUNT(*) FROM jobs WHERE owner = ? AND status IN "
                    "('queued', 'running')", (owner,)).fetchone()
                if held + len(members) > limit:
                    return False
            conn.execute("INSERT INTO batches (id, owner, created, spec) VALUES (?, ?, ?, ?)",
                         (batch_id, owner, now, _dumps(spec)))
            conn.executemany(
                "INSERT INTO jobs (id, status, scene, owner, created, batch, member, "
                "admission) VALUES (?, 'queued', ?, ?, ?, ?, ?, ?)",
                [(job_id, _dumps(scene), owner, now, batch_id, index, _dumps(admission))
                 for index, ((job_id, scene), admission)
                 in enumerate(zip(members, decided, strict=True))])
        return True

    def get_batch(self, batch_id: str) -> BatchRecord | None:
        rows = self._rows("SELECT id, spec, owner, created FROM batches WHERE id = ?",
                          (batch_id,))
        if not rows:
            return None
        id_, spec, owner, created = rows[0]
        members = self._rows(f"SELECT {_MEMBER_COLUMNS} FROM jobs WHERE batch = ? "
                             "ORDER BY member", (batch_id,))
        return BatchRecord(id=id_, spec=_loads(spec), owner=owner, created=created,
                           members=[_member(row) for row in members])

    def hold_name(self, name: str) -> NameLock:
        """The lock file of server name `name` beside the store (`app.store.sqlite_locks`)."""
        return NameLock(self.path, name)

    def listen(self) -> None:
        """None: SQLite cannot announce a queued job to another process, so an idle worker
        polls the store (`app.worker.IDLE_POLL`); a server's own workers are also woken
        through their supervisor's pipe (WAKE) whenever the server queues a job."""
        return None

    def retry(self, job_id: str, owner: str, limit: int | None = None) -> bool:
        self.integrity.verify()
        return super().retry(job_id, owner, limit)

    def check(self) -> None:
        """Check the files (database, write-ahead log, header) and read the schema, the
        newest job, the last row of the table and the count of its index through a new
        connection, whose pages come from the file and not from a cache; then `verify`."""
        self.file.connection()
        try:
            with contextlib.closing(self.file.open()) as conn:
                conn.execute("SELECT id FROM jobs ORDER BY created DESC LIMIT 1").fetchall()
                conn.execute("SELECT id, status FROM jobs WHERE rowid = "
                             "(SELECT max(rowid) FROM jobs)").fetchall()
                conn.execute("SELECT status, COUNT(*) FROM jobs GROUP BY status").fetchall()
        except sqlite3.Error as exc:
            raise self.file.failure(exc) from exc
        self.integrity.verify()

    def checkpoint(self, final: bool = False) -> None:
        self._checkpointed = time.monotonic()
        mode = "TRUNCATE" if final else "PASSIVE"
        busy, _, _ = self._rows(f"PRAGMA wal_checkpoint({mode})")[0]
        if busy:
            log.warning("the job store's write-ahead log could not be moved into %s "
                        "entirely (busy); it stays in %s-wal", self.path, self.path)

    def close(self) -> None:
        self.file.close()
