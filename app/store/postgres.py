"""PostgreSQL job store (psycopg 3 with a connection pool): one database shared by API
servers and workers on any number of machines.

Each process opens its own pool on first use (the store pickles as its URL, so worker
processes reopen it). Statements run in autocommit mode; the few that must agree with a
count (a new job or batch under the owner's limit) run in one transaction holding the
owner's advisory lock. Claims take the oldest queued job with `FOR UPDATE SKIP LOCKED`,
so concurrent workers never wait for each other and never take the same job.

The schema is versioned in the table `undertow_schema`; opening the store applies the
migrations it has not had, numbered as the SQLite store's, under an advisory lock so that
servers starting together migrate once. JSON objects are `jsonb`; times are Unix seconds
(`double precision`) taken from the clock of the process that writes them, so the
machines of one deployment keep their clocks synchronised (NTP).
"""

from __future__ import annotations

import builtins
import json
import os
import threading
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import psycopg
from psycopg.types.json import Jsonb
from psycopg_pool import ConnectionPool, PoolTimeout

from app.store.base import (
    CANCELLED_ON_REQUEST,
    INTERRUPTED,
    MAX_ATTEMPTS,
    BatchRecord,
    JobRecord,
    JobStatus,
    MemberRecord,
    StoreUnavailable,
)
from app.store.sql import COLUMNS, SqlJobStore

_MIGRATIONS: tuple[tuple[str, ...], ...] = (
    (  # 1: the jobs table
        """CREATE TABLE IF NOT EXISTS jobs (
            id               text PRIMARY KEY,
            status           text NOT NULL,
            scene            jsonb NOT NULL,
            progress         jsonb,
            plan             jsonb,
            error            text,
            cancel_requested boolean NOT NULL DEFAULT false,
            owner            text NOT NULL,
            created          double precision NOT NULL,
            started          double precision,
            finished         double precision)""",
        "CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status)",
        "CREATE INDEX IF NOT EXISTS jobs_created ON jobs (created)",
    ),
    (  # 2: claims name their worker and hold a lease
        "ALTER TABLE jobs ADD COLUMN worker text",
        "ALTER TABLE jobs ADD COLUMN lease_until double precision",
        "CREATE INDEX IF NOT EXISTS jobs_owner_status ON jobs (owner, status, created)",
    ),
    (  # 3: the NLP solution behind a plan, for warm starts (kept out of the plan's JSON)
        "ALTER TABLE jobs ADD COLUMN solution jsonb",
    ),
    (  # 4: claims are counted (a job whose lease ran out is requeued once); batches
        "ALTER TABLE jobs ADD COLUMN attempts integer NOT NULL DEFAULT 0",
        "ALTER TABLE jobs ADD COLUMN batch text",
        "ALTER TABLE jobs ADD COLUMN member integer",
        "CREATE INDEX IF NOT EXISTS jobs_batch ON jobs (batch, member)",
        """CREATE TABLE IF NOT EXISTS batches (
            id      text PRIMARY KEY,
            owner   text NOT NULL,
            created double precision NOT NULL,
            spec    jsonb NOT NULL)""",
    ),
)
SCHEMA_VERSION = len(_MIGRATIONS)
_MIGRATION_LOCK = 0x756E6474  # advisory lock key held while migrating ("undt")

_MEMBER_COLUMNS = ("id, member, status, error, (plan->'verification'->>'verified')::boolean, "
                   "(plan->>'objective')::double precision, started, finished")
_REQUEUE = "NOT cancel_requested AND attempts < %(max)s"
_EXPIRED = (  # the settlement of a running job whose lease ran out (see JobStore.expire)
    "status = CASE WHEN cancel_requested THEN 'cancelled' WHEN attempts < %(max)s "
    "THEN 'queued' ELSE 'failed' END, error = CASE WHEN cancel_requested THEN %(cancelled)s "
    "WHEN attempts < %(max)s THEN NULL ELSE %(interrupted)s END, "
    f"finished = CASE WHEN {_REQUEUE} THEN NULL ELSE %(now)s END, "
    f"started = CASE WHEN {_REQUEUE} THEN NULL ELSE started END, "
    f"progress = CASE WHEN {_REQUEUE} THEN NULL ELSE progress END, "
    f"worker = CASE WHEN {_REQUEUE} THEN NULL ELSE worker END, lease_until = NULL")


