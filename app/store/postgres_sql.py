"""The PostgreSQL job store without its queue (psycopg 3 with a connection pool): its
connections, its dialect of the shared statements, and the statements it runs in
transactions of its own. The queue (claims, leases, pickup) is procrastinate's, added by
`app.store.postgres`, the store a process opens, and so is a job's status: the database
derives it from the engine job's (`app.store.postgres_status`), so no statement here
writes it and a new job starts `queued` by the column's default.

Each process opens its own pool on first use (the store pickles as its URL, so worker
processes reopen it). Statements run in autocommit mode, or in the one transaction their
thread has open (`_transaction`), which every statement of that thread joins until it
ends; the few that must agree with a count (a new job or batch under the owner's limit)
run in one transaction holding the owner's advisory lock.

The schema is versioned in the table `undertow_schema`; opening the store applies the
migrations it has not had (`app.store.migrations`, the SQLite store's too) under an
advisory lock so that servers starting together migrate once, and refuses a schema newer
than the code knows (`NewerSchema`). JSON objects are `jsonb`;
times are Unix seconds (`double precision`) taken from the clock of the process that
writes them, so the machines of one deployment keep their clocks synchronised (NTP).
"""

from __future__ import annotations

import builtins
import os
import re
import threading
import time
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from typing import Any

import psycopg
from psycopg.types.json import Jsonb, set_json_loads
from psycopg_pool import ConnectionPool, PoolTimeout

from app.store import json_text
from app.store.base import (
    CANCELLED_ON_REQUEST,
    BatchRecord,
    DuplicateKey,
    JobRecord,
    MemberRecord,
    NameTaken,
    RetryPolicy,
    StoreUnavailable,
)
from app.store.migrations import migrate, version
from app.store.postgres_pool import Pool
from app.store.sql import COLUMNS, SqlJobStore
from app.store.waits import CHECK_WAIT, connection_wait

_MIGRATION_LOCK = 0x756E6474  # advisory lock key held while migrating ("undt")

_MEMBER_COLUMNS = "id, member, status, error, verified, objective, started, finished"


_NAMED = re.compile(r"(?<![:\w]):([a-z_]+)")
"""A named parameter of the shared statements (`:name`, never a `::type` cast)."""


def _reads_json_text(conn: psycopg.Connection) -> None:
    """A pooled connection decodes json and jsonb columns by `app.store.json_text`."""
    set_json_loads(json_text.loads, conn)


def _jsonb(value: Any) -> Jsonb | None:
    """A JSON parameter (`app.store.json_text`: no NaN or Inf, which PostgreSQL's jsonb
    refuses)."""
    return None if value is None else Jsonb(value, dumps=json_text.dumps)


def _job(row: tuple) -> JobRecord:
    (id_, status, scene, progress, plan, error, cancel, owner, created, started,
     finished, worker, attempts, infra, dead, events, admission) = row
    return JobRecord(id=id_, status=status, scene=scene or {}, progress=progress, plan=plan,
                     error=error, cancel_requested=cancel, owner=owner, created=created,
                     started=started, finished=finished, worker=worker, attempts=attempts,
                     infra_failures=infra, dead_letter=dead, history=events,
                     admission=admission)


def _member(row: tuple) -> MemberRecord:
    id_, index, status, error, verified, objective, started, finished = row
    return MemberRecord(job_id=id_, index=index, status=status, error=error,
                        verified=verified, objective=objective, started=started,
                        finished=finished)


def _one(cursor: psycopg.Cursor) -> tuple[Any, ...]:
    """The row of a statement that always returns one (a COUNT, an INSERT ... RETURNING)."""
    row = cursor.fetchone()
    if row is None:
        raise RuntimeError("the statement returned no row")
    return row


def _execute(conn: psycopg.Connection, sql: str) -> builtins.list[tuple]:
    """Every row of one statement without parameters ([] when it returns none)."""
    cursor = conn.execute(sql)
    return cursor.fetchall() if cursor.description is not None else []


