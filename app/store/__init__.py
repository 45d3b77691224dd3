"""Job stores: the `JobStore` interface and its SQLite implementation."""

from app.store.base import FINAL, INTERRUPTED, STATUSES, JobRecord, JobStatus, JobStore
from app.store.sqlite import SqliteJobStore

__all__ = ["FINAL", "INTERRUPTED", "STATUSES", "JobRecord", "JobStatus", "JobStore",
           "SqliteJobStore"]