def _jsonb(value: Any) -> Jsonb | None:
    """A JSON parameter (no NaN or Inf: PostgreSQL's jsonb refuses them too)."""
    return None if value is None else Jsonb(value, dumps=_dumps)


def _dumps(value: Any) -> str:
    return json.dumps(value, allow_nan=False, separators=(",", ":"))


def _job(row: tuple) -> JobRecord:
    (id_, status, scene, progress, plan, error, cancel, owner, created, started,
     finished, worker) = row
    return JobRecord(id=id_, status=status, scene=scene, progress=progress, plan=plan,
                     error=error, cancel_requested=cancel, owner=owner, created=created,
                     started=started, finished=finished, worker=worker)


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


def _lock_key(owner: str) -> int:
    """The advisory lock key of an owner's job count (a signed 32-bit hash)."""
    return zlib.crc32(owner.encode()) - 2**31


class PostgresJobStore(SqlJobStore):
    """Jobs in a PostgreSQL database at `url` ("postgresql://user:password@host:port/db").

    `pool_size` connections at most per process; a statement that cannot get one within
    `timeout` seconds, or fails on the server, raises StoreUnavailable."""

    claim_lock = "FOR UPDATE SKIP LOCKED"

    def __init__(self, url: str, pool_size: int = 4, timeout: float = 10.0):
        self.url, self.pool_size, self.timeout = url, pool_size, timeout
        self._lock = threading.Lock()
        self._pool: ConnectionPool | None = None
        self._pid = os.getpid()
        try:
            self._migrate()
        except StoreUnavailable:
            self.close()  # no pool left retrying in the background
            raise

    def __getstate__(self) -> dict[str, Any]:
        return {"url": self.url, "pool_size": self.pool_size, "timeout": self.timeout}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.url, self.pool_size, self.timeout = state["url"], state["pool_size"], state["timeout"]
        self._lock, self._pool, self._pid = threading.Lock(), None, os.getpid()

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
                self._pool = ConnectionPool(
                    self.url, min_size=1, max_size=self.pool_size, timeout=self.timeout,
                    kwargs={"autocommit": True, "connect_timeout": max(1, int(self.timeout))},
                    open=True, name="undertow-jobs")
                self._pid = os.getpid()
            return self._pool

    @contextmanager
    def _connection(self) -> Iterator[psycopg.Connection]:
        """A pooled connection; any database or pool error becomes StoreUnavailable."""
        try:
            with self._get_pool().connection() as conn:
                yield conn
        except (psycopg.OperationalError, psycopg.InterfaceError, psycopg.errors.DataError,
                psycopg.errors.InternalError, PoolTimeout) as exc:
            raise self._unavailable(exc) from exc

    def _rows(self, sql: str, params: tuple | dict = ()) -> builtins.list[tuple]:
        """Every row of one statement (autocommit: a write is complete on return); the
        shared statements' `?` parameters become psycopg's `%s`."""
        if isinstance(params, tuple):
            sql = sql.replace("?", "%s")
        with self._connection() as conn:
            cursor = conn.execute(sql, params)
            return cursor.fetchall() if cursor.description is not None else []

    def _write(self, sql: str, params: tuple | dict = ()) -> builtins.list[tuple]:
        return self._rows(sql, params)

    def _json(self, value: Any) -> Jsonb | None:
        return _jsonb(value)

    def _from_json(self, value: Any) -> Any:
        return value  # jsonb columns come back decoded

    def _record(self, row: tuple) -> JobRecord:
        return _job(row)

    def _migrate(self) -> None:
        """Apply the migrations this database has not had yet, in one transaction."""
        try:
            with self._connection() as conn, conn.transaction():
                conn.execute("SELECT pg_advisory_xact_lock(%s)", (_MIGRATION_LOCK,))
                conn.execute("CREATE TABLE IF NOT EXISTS undertow_schema (version integer "
                             "NOT NULL)")
                row = conn.execute("SELECT version FROM undertow_schema").fetchone()
                version = 0 if row is None else row[0]
                for statements in _MIGRATIONS[version:]:
                    for statement in statements:
                        conn.execute(statement)
                if row is None:
                    conn.execute("INSERT INTO undertow_schema VALUES (%s)", (SCHEMA_VERSION,))
                elif version < SCHEMA_VERSION:
                    conn.execute("UPDATE undertow_schema SET version = %s", (SCHEMA_VERSION,))
        except psycopg.Error as exc:
            raise StoreUnavailable(f"the job store ({self._where()}) could not be migrated: "
                                   f"{exc}") from exc

    @property
    def schema_version(self) -> int:
        """The number of migrations the database has had."""
        return self._rows("SELECT version FROM undertow_schema")[0][0]

    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None) -> JobRecord | None:
        insert = ("INSERT INTO jobs (id, status, scene, owner, created) "
                  f"VALUES (%s, 'queued', %s, %s, %s) RETURNING {COLUMNS}")
        values = (job_id, _jsonb(scene), owner, time.time())
        if limit is None:
            return _job(self._rows(insert, values)[0])
        with self._connection() as conn, conn.transaction():
            if self._held(conn, owner) >= limit:
                return None
            return _job(_one(conn.execute(insert, values)))

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
            "status = CASE WHEN status = 'queued' THEN 'cancelled' ELSE status END, "
            "finished = CASE WHEN status = 'queued' THEN %s ELSE finished END "
            "WHERE id = %s AND status IN ('queued', 'running')", (time.time(), job_id))
        return self.get(job_id)

    def renew(self, workers: builtins.list[str], lease_until: float) -> dict[str, bool]:
        if not workers:
            return {}
        rows = self._rows(
            "UPDATE jobs SET lease_until = %s WHERE status = 'running' AND worker = ANY(%s) "
            "RETURNING id, cancel_requested", (lease_until, workers))
        return {job_id: cancel for job_id, cancel in rows}

    def expire(self, now: float) -> dict[str, JobStatus]:
        rows = self._rows(
            f"UPDATE jobs SET {_EXPIRED} WHERE status = 'running' AND lease_until < %(now)s "
            "RETURNING id, status", {"max": MAX_ATTEMPTS, "cancelled": CANCELLED_ON_REQUEST,
                                     "interrupted": INTERRUPTED, "now": now})
        return dict(rows)

    def interrupt(self, owner: str) -> builtins.list[str]:
        return self._fail_running("owner = %s AND starts_with(worker, %s)",
                                  (owner, owner + "/"), INTERRUPTED)

    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None) -> bool:
        now = time.time()
        with self._connection() as conn, conn.transaction():
            if limit is not None and self._held(conn, owner) + len(members) > limit:
                return False
            conn.execute("INSERT INTO batches (id, owner, created, spec) "
                         "VALUES (%s, %s, %s, %s)", (batch_id, owner, now, _jsonb(spec)))
            with conn.cursor() as cursor:
                cursor.executemany(
                    "INSERT INTO jobs (id, status, scene, owner, created, batch, member) "
                    "VALUES (%s, 'queued', %s, %s, %s, %s, %s)",
                    [(job_id, _jsonb(scene), owner, now, batch_id, index)
                     for index, (job_id, scene) in enumerate(members)])
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

    def check(self) -> None:
        """Read the newest job through the pool (a new connection if the old ones broke)."""
        self._rows("SELECT id FROM jobs ORDER BY created DESC LIMIT 1")

    def checkpoint(self, final: bool = False) -> None:
        """Nothing to do: PostgreSQL makes every committed change durable itself."""

    def close(self) -> None:
        with self._lock:
            if self._pool is not None and self._pid == os.getpid():
                self._pool.close()
            self._pool = None
