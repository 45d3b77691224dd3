"""The job store's one list of migrations (`app.store.migrations`): a fresh SQLite file and a
fresh PostgreSQL database end at the same version with the same tables, columns and
indexes, and a database left at any older version upgrades to the latest keeping its
rows."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, closing, contextmanager
from pathlib import Path

import psycopg
import pytest

from app.store import JobStore, SqliteJobStore
from app.store.migrations import DIALECTS, SCHEMA_VERSION, STEPS, Dialect, migrate, version
from app.store.postgres import PostgresJobStore
from app.store.postgres_sql import _execute as pg_execute

Execute = Callable[[str], list]
Columns = dict[str, list[tuple[str, bool]]]
"""Each table's columns in order: (name, NOT NULL; a primary key counts as NOT NULL)."""
MIGRATED = "table_name NOT LIKE 'procrastinate%' AND table_name <> 'undertow_queue'"
"""The PostgreSQL tables of the migrations: not the queue's, which the store installs
beside them (procrastinate's and the link table, `app.store.postgres`)."""


@contextmanager
def sqlite_file(tmp_path: Path) -> Iterator[tuple[Execute, Callable[[], JobStore]]]:
    """A new empty SQLite file through a plain connection (autocommit), and how to open
    the store on it."""
    path = tmp_path / "db.sqlite3"
    with closing(sqlite3.connect(path, isolation_level=None)) as conn:
        yield (lambda sql: conn.execute(sql).fetchall()), lambda: SqliteJobStore(path)


@contextmanager
def postgres_database(url: str) -> Iterator[tuple[Execute, Callable[[], JobStore]]]:
    """The same for a new empty PostgreSQL database at `url`."""
    with psycopg.connect(url, autocommit=True) as conn:
        yield (lambda sql: pg_execute(conn, sql)), lambda: PostgresJobStore(url)


def database(dialect: Dialect, tmp_path: Path, url: str
             ) -> AbstractContextManager[tuple[Execute, Callable[[], JobStore]]]:
    """A new empty database of `dialect`, as the two functions above give it."""
    return sqlite_file(tmp_path) if dialect == "sqlite" else postgres_database(url)


def columns(execute: Execute, dialect: Dialect) -> Columns:
    """The columns of every table of the migrations but the version ledger."""
    if dialect == "sqlite":
        tables = [name for (name,) in execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' "
            "AND name NOT LIKE 'sqlite_%' ORDER BY name")]
        return {table: [(name, bool(notnull or pk)) for _, name, _, notnull, _, pk
                        in execute(f"PRAGMA table_info({table})")] for table in tables}
    found: Columns = {}
    for table, name, nullable in execute(
            "SELECT table_name, column_name, is_nullable FROM information_schema.columns "
            "WHERE table_schema = 'public' AND table_name <> 'undertow_schema' "
            f"AND {MIGRATED} ORDER BY table_name, ordinal_position"):
        found.setdefault(table, []).append((name, nullable == "NO"))
    return found


def indexes(execute: Execute, dialect: Dialect) -> set[str]:
    """The names of the indexes the migrations created (not those of primary keys)."""
    if dialect == "sqlite":
        return {name for (name,) in execute("SELECT name FROM sqlite_master WHERE type = "
                                            "'index' AND name NOT LIKE 'sqlite_%'")}
    return {name for (name,) in execute(
        "SELECT indexname FROM pg_indexes WHERE schemaname = 'public' AND indexname NOT LIKE "
        f"'%_pkey' AND {MIGRATED.replace('table_name', 'tablename')}")}


def test_the_steps_are_numbered_one_by_one():
    assert [step.version for step in STEPS] == list(range(1, SCHEMA_VERSION + 1))
    assert all(step.description and step.sql("sqlite") + step.sql("postgres")
               for step in STEPS)


def test_fresh_databases_of_both_kinds_end_alike(tmp_path, postgres_url):
    schemas = {}
    for dialect in DIALECTS:
        with database(dialect, tmp_path, postgres_url) as (execute, open_store):
            open_store().close()
            schemas[dialect] = (version(execute, dialect), columns(execute, dialect),
                                indexes(execute, dialect))
    assert schemas["sqlite"] == schemas["postgres"]
    latest, tables, names = schemas["sqlite"]
    assert latest == SCHEMA_VERSION
    assert sorted(tables) == ["batches", "jobs", "workers"]
    assert names == {"jobs_status", "jobs_created", "jobs_owner_status", "jobs_batch",
                     "jobs_idem_key"}


def upgrades_keeping_its_rows(dialect: Dialect, older: int, execute: Execute,
                              open_store: Callable[[], JobStore]) -> None:
    """Bring an empty database to version `older`, store a job (and from version 4 a
    batch) the way that version could, then open the store: it ends at the latest version
    with the rows as they were, and the latest columns work."""
    assert migrate(execute, dialect, upto=older) == older
    assert version(execute, dialect) == older
    execute("INSERT INTO jobs (id, status, scene, progress, plan, error, owner, created, "
            "started, finished) VALUES ('old', 'succeeded', '{\"note\": 1}', NULL, "
            "'{\"objective\": 2.5}', NULL, 'host', 1.0, 2.0, 3.0)")
    if older >= 4:
        execute("INSERT INTO batches (id, owner, created, spec) "
                "VALUES ('b', 'host', 1.0, '{\"parameters\": []}')")
        execute("INSERT INTO jobs (id, status, scene, plan, owner, created, batch, member) "
                "VALUES ('member', 'succeeded', '{}', '{\"objective\": 1.5, "
                "\"verification\": {\"verified\": true}}', 'host', 1.0, 'b', 0)")
    store = open_store()
    try:
        assert store.schema_version == SCHEMA_VERSION  # type: ignore[attr-defined]
        old = store.get("old")
        assert old is not None
        assert (old.status, old.scene, old.plan, old.created, old.finished) == (
            "succeeded", {"note": 1}, {"objective": 2.5}, 1.0, 3.0)
        assert (old.attempts, old.infra_failures, old.dead_letter, old.history) == (
            0, 0, False, None)
        if older >= 4:  # the summary's figures, from the plan's own columns since 9
            batch = store.get_batch("b")
            assert batch is not None
            assert [(m.job_id, m.verified, m.objective) for m in batch.members] == [
                ("member", True, 1.5)]
        assert old.admission is None  # its worker decides, as that version's did
        store.create("new", {"x": 1}, "host", key="k", admission={"issues": []})
        assert store.find_key("k") == "new"  # the latest columns are there
        assert store.get("new").admission == {"issues": []}  # type: ignore[union-attr]
    finally:
        store.close()
    assert version(execute, dialect) == SCHEMA_VERSION


@pytest.mark.parametrize("older", range(1, SCHEMA_VERSION))
def test_a_sqlite_file_at_an_older_version_upgrades_keeping_its_rows(older, tmp_path):
    with sqlite_file(tmp_path) as (execute, open_store):
        upgrades_keeping_its_rows("sqlite", older, execute, open_store)


@pytest.mark.parametrize("older", range(1, SCHEMA_VERSION))
def test_a_postgres_database_at_an_older_version_upgrades_keeping_its_rows(older,
                                                                           postgres_url):
    with postgres_database(postgres_url) as (execute, open_store):
        upgrades_keeping_its_rows("postgres", older, execute, open_store)
