"""SQLite job store (stdlib sqlite3, WAL mode): one file shared by threads and processes.

Each thread of each process opens its own connection on first use. Writes are single
conditional statements, so they are atomic without explicit transactions; the busy
timeout makes concurrent writers queue instead of failing.

Its queue is its own: a claim is one conditional UPDATE of the oldest queued job, holding a
lease until the time it writes, which the supervisor renews; `expire` requeues the claims
whose lease ended. Nothing announces a queued job to another process (`listen`).

Opening the store checks its integrity (`PRAGMA quick_check`) and brings its schema up to
date (`app.store.migrations`; `PRAGMA user_version` counts the migrations applied).
Connections open the file read-write without creating it, and every statement first checks
that the path still names the file opened: a store deleted or replaced under a running
service is reported as unavailable instead of being silently recreated empty. The
write-ahead log is moved into the database file at least every `checkpoint_interval`
seconds of writes and entirely on shutdown, so the `-wal` file never holds more than that
interval's jobs.
"""

from __future__ import annotations

import builtins
import contextlib
import json
import logging
import os
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

from app.store.base import (
    CANCELLED_ON_REQUEST,
    BatchRecord,
    DuplicateKey,
    JobRecord,
    JobStatus,
    MemberRecord,
    RetryPolicy,
    StoreDamaged,
    StoreUnavailable,
)
from app.store.migrations import migrate, version
from app.store.sql import COLUMNS, LEASE_RAN_OUT, SqlJobStore, history

log = logging.getLogger("undertow.store")

_MEMBER_COLUMNS = ("id, member, status, error, json_extract(plan, '$.verification.verified'), "
                   "json_extract(plan, '$.objective'), started, finished")


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _job(row: tuple) -> JobRecord:
    (id_, status, scene, progress, plan, error, cancel, owner, created, started,
     finished, worker, attempts, infra, dead, events) = row
    return JobRecord(id=id_, status=status, scene=_loads(scene) or {}, progress=_loads(progress),
                     plan=_loads(plan), error=error, cancel_requested=bool(cancel),
                     owner=owner, created=created, started=started, finished=finished,
                     worker=worker, attempts=attempts, infra_failures=infra,
                     dead_letter=bool(dead), history=history(events))


def _member(row: tuple) -> MemberRecord:
    id_, index, status, error, verified, objective, started, finished = row
    return MemberRecord(job_id=id_, index=index, status=status, error=error,
                        verified=None if verified is None else bool(verified),
                        objective=objective, started=started, finished=finished)


def _dumps(value: Any) -> str | None:
    return None if value is None else json.dumps(value, allow_nan=False, separators=(",", ":"))


def _identity(path: str) -> tuple[int, int] | None:
    """(device, inode) of the file at `path`; None when there is none."""
    try:
        stat = os.stat(path)
    except FileNotFoundError:
        return None
    return stat.st_dev, stat.st_ino


