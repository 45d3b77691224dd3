"""Backups of the SQLite job store, and their restore (`undertow backup PATH`,
`undertow restore PATH`).

A backup is SQLite's `VACUUM INTO`: one read transaction, so it may run while servers and
workers use the store, and the copy is the store as one moment left it, without its free
pages. The copy must pass `PRAGMA integrity_check` before it takes the place of any
earlier file at PATH (it is written beside it first, then renamed), so a damaged store
never overwrites a good backup.

A restore puts a checked backup in the store's place. It refuses while any process uses
the store (each holds a shared lock on its file: `app.store.sqlite_locks`), moves the
store's files (the database, its -wal and -shm) aside under a name with the time, and
copies the backup in (beside the store first, then renamed). The next start runs the
jobs the backup held: queued ones run, running ones are requeued as infrastructure
failures; the jobs accepted after the backup are only in the files moved aside.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from app.store.sqlite_file import DAMAGED
from app.store.sqlite_locks import unused

SIDE_FILES = ("", "-wal", "-shm")
"""The store's files: the database, its write-ahead log and the log's index."""


class BackupFailed(Exception):
    """A backup or restore that could not be done; the message says why and what to do."""


@dataclass(frozen=True)
class Copy:
    """A copy of the store that passed its integrity check: where, its size [bytes], its
    jobs and the files moved aside to make room for it (a restore's)."""

    path: str
    size: int
    jobs: int
    aside: tuple[str, ...] = ()


def _checked(path: str) -> Copy:
    """The file at `path` as a checked copy of a store (BackupFailed unless it passes
    `PRAGMA integrity_check` and holds a jobs table). The file alone is read, never a
    write-ahead log beside it: what is checked is what a restore copies."""
    try:
        uri = Path(path).absolute().as_uri() + "?mode=ro&immutable=1"  # the file alone
        with contextlib.closing(sqlite3.connect(uri, uri=True)) as conn:
            findings = [row[0] for row in conn.execute("PRAGMA integrity_check")]
            if findings != ["ok"]:
                raise BackupFailed(f"{path} failed its integrity check: "
                                   f"{'; '.join(findings[:5])}")
            (jobs,) = conn.execute("SELECT COUNT(*) FROM jobs").fetchone()
    except sqlite3.Error as exc:
        if _damaged(exc):
            raise BackupFailed(f"{path} failed its integrity check: {exc}") from exc
        raise BackupFailed(f"{path} is not a job store that can be read: {exc}") from exc
    return Copy(path, os.path.getsize(path), jobs)


def _damaged(exc: sqlite3.Error) -> bool:
    """Whether SQLite failed because the file is damaged."""
    return getattr(exc, "sqlite_errorcode", 0) & 0xFF in DAMAGED


def _durable(path: str) -> None:
    """Flush the file at `path`, then its directory (a rename into it is then durable)."""
    for name, flags in ((path, os.O_RDONLY), (os.path.dirname(path) or ".", os.O_RDONLY)):
        fd = os.open(name, flags)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def backup(store: str, target: str) -> Copy:
    """Copy the store at `store` to `target` (replacing a file there only once the copy
    passed its check)."""
    if not os.path.exists(store):
        raise BackupFailed(f"there is no job store at {store} (UNDERTOW_DB_PATH)")
    partial = f"{target}.partial"
    Path(target).parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        os.unlink(partial)
    try:
        with contextlib.closing(sqlite3.connect(store, timeout=30.0)) as conn:
            conn.execute("VACUUM INTO ?", (partial,))
    except sqlite3.Error as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(partial)
        raise BackupFailed(f"the job store {store} could not be copied: {exc}" + (
            "; it is damaged: keep the backups you have" if _damaged(exc) else "")) from exc
    try:
        copy = _checked(partial)
    except BackupFailed:
        os.unlink(partial)
        raise
    _durable(partial)
    os.replace(partial, target)
    _durable(target)
    return Copy(target, copy.size, copy.jobs)


def restore(source: str, store: str) -> Copy:
    """Put the backup at `source` in the place of the store at `store`, whose files are
    moved aside (BackupFailed, touching nothing, while a process uses the store or when
    the backup fails its check)."""
    _checked(source)
    Path(store).parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(store, os.O_RDONLY | os.O_CREAT, 0o644)
    try:
        if not unused(fd):
            raise BackupFailed(f"the job store {store} is in use: stop the servers and worker "
                               "nodes that use it, then restore")
        partial = f"{store}.partial"
        shutil.copyfile(source, partial)
        _durable(partial)
        aside = _move_aside(store)
        os.replace(partial, store)
        _durable(store)
    finally:
        os.close(fd)
    return Copy(store, os.path.getsize(store), _checked(store).jobs, aside)


def _move_aside(store: str) -> tuple[str, ...]:
    """Rename the store's files that hold anything to STORE.before-restore-TIME (with
    their suffixes), delete the empty ones; the new names."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = []
    for suffix in SIDE_FILES:
        path = store + suffix
        if not os.path.exists(path):
            continue
        if os.path.getsize(path) == 0:
            os.unlink(path)
            continue
        aside.append(f"{store}.before-restore-{stamp}{suffix}")
        os.replace(path, aside[-1])
    return tuple(aside)
