"""The job store a process's settings name: PostgreSQL at UNDERTOW_DB_URL when it is set
(its jobs queued by procrastinate), else the SQLite file at UNDERTOW_DB_PATH (its jobs
queued by its own statements)."""

from __future__ import annotations

from app.settings import Settings
from app.store.base import JobStore, RetryPolicy
from app.store.sqlite import SqliteJobStore


def open_store(settings: Settings) -> JobStore:
    """The configured store, opened and migrated (StoreDamaged, StoreUnavailable), with
    the settings' retry policy."""
    policy = RetryPolicy(settings.max_retries, settings.retry_backoff,
                         settings.retry_max_backoff)
    if settings.db_url:
        from app.store.postgres import PostgresJobStore  # psycopg only where it is used

        return PostgresJobStore(settings.db_url, policy=policy, lease=settings.lease)
    return SqliteJobStore(settings.db_path, policy=policy,
                          integrity_interval=settings.integrity_interval)
