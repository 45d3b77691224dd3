"""Job stores: the `JobStore` interface, its SQLite implementation (the default) and its
PostgreSQL one (`app.store.postgres`, imported where `app.store.open` chooses it)."""

from app.store.base import (
    BUILDING,
    CANCELLED_ON_REQUEST,
    DEAD_LETTER,
    FINAL,
    INTERRUPTED,
    STATUSES,
    BatchRecord,
    DuplicateKey,
    Held,
    JobRecord,
    JobStatus,
    JobStore,
    Listener,
    MemberRecord,
    NameTaken,
    NewerSchema,
    Retention,
    RetryPolicy,
    StoreDamaged,
    StoreUnavailable,
    WorkerRecord,
)
from app.store.sqlite import SqliteJobStore

__all__ = ["BUILDING", "CANCELLED_ON_REQUEST", "DEAD_LETTER", "FINAL", "INTERRUPTED",
           "STATUSES", "BatchRecord", "DuplicateKey", "Held", "JobRecord", "JobStatus",
           "JobStore", "Listener", "MemberRecord", "NameTaken", "NewerSchema", "Retention",
           "RetryPolicy", "SqliteJobStore", "StoreDamaged", "StoreUnavailable", "WorkerRecord"]
