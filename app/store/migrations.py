"""The job store's schema: one ordered list of migrations for both databases.

Each step has a version (1, 2, ...: the numbering both stores used before they shared this
list, so a database at version k goes on with step k + 1), what it is for, and its
statements, written once: the few types that differ between the dialects are placeholders
(`TYPES`: {json}, {real}, {bool}, {false}), and a statement only one database has (the
PostgreSQL notification of a queued job, and its removal) is listed under that dialect; a
step may have statements for one database alone, and the other then only records its
version.

`migrate` applies the steps a database has not had, through the store's own connection and
inside the transaction the store opened, and records the version where that database keeps
it (`LEDGERS`: SQLite's `PRAGMA user_version`, PostgreSQL's table `undertow_schema`). A
database of a newer version than this list's newest step (migrated by a newer version of
the service) is refused, changing nothing (`NewerSchema`, saying to upgrade the process):
a process does not start on a schema it does not know.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from app.store.base import NewerSchema

Dialect = Literal["sqlite", "postgres"]
DIALECTS: tuple[Dialect, ...] = ("sqlite", "postgres")

TYPES: dict[Dialect, dict[str, str]] = {
    "sqlite": {"json": "TEXT", "real": "REAL", "bool": "INTEGER", "false": "0"},
    "postgres": {"json": "jsonb", "real": "double precision", "bool": "boolean",
                 "false": "false"},
}
"""What each placeholder of a step's statements stands for in each dialect."""

CHANNEL = "undertow_jobs"
"""The PostgreSQL channel undertow's own queue notified whenever a job became queued
(steps 5 to 7; procrastinate announces queued jobs on its own channel)."""


@dataclass(frozen=True)
class Step:
    """One migration: `statements` for both databases (with `TYPES` placeholders), then
    those of one database alone (verbatim)."""

    version: int
    description: str
    statements: tuple[str, ...]
    sqlite: tuple[str, ...] = ()
    postgres: tuple[str, ...] = ()

    def sql(self, dialect: Dialect) -> tuple[str, ...]:
        """The statements of this step in `dialect`, in order."""
        shared = tuple(statement.format(**TYPES[dialect]) for statement in self.statements)
        return shared + (self.sqlite if dialect == "sqlite" else self.postgres)


STEPS: tuple[Step, ...] = (
    Step(1, "the jobs table (SQLite stores made before versioning have it already)", (
        """CREATE TABLE IF NOT EXISTS jobs (
            id               TEXT PRIMARY KEY,
            status           TEXT NOT NULL,
            scene            {json} NOT NULL,
            progress         {json},
            plan             {json},
            error            TEXT,
            cancel_requested {bool} NOT NULL DEFAULT {false},
            owner            TEXT NOT NULL,
            created          {real} NOT NULL,
            started          {real},
            finished         {real})""",
        "CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status)",
        "CREATE INDEX IF NOT EXISTS jobs_created ON jobs (created)",
    )),
    Step(2, "claims name their worker and hold a lease", (
        "ALTER TABLE jobs ADD COLUMN worker TEXT",
        "ALTER TABLE jobs ADD COLUMN lease_until {real}",
        "CREATE INDEX IF NOT EXISTS jobs_owner_status ON jobs (owner, status, created)",
    )),
    Step(3, "the NLP solution behind a plan, for warm starts (kept out of the plan's JSON)", (
        "ALTER TABLE jobs ADD COLUMN solution {json}",
    )),
    Step(4, "claims are counted; batches", (
        "ALTER TABLE jobs ADD COLUMN attempts INTEGER NOT NULL DEFAULT 0",
        "ALTER TABLE jobs ADD COLUMN batch TEXT",
        "ALTER TABLE jobs ADD COLUMN member INTEGER",
        "CREATE INDEX IF NOT EXISTS jobs_batch ON jobs (batch, member)",
        """CREATE TABLE IF NOT EXISTS batches (
            id      TEXT PRIMARY KEY,
            owner   TEXT NOT NULL,
            created {real} NOT NULL,
            spec    {json} NOT NULL)""",
    )),
    Step(5, "infrastructure failures counted apart, retried after a pause, dead letters, "
            "the claims' history, idempotency keys; PostgreSQL notifies queued jobs", (
        "ALTER TABLE jobs ADD COLUMN infra_failures INTEGER NOT NULL DEFAULT 0",
        "ALTER TABLE jobs ADD COLUMN dead_letter {bool} NOT NULL DEFAULT {false}",
        "ALTER TABLE jobs ADD COLUMN not_before {real}",
        "ALTER TABLE jobs ADD COLUMN lease {real}",
        "ALTER TABLE jobs ADD COLUMN history {json}",
        "ALTER TABLE jobs ADD COLUMN idem_key TEXT",
        "CREATE UNIQUE INDEX IF NOT EXISTS jobs_idem_key ON jobs (idem_key) "
        "WHERE idem_key IS NOT NULL",
    ), postgres=(
        f"""CREATE OR REPLACE FUNCTION undertow_job_queued() RETURNS trigger
            LANGUAGE plpgsql AS $$ BEGIN PERFORM pg_notify('{CHANNEL}', ''); RETURN NULL;
            END $$""",
        "CREATE TRIGGER undertow_job_queued AFTER INSERT OR UPDATE OF status ON jobs "
        "FOR EACH ROW WHEN (NEW.status = 'queued') EXECUTE FUNCTION undertow_job_queued()",
    )),
    Step(6, "the live solver workers, each supervisor's heartbeat", (
        """CREATE TABLE IF NOT EXISTS workers (
            name      TEXT PRIMARY KEY,
            processes INTEGER NOT NULL,
            busy      INTEGER NOT NULL,
            started   {real} NOT NULL,
            seen      {real} NOT NULL)""",
    )),
    Step(7, "undertow's own PostgreSQL queue removed: its NOTIFY of queued jobs, which "
            "nobody LISTENs to any more, goes (no table or row is dropped)", (), postgres=(
        "DROP TRIGGER IF EXISTS undertow_job_queued ON jobs",
        "DROP FUNCTION IF EXISTS undertow_job_queued()",
    )),
    Step(8, "what was decided about a job's scene when it was submitted (`app.admission`: "
            "the checks' findings, the earlier plan it starts from), so that its worker "
            "does not decide again; NULL in jobs stored before", (
        "ALTER TABLE jobs ADD COLUMN admission {json}",
    )),
    Step(9, "a plan's verdict and objective in columns of their own, which a batch's "
            "summary reads (the SQLite store compresses plans from this version on); "
            "filled from the stored plans of batch members, their only reader", (
        "ALTER TABLE jobs ADD COLUMN verified {bool}",
        "ALTER TABLE jobs ADD COLUMN objective {real}",
    ), sqlite=(
        "UPDATE jobs SET verified = json_extract(plan, '$.verification.verified'), "
        "objective = json_extract(plan, '$.objective') "
        "WHERE batch IS NOT NULL AND plan IS NOT NULL",
    ), postgres=(
        "UPDATE jobs SET verified = (plan->'verification'->>'verified')::boolean, "
        "objective = (plan->>'objective')::double precision "
        "WHERE batch IS NOT NULL AND plan IS NOT NULL",
    )),
    Step(10, "on PostgreSQL a node's liveness is its queue engine registration's heartbeat "
             "(`app.store.postgres_nodes`): its `workers` row names the registration and "
             "no longer needs a heartbeat of its own (nodes of earlier versions still "
             "write one)", (), postgres=(
        "ALTER TABLE workers ADD COLUMN engine_worker bigint",
        "ALTER TABLE workers ALTER COLUMN seen DROP NOT NULL",
    )),
    Step(11, "on PostgreSQL a job's status is derived from its queue engine job's "
             "(`app.store.postgres_status`) and no statement writes it: a new job starts "
             "queued by the column's default", (), postgres=(
        "ALTER TABLE jobs ALTER COLUMN status SET DEFAULT 'queued'",
    )),
)
SCHEMA_VERSION = STEPS[-1].version
"""The version of a database that has had every step."""


