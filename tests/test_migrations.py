"""The job store's one list of migrations (`app.store.migrations`): a fresh SQLite file and a
fresh PostgreSQL database end at the same version with the same tables, columns and
indexes, a database left at any older version upgrades to the latest keeping its rows,
and one whose ledger records a version newer than the code knows is refused, left as it
is, by the store and by the API server and the worker node that would open it (one log
line, no traceback, a non-zero exit)."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, closing, contextmanager
from pathlib import Path

import psycopg
import pytest

from app.store import JobStore, NewerSchema, SqliteJobStore
from app.store.migrations import (
    DIALECTS,
    LEDGERS,
    SCHEMA_VERSION,
    STEPS,
    Dialect,
    migrate,
    version,
)
from app.store.postgres import PostgresJobStore
from app.store.postgres_sql import _execute as pg_execute
from app.worker_node import REFUSED
from testbed.cluster import WorkerNode
from testbed.service import LiveServer

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
    """Alike but for the node's liveness, which PostgreSQL keeps in the queue engine's
    registration (step 10): its `workers` rows name it and need no heartbeat of their own."""
    schemas = {}
    for dialect in DIALECTS:
        with database(dialect, tmp_path, postgres_url) as (execute, open_store):
            open_store().close()
            schemas[dialect] = (version(execute, dialect), columns(execute, dialect),
                                indexes(execute, dialect))
    workers = schemas["postgres"][1]["workers"]
    assert workers[-2:] == [("seen", False), ("engine_worker", False)]
    schemas["postgres"][1]["workers"] = workers[:-2] + [("seen", True)]
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
        figures = (", verified, objective", ", (1 = 1), 1.5") if older >= 9 else ("", "")
        execute(f"INSERT INTO jobs (id, status, scene, plan, owner, created, batch, member"
                f"{figures[0]}) VALUES ('member', 'succeeded', '{{}}', '{{\"objective\": 1.5, "
                f"\"verification\": {{\"verified\": true}}}}', 'host', 1.0, 'b', 0"
                f"{figures[1]})")
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


def refusal(where: str) -> str:
    """The exact refusal of a store named `where` whose ledger records SCHEMA_VERSION + 1."""
    return (f"{where} has schema version {SCHEMA_VERSION + 1}, newer than version "
            f"{SCHEMA_VERSION}, the newest this version of undertow knows: a newer version "
            "of undertow migrated it. Upgrade this node to that version before starting it "
            "(docs/deploy.md, Upgrading a cluster); it does not start on a schema it does "
            "not know")


def newer_is_refused(dialect: Dialect, where: str, execute: Execute,
                     open_store: Callable[[], JobStore]) -> None:
    """A database at the latest version with a job, its ledger then set one version ahead
    (as a newer version that added a step would leave it): the store refuses it with
    `refusal(where)` and changes nothing; at the current version again, it opens."""
    def record(number: int) -> None:
        for statement in LEDGERS[dialect].write:
            execute(statement.format(version=number))

    migrate(execute, dialect)
    execute("INSERT INTO jobs (id, status, scene, owner, created) "
            "VALUES ('kept', 'queued', '{}', 'host', 1.0)")
    record(SCHEMA_VERSION + 1)
    with pytest.raises(NewerSchema) as refused:
        open_store()
    assert str(refused.value) == refusal(where)
    assert version(execute, dialect) == SCHEMA_VERSION + 1  # left as it was
    record(SCHEMA_VERSION)
    store = open_store()
    try:
        assert store.schema_version == SCHEMA_VERSION  # type: ignore[attr-defined]
        assert store.get("kept").status == "queued"  # type: ignore[union-attr]
    finally:
        store.close()


def test_a_sqlite_file_of_a_newer_schema_is_refused(tmp_path):
    with sqlite_file(tmp_path) as (execute, open_store):
        newer_is_refused("sqlite", f"the job store {tmp_path / 'db.sqlite3'}", execute,
                         open_store)


def postgres_where(url: str) -> str:
    """How the store at `url` is named in messages."""
    info = psycopg.conninfo.conninfo_to_dict(url)
    return f"the job store (PostgreSQL {info['host']}:{info['port']}/{info['dbname']})"


def test_a_postgres_database_of_a_newer_schema_is_refused(postgres_url):
    with postgres_database(postgres_url) as (execute, open_store):
        newer_is_refused("postgres", postgres_where(postgres_url), execute, open_store)


def neither_role_starts(folder: Path, where: str, **store: str) -> None:
    """An API server and a worker node on the store that `store` (UNDERTOW_* variables)
    names, whose ledger records SCHEMA_VERSION + 1: both exit non-zero, logging
    `refusal(where)` and no traceback."""
    server = LiveServer(folder / "api.sqlite3", **store)  # the store of `store`
    assert server.refused() != 0
    node = WorkerNode(folder, "node", **store).start()
    assert node.proc is not None and node.proc.wait(60) == REFUSED
    for log in (server.log, node.log):
        said = log.read_text()
        assert refusal(where) in said and "Traceback" not in said, said


def test_neither_role_starts_on_a_sqlite_file_of_a_newer_schema(tmp_path):
    db = tmp_path / "jobs.sqlite3"
    SqliteJobStore(db).close()
    with closing(sqlite3.connect(db)) as conn:
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    neither_role_starts(tmp_path, f"the job store {db}", UNDERTOW_DB_PATH=str(db))


def test_neither_role_starts_on_a_postgres_database_of_a_newer_schema(tmp_path, postgres_url):
    PostgresJobStore(postgres_url).close()
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("UPDATE undertow_schema SET version = %s", (SCHEMA_VERSION + 1,))
    neither_role_starts(tmp_path, postgres_where(postgres_url), UNDERTOW_DB_URL=postgres_url)
