"""Job stores: the `JobStore` interface and its SQLite implementation."""

from app.store.base import (
    BUILDING,
    FINAL,
    INTERRUPTED,
    STATUSES,
    JobRecord,
    JobStatus,
    JobStore,
    StoreDamaged,
    StoreUnavailable,
)
from app.store.sqlite import SqliteJobStore

__all__ = ["BUILDING", "FINAL", "INTERRUPTED", "STATUSES", "JobRecord", "JobStatus", "JobStore",
           "SqliteJobStore", "StoreDamaged", "StoreUnavailable"]