@dataclass(frozen=True)
class Ledger:
    """Where a database records its version: `setup` makes the place, `read` returns
    one row (version) or none (version 0), `write` (formatted with {version}) sets it."""

    setup: tuple[str, ...]
    read: str
    write: tuple[str, ...]


LEDGERS: dict[Dialect, Ledger] = {
    "sqlite": Ledger((), "PRAGMA user_version", ("PRAGMA user_version = {version}",)),
    "postgres": Ledger(
        ("CREATE TABLE IF NOT EXISTS undertow_schema (version integer NOT NULL)",),
        "SELECT version FROM undertow_schema",
        ("DELETE FROM undertow_schema", "INSERT INTO undertow_schema VALUES ({version})")),
}

Execute = Callable[[str], list[Any]]
"""Runs one statement on the store's connection and returns its rows ([] when none)."""


def version(execute: Execute, dialect: Dialect) -> int:
    """The version a database has recorded (0 before any step)."""
    rows = execute(LEDGERS[dialect].read)
    return rows[0][0] if rows else 0


def newer(where: str, found: int) -> NewerSchema:
    """The refusal of `where` (the store, as messages name it), whose recorded schema
    version `found` is newer than SCHEMA_VERSION."""
    return NewerSchema(
        f"{where} has schema version {found}, newer than version {SCHEMA_VERSION}, the "
        f"newest this version of undertow knows: a newer version of undertow migrated it. "
        f"Upgrade this node to that version before starting it (docs/deploy.md, "
        f"Upgrading a cluster); it does not start on a schema it does not know")


def migrate(execute: Execute, dialect: Dialect, upto: int = SCHEMA_VERSION,
            where: str = "the database") -> int:
    """Apply the steps after the database's version up to `upto` (in the caller's
    transaction) and record the new version; the version the database ends at.
    NewerSchema (`newer`, naming the store as `where`), before any change, when the
    database's version is newer than SCHEMA_VERSION."""
    ledger = LEDGERS[dialect]
    for statement in ledger.setup:
        execute(statement)
    start = version(execute, dialect)
    if start > SCHEMA_VERSION:
        raise newer(where, start)
    steps = [step for step in STEPS if start < step.version <= upto]
    for step in steps:
        for statement in step.sql(dialect):
            execute(statement)
    if not steps:
        return start
    for statement in ledger.write:
        execute(statement.format(version=steps[-1].version))
    return steps[-1].version