def _lock_key(owner: str) -> int:
    """The advisory lock key of an owner's job count (a signed 32-bit hash)."""
    return zlib.crc32(owner.encode()) - 2**31


_NAME_LOCKS = 0x756E6476  # first key of the advisory locks of server names ("undv")


class NameLock:
    """Server name `name` held in the database at `url` by a session advisory lock on a
    connection of its own, kept open until `release` (NameTaken when another session
    holds it). The lock ends with the session: a server that loses its connection to
    the database loses its name with it."""

    def __init__(self, url: str, name: str, where: str, timeout: float):
        self._conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, int(timeout)))
        (held,) = _one(self._conn.execute("SELECT pg_try_advisory_lock(%s, %s)",
                                          (_NAME_LOCKS, _lock_key(name))))
        if not held:
            self._conn.close()
            raise NameTaken(
                f"another server named {name!r} runs on the job store ({where}): a second "
                "server of that name would take its running jobs for its own. Stop that "
                "server first, or give this one another name (UNDERTOW_INSTANCE)")

    def release(self) -> None:
        """End the session, and the lock with it."""
        self._conn.close()


class PostgresSql(SqlJobStore):
    """Jobs in a PostgreSQL database at `url` ("postgresql://user:password@host:port/db"),
    without a queue: `app.store.postgres.PostgresJobStore` claims, renews, expires and
    announces them.

    `pool_size` connections at most per process; a statement that cannot get one within
    `timeout` seconds (REQUEST_WAIT at most for an HTTP request: `app.store.waits`), or
    fails on the server, raises StoreUnavailable."""

    SMALLER = "LEAST"

    def __init__(self, url: str, pool_size: int = 4, timeout: float = 10.0,
                 policy: RetryPolicy | None = None):
        self.url, self.pool_size, self.timeout = url, pool_size, timeout
        self.policy = policy or RetryPolicy()
        self._lock = threading.Lock()
        self._pool: ConnectionPool | None = None
        self._pid = os.getpid()
        self._local = threading.local()
        try:
            self._migrate()
        except StoreUnavailable:
            self.close()  # no pool left retrying in the background
            raise

    def __getstate__(self) -> dict[str, Any]:
        return {"url": self.url, "pool_size": self.pool_size, "timeout": self.timeout,
                "policy": self.policy}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.url, self.pool_size, self.timeout = state["url"], state["pool_size"], state["timeout"]
        self.policy = state["policy"]
        self._lock, self._pool, self._pid = threading.Lock(), None, os.getpid()
        self._local = threading.local()

    def _where(self) -> str:
        """The database named in messages: host, port and name, never the password."""
        try:
            info = psycopg.conninfo.conninfo_to_dict(self.url)
        except psycopg.Error:
            return "PostgreSQL"
        host, port = info.get("host", ""), info.get("port", 5432)
        return f"PostgreSQL {host}:{port}/{info.get('dbname', '')}"

    def _unavailable(self, exc: Exception) -> StoreUnavailable:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return StoreUnavailable(f"the job store ({self._where()}) failed: {first}")

    def _get_pool(self) -> ConnectionPool:
        """This process's pool (a new one after a fork)."""
        with self._lock:
            if self._pool is None or self._pid != os.getpid():
                self._pool = Pool(
                    self.url, min_size=1, max_size=self.pool_size, timeout=self.timeout,
                    kwargs={"autocommit": True, "connect_timeout": max(1, int(self.timeout))},
                    check=ConnectionPool.check_connection, configure=_reads_json_text,
                    open=True, name="undertow-jobs")
                self._pid = os.getpid()
            return self._pool

    @contextmanager
    def _connection(self, wait: float | None = None) -> Iterator[psycopg.Connection]:
        """The connection of this thread's open transaction, else a pooled one within
        `wait` seconds (default: the store's timeout, bounded within an HTTP request:
        `app.store.waits`); any database or pool error becomes StoreUnavailable."""
        held = getattr(self._local, "conn", None)
        if held is not None:
            yield held
            return
        if wait is None:
            wait = connection_wait(self.timeout)
        try:
            with self._get_pool().connection(timeout=wait) as conn:
                yield conn
        except (psycopg.OperationalError, psycopg.InterfaceError, psycopg.errors.DataError,
                psycopg.errors.InternalError, PoolTimeout) as exc:
            raise self._unavailable(exc) from exc

    @contextmanager
    def _transaction(self) -> Iterator[psycopg.Connection]:
        """One transaction that every statement of this thread joins until it ends."""
        with self._connection() as conn, conn.transaction():
            outer, self._local.conn = getattr(self._local, "conn", None), conn
            try:
                yield conn
            finally:
                self._local.conn = outer

    def _rows(self, sql: str, params: tuple | dict = (),
              wait: float | None = None) -> builtins.list[tuple]:
        """Every row of one statement (autocommit: a write is complete on return), waiting
        `wait` seconds at most for a connection (`_connection`'s default without); the
        shared statements' `?` and `:name` parameters become psycopg's `%s`, `%(name)s`."""
        named = not isinstance(params, tuple)
        sql = _NAMED.sub(r"%(\1)s", sql) if named else sql.replace("?", "%s")
        with self._connection(wait) as conn:
            cursor = conn.execute(sql, params)
            return cursor.fetchall() if cursor.description is not None else []

    def _write(self, sql: str, params: tuple | dict = ()) -> builtins.list[tuple]:
        return self._rows(sql, params)

    def _json(self, value: Any) -> Jsonb | None:
        return _jsonb(value)

    def _from_json(self, value: Any) -> Any:
        return value  # jsonb columns come back decoded

    def _packed(self, value: Any) -> Jsonb | None:
        """jsonb, which PostgreSQL compresses itself where it is large (TOAST)."""
        return _jsonb(value)

    def _stored_bytes(self) -> str:
        """pg_column_size() of each column: its size as stored, compressed or not."""
        return ("pg_column_size(scene) + COALESCE(pg_column_size(progress), 0) + "
                "COALESCE(pg_column_size(plan), 0) + COALESCE(pg_column_size(solution), 0)")

    def _record(self, row: tuple) -> JobRecord:
        return _job(row)

    def _migrate(self) -> None:
        """Apply the migrations (`app.store.migrations`) this database has not had yet, in
        one transaction; NewerSchema, changing nothing, when a newer version migrated it."""
        try:
            with self._connection() as conn, conn.transaction():
                conn.execute("SELECT pg_advisory_xact_lock(%s)", (_MIGRATION_LOCK,))
                migrate(partial(_execute, conn), "postgres",
                        where=f"the job store ({self._where()})")
        except psycopg.Error as exc:
            raise StoreUnavailable(f"the job store ({self._where()}) could not be migrated: "
                                   f"{exc}") from exc

    @property
    def schema_version(self) -> int:
        """The version of the schema the database has (`app.store.migrations`)."""
        return version(self._rows, "postgres")

    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None, key: str | None = None,
               admission: dict[str, Any] | None = None) -> JobRecord | None:
        insert = ("INSERT INTO jobs (id, scene, owner, created, idem_key, admission) "
                  f"VALUES (%s, %s, %s, %s, %s, %s) RETURNING {COLUMNS}")
        values = (job_id, _jsonb(scene), owner, time.time(), key, _jsonb(admission))
        try:
            if limit is None:
                return _job(self._rows(insert, values)[0])
            with self._connection() as conn, conn.transaction():
                if self._held(conn, owner) >= limit:
                    return None
                return _job(_one(conn.execute(insert, values)))
        except psycopg.errors.UniqueViolation as exc:
            raise DuplicateKey(key) from exc

    def retry(self, job_id: str, owner: str, limit: int | None = None) -> bool:
        params = {"id": job_id, "owner": owner, "limit": limit, "now": time.time()}
        sql = _NAMED.sub(r"%(\1)s", self._retry_statement(False))
        with self._connection() as conn, conn.transaction():
            if limit is not None and self._held(conn, owner) >= limit:
                return False
            return conn.execute(sql, params).fetchone() is not None

    @staticmethod
    def _held(conn: psycopg.Connection, owner: str) -> int:
        """The owner's unfinished jobs, counted under its advisory lock (held until the
        transaction ends, so a concurrent create waits for this one's insert)."""
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (_lock_key(owner),))
        return _one(conn.execute("SELECT COUNT(*) FROM jobs WHERE owner = %s AND status IN "
                                 "('queued', 'running')", (owner,)))[0]

    def request_cancel(self, job_id: str) -> JobRecord | None:
        self._rows(
            "UPDATE jobs SET cancel_requested = true, "
            "finished = CASE WHEN status = 'queued' THEN %s ELSE finished END "
            "WHERE id = %s AND status IN ('queued', 'running')", (time.time(), job_id))
        return self.get(job_id)

    def cancel_batch(self, batch_id: str) -> bool:
        with self._connection() as conn, conn.transaction():
            if conn.execute("SELECT 1 FROM batches WHERE id = %s", (batch_id,)).fetchone() is None:
                return False
            conn.execute(
                "UPDATE jobs SET cancel_requested = true, "
                "error = CASE WHEN status = 'queued' THEN %s ELSE error END, "
                "finished = CASE WHEN status = 'queued' THEN %s ELSE finished END "
                "WHERE batch = %s AND status IN ('queued', 'running')",
                (CANCELLED_ON_REQUEST, time.time(), batch_id))
        return True

    def _push(self, pairs: str) -> str:
        return f"COALESCE(history, '[]'::jsonb) || jsonb_build_array(jsonb_build_object({pairs}))"

    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None,
                     admissions: Sequence[dict[str, Any] | None] | None = None) -> bool:
        now, decided = time.time(), admissions or [None] * len(members)
        with self._connection() as conn, conn.transaction():
            if limit is not None and self._held(conn, owner) + len(members) > limit:
                return False
            conn.execute("INSERT INTO batches (id, owner, created, spec) "
                         "VALUES (%s, %s, %s, %s)", (batch_id, owner, now, _jsonb(spec)))
            with conn.cursor() as cursor:
                cursor.executemany(
                    "INSERT INTO jobs (id, scene, owner, created, batch, member, admission) "
                    "VALUES (%s, %s, %s, %s, %s, %s, %s)",
                    [(job_id, _jsonb(scene), owner, now, batch_id, index, _jsonb(admission))
                     for index, ((job_id, scene), admission)
                     in enumerate(zip(members, decided, strict=True))])
        return True

    def get_batch(self, batch_id: str) -> BatchRecord | None:
        with self._connection() as conn, conn.transaction():
            conn.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
            row = conn.execute("SELECT id, spec, owner, created FROM batches WHERE id = %s",
                               (batch_id,)).fetchone()
            if row is None:
                return None
            members = conn.execute(f"SELECT {_MEMBER_COLUMNS} FROM jobs WHERE batch = %s "
                                   "ORDER BY member", (batch_id,)).fetchall()
        id_, spec, owner, created = row
        return BatchRecord(id=id_, spec=spec, owner=owner, created=created,
                           members=[_member(m) for m in members])

    def hold_name(self, name: str) -> NameLock:
        try:
            return NameLock(self.url, name, self._where(), self.timeout)
        except psycopg.Error as exc:
            raise self._unavailable(exc) from exc

    def check(self) -> None:
        """Read the newest job through the pool (a new connection if the old ones broke),
        waiting at most CHECK_WAIT for a connection: a health check answers within a
        container's health-check timeout while the database is away."""
        self._rows("SELECT id FROM jobs ORDER BY created DESC LIMIT 1", wait=CHECK_WAIT)

    def verify(self) -> None:
        """Nothing to do: PostgreSQL checks its own pages as it reads them (checksums,
        when the cluster has them) and reports damage as an error of the statement."""

    def checkpoint(self, final: bool = False) -> None:
        """Nothing to do: PostgreSQL makes every committed change durable itself."""

    def close(self) -> None:
        with self._lock:
            if self._pool is not None and self._pid == os.getpid():
                self._pool.close()
            self._pool = None