class SqliteJobStore(SqlJobStore):
    """Jobs in one SQLite file (created with its directory if missing).

    Raises StoreDamaged when the file fails its integrity check."""

    def __init__(self, path: str | os.PathLike, busy_timeout: float = 30.0,
                 checkpoint_interval: float = 60.0, policy: RetryPolicy | None = None):
        self.path = str(path)
        self.policy = policy or RetryPolicy()
        self._started = False
        self.busy_timeout, self.checkpoint_interval = busy_timeout, checkpoint_interval
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        sqlite3.connect(self.path).close()  # creates an empty file if there is none
        self._identity = _identity(self.path)
        self._local = threading.local()
        self._wal_state()
        self._checkpointed = time.monotonic()
        self._verify()
        self._migrate()
        self._started = True

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "busy_timeout": self.busy_timeout,
                "checkpoint_interval": self.checkpoint_interval, "identity": self._identity,
                "policy": self.policy}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path, self.busy_timeout = state["path"], state["busy_timeout"]
        self.checkpoint_interval, self._identity = state["checkpoint_interval"], state["identity"]
        self.policy, self._started = state["policy"], True
        self._local = threading.local()
        self._wal_state()
        self._checkpointed = time.monotonic()

    def _wal_state(self) -> None:
        self._wal: tuple[int, tuple[int, int]] | None = None  # (pid, identity) first seen
        self._wal_lost = False
        self._wal_lock = threading.Lock()
        self._connections: list[sqlite3.Connection] = []
        self._header_fd: tuple[int, int] | None = None  # (pid, descriptor), never closed

    def _verify(self) -> None:
        """StoreDamaged unless the file is a database that passes PRAGMA quick_check."""
        try:
            rows = self._rows("PRAGMA quick_check")
        except StoreUnavailable as exc:
            raise StoreDamaged(self._damaged(str(exc.__cause__ or exc))) from exc
        findings = [" ".join(row[0].split()) for row in rows]
        if findings != ["ok"]:
            raise StoreDamaged(self._damaged("; ".join(findings[:5])))

    def _damaged(self, finding: str) -> str:
        return (f"the job store {self.path} failed its integrity check ({finding}); "
                "refusing to start on it. Move the file (with its -wal and -shm files) "
                "aside, keep it for recovery (`sqlite3 FILE .recover`), and start again "
                "to begin with an empty store")

    def _migrate(self) -> None:
        """Apply the migrations (`app.store.migrations`) this file has not had yet, in one
        transaction."""
        conn = self._connection()
        try:
            conn.execute("BEGIN IMMEDIATE")
            migrate(lambda sql: conn.execute(sql).fetchall(), "sqlite")
            conn.execute("COMMIT")
        except sqlite3.Error as exc:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            raise StoreUnavailable(f"the job store {self.path} could not be migrated: "
                                   f"{exc}") from exc

    @property
    def schema_version(self) -> int:
        """The version of the schema the file has (`app.store.migrations`)."""
        return version(self._rows, "sqlite")

    def _open(self) -> sqlite3.Connection:
        """A new connection to the file opened first (never creating one)."""
        if _identity(self.path) != self._identity:
            raise StoreUnavailable(f"the job store file {self.path} was deleted or replaced "
                                   "while the service ran; restart the service")
        self._check_header()
        uri = Path(self.path).absolute().as_uri() + "?mode=rw"
        conn = sqlite3.connect(uri, uri=True, timeout=self.busy_timeout,
                               isolation_level=None, check_same_thread=False)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        return conn

    def _check_header(self) -> None:
        """StoreUnavailable unless the file still starts with SQLite's header (it was not
        overwritten in place since the store was opened). The header is read through a
        descriptor this process keeps open: closing any descriptor of the file would drop
        the process's POSIX locks on it, and with them SQLite's knowledge that this
        process still uses the write-ahead log."""
        if not self._started:
            return
        try:
            with self._wal_lock:
                if self._header_fd is None or self._header_fd[0] != os.getpid():
                    self._header_fd = (os.getpid(), os.open(self.path, os.O_RDONLY))
                header = os.pread(self._header_fd[1], 16, 0)
        except OSError as exc:
            raise StoreUnavailable(f"the job store {self.path} cannot be read: {exc}") from exc
        if header != b"SQLite format 3\0":
            raise StoreUnavailable(f"the job store file {self.path} was overwritten while the "
                                   "service ran (it no longer starts with SQLite's header); "
                                   "restart the service")

    def _connection(self) -> sqlite3.Connection:
        """This thread's connection (a new one after a fork); every use checks that the
        path still names the file opened first, and that PATH-wal is still the
        write-ahead log this process first saw (SQLite deletes it only when the last
        connection closes, and this process keeps its connections open)."""
        local = self._local
        if getattr(local, "pid", None) != os.getpid():
            self._check_wal()
            local.conn, local.pid = self._open(), os.getpid()
            with self._wal_lock:
                self._connections.append(local.conn)
        elif _identity(self.path) != self._identity:
            self._open()  # raises StoreUnavailable
        else:
            self._check_wal()
        return local.conn

    def _check_wal(self) -> None:
        wal = _identity(self.wal_path)
        with self._wal_lock:
            if self._wal is None or self._wal[0] != os.getpid():
                if wal is not None:
                    self._wal = (os.getpid(), wal)
                return
            if wal == self._wal[1]:
                return
            first = not self._wal_lost
            self._wal_lost = True
        if first:
            self._salvage()
        raise StoreUnavailable(
            f"the job store's write-ahead log {self.wal_path} was deleted or replaced "
            "while the service ran; new jobs are refused until the service is restarted "
            "(what the log held was moved into the database file)")

    @property
    def wal_path(self) -> str:
        return self.path + "-wal"

    def _salvage(self) -> None:
        """Move what the deleted write-ahead log (still open in this process's
        connections) holds into the database file, so that the jobs accepted before it
        was deleted survive."""
        for conn in list(self._connections):
            try:
                busy, _, _ = conn.execute("PRAGMA wal_checkpoint(FULL)").fetchone()
            except sqlite3.Error as exc:
                log.error("the job store's write-ahead log could not be saved: %s", exc)
                continue
            if not busy:
                log.error("the job store's write-ahead log %s was deleted; what it held was "
                          "moved into %s", self.wal_path, self.path)
                return
        log.error("the job store's write-ahead log %s was deleted and could not be moved "
                  "into %s entirely", self.wal_path, self.path)

    def _rows(self, sql: str, params: tuple | dict = (), fresh: bool = False) -> list[tuple]:
        """Every row of one statement (fetched at once, so a write is complete); `fresh`:
        through a new connection, whose pages come from the file and not from a cache."""
        try:
            if fresh:
                self._connection()  # the checks of the files
                with contextlib.closing(self._open()) as conn:
                    return conn.execute(sql, params).fetchall()
            rows = self._connection().execute(sql, params).fetchall()
            if self._wal is None:
                self._check_wal()  # the log this process writes to, once there is one
            return rows
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise StoreUnavailable(f"the job store {self.path} failed: {exc}") from exc

    @contextlib.contextmanager
    def _transaction(self, fresh: bool = False):
        """This thread's connection (`fresh`: a new one) inside BEGIN IMMEDIATE ... COMMIT
        (ROLLBACK on error)."""
        try:
            conn = self._connection()
            if fresh:
                conn = self._open()
            try:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    yield conn
                except BaseException:
                    conn.execute("ROLLBACK")
                    raise
                conn.execute("COMMIT")
            finally:
                if fresh:
                    conn.close()
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise StoreUnavailable(f"the job store {self.path} failed: {exc}") from exc

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

    def _record(self, row: tuple) -> JobRecord:
        return _job(row)

    @property
    def journal_mode(self) -> str:
        """The journal mode in force ("wal")."""
        return self._rows("PRAGMA journal_mode")[0][0]

    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None, key: str | None = None) -> JobRecord | None:
        values = (job_id, _dumps(scene), owner, time.time(), key)
        held = ("" if limit is None else "WHERE (SELECT COUNT(*) FROM jobs WHERE owner = ? "
                "AND status IN ('queued', 'running')) < ?")
        try:
            rows = self._write(
                "INSERT INTO jobs (id, status, scene, owner, created, idem_key) "
                f"SELECT ?, 'queued', ?, ?, ?, ? {held} RETURNING {COLUMNS}",
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
        with self._transaction() as conn:
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
        return self._requeue("lease_until < :expired", {"expired": now}, LEASE_RAN_OUT)

    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None) -> bool:
        now = time.time()
        with self._transaction(fresh=True) as conn:
            if limit is not None:
                (held,) = conn.execute(
                    "SELECT COUNT(*) FROM jobs WHERE owner = ? AND status IN "
                    "('queued', 'running')", (owner,)).fetchone()
                if held + len(members) > limit:
                    return False
            conn.execute("INSERT INTO batches (id, owner, created, spec) VALUES (?, ?, ?, ?)",
                         (batch_id, owner, now, _dumps(spec)))
            conn.executemany(
                "INSERT INTO jobs (id, status, scene, owner, created, batch, member) "
                "VALUES (?, 'queued', ?, ?, ?, ?, ?)",
                [(job_id, _dumps(scene), owner, now, batch_id, index)
                 for index, (job_id, scene) in enumerate(members)])
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

    def listen(self) -> None:
        """None: SQLite cannot announce a queued job to another process, so an idle worker
        polls the store (`app.worker.IDLE_POLL`); a server's own workers are also woken
        through their supervisor's pipe (WAKE) whenever the server queues a job."""
        return None

    def check(self) -> None:
        """Check the files (database, write-ahead log, header) and read the schema, the
        newest job, the last row of the table and the count of its index through a new
        connection, whose pages come from the file and not from a cache."""
        self._connection()
        try:
            with contextlib.closing(self._open()) as conn:
                conn.execute("SELECT id FROM jobs ORDER BY created DESC LIMIT 1").fetchall()
                conn.execute("SELECT id, status FROM jobs WHERE rowid = "
                             "(SELECT max(rowid) FROM jobs)").fetchall()
                conn.execute("SELECT status, COUNT(*) FROM jobs GROUP BY status").fetchall()
        except sqlite3.Error as exc:
            raise StoreUnavailable(f"the job store {self.path} failed: {exc}") from exc

    def checkpoint(self, final: bool = False) -> None:
        self._checkpointed = time.monotonic()
        mode = "TRUNCATE" if final else "PASSIVE"
        busy, _, _ = self._rows(f"PRAGMA wal_checkpoint({mode})")[0]
        if busy:
            log.warning("the job store's write-ahead log could not be moved into %s "
                        "entirely (busy); it stays in %s-wal", self.path, self.path)

    def close(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None and self._local.pid == os.getpid():
            conn.close()
            with self._wal_lock:
                if conn in self._connections:
                    self._connections.remove(conn)
                if not self._connections:  # the log may go with the last connection
                    self._wal = None
        self._local = threading.local()
