"""The SQLite file a job store keeps using (stdlib sqlite3, WAL mode): its connections, and
the checks that it is still the file first opened.

Each thread of each process opens its own connection on first use. Connections open the
file read-write without creating it, and every statement first checks that the path still
names the file opened: a store deleted or replaced under a running service is reported as
unavailable instead of being silently recreated empty, and so is a write-ahead log deleted
or replaced (what the deleted one held is first moved into the database file, through the
connections that still have it open). A file overwritten in place (it no longer starts
with SQLite's header), or one SQLite reports damaged, is StoreDamaged
(`app.store.sqlite_integrity` checks the rest of the file).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from app.store.base import StoreDamaged, StoreUnavailable
from app.store.sqlite_locks import hold_shared, release

log = logging.getLogger("undertow.store")

HEADER = b"SQLite format 3\0"
"""The first 16 bytes of every SQLite database file."""
DAMAGED = (11, 26)
"""SQLite's primary result codes for a damaged file: SQLITE_CORRUPT, SQLITE_NOTADB."""
RESTART_OR_RESTORE = (
    "no new job is accepted. Stop the service and start it again: the start checks the "
    "store, and when it refuses it, restore the last backup (`undertow restore BACKUP`; "
    "docs/deploy.md, \"Backups\")")
"""What to do about a store found damaged while the service runs."""


def _identity(path: str) -> tuple[int, int] | None:
    """(device, inode) of the file at `path`; None when there is none."""
    try:
        stat = os.stat(path)
    except FileNotFoundError:
        return None
    return stat.st_dev, stat.st_ino


class SqliteFile:
    """The SQLite file at `path` (created with its directory if missing), each connection
    waiting up to `busy_timeout` seconds for a concurrent writer. Picklable: a copy in
    another process opens connections of its own to the same file.

    Its header is checked only once `check_header` is set (the store sets it once the
    file holds its schema: a new file is empty until then)."""

    def __init__(self, path: str | os.PathLike, busy_timeout: float = 30.0):
        self.path, self.busy_timeout = str(path), busy_timeout
        self.check_header = False
        self.failures = 0
        """Statements that failed so far in this process (`failure`)."""
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        sqlite3.connect(self.path).close()  # creates an empty file if there is none
        self._identity = _identity(self.path)
        self._local = threading.local()
        self._wal_state()

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "busy_timeout": self.busy_timeout,
                "identity": self._identity}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path, self.busy_timeout = state["path"], state["busy_timeout"]
        self._identity, self.check_header = state["identity"], True
        self.failures = 0
        self._local = threading.local()
        self._wal_state()

    def _wal_state(self) -> None:
        self._wal: tuple[int, tuple[int, int]] | None = None  # (pid, identity) first seen
        self._wal_lost = False
        self._wal_lock = threading.Lock()
        self._connections: list[sqlite3.Connection] = []
        self._header_fd: tuple[int, int] | None = None  # (pid, descriptor), never closed
        self._in_use = False  # whether the descriptor holds its shared lock

    @property
    def wal_path(self) -> str:
        return self.path + "-wal"

    def open(self) -> sqlite3.Connection:
        """A new connection to the file opened first (never creating one)."""
        if _identity(self.path) != self._identity:
            raise StoreUnavailable(f"the job store file {self.path} was deleted or replaced "
                                   "while the service ran; restart the service")
        self._verify_header()
        uri = Path(self.path).absolute().as_uri() + "?mode=rw"
        conn = sqlite3.connect(uri, uri=True, timeout=self.busy_timeout,
                               isolation_level=None, check_same_thread=False)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        return conn

    def _descriptor(self) -> int:
        """This process's own descriptor of the file, holding a shared flock(2) lock on it
        (`app.store.sqlite_locks`: the store is in use) while the store has connections.
        It is never closed: closing any descriptor of the file would drop the process's
        POSIX locks on it, and with them SQLite's knowledge that this process still uses
        the write-ahead log."""
        if self._header_fd is None or self._header_fd[0] != os.getpid():
            self._header_fd = (os.getpid(), os.open(self.path, os.O_RDONLY))
            self._in_use = False
        if not self._in_use:
            hold_shared(self._header_fd[1])
            self._in_use = True
        return self._header_fd[1]

    def header(self) -> bytes:
        """The first 16 bytes of the file (b"" while it is empty)."""
        try:
            with self._wal_lock:
                return os.pread(self._descriptor(), 16, 0)
        except OSError as exc:
            raise StoreUnavailable(f"the job store {self.path} cannot be read: {exc}") from exc

    def _verify_header(self) -> None:
        """StoreDamaged unless the file still starts with SQLite's header (it was not
        overwritten in place since the store was opened); marks the store in use."""
        if self.header() != HEADER and self.check_header:
            raise StoreDamaged(f"the job store file {self.path} was overwritten while the "
                               "service ran (it no longer starts with SQLite's header); "
                               f"{RESTART_OR_RESTORE}")

    def connection(self) -> sqlite3.Connection:
        """This thread's connection (a new one after a fork); every use checks that the
        path still names the file opened first, and that PATH-wal is still the
        write-ahead log this process first saw (SQLite deletes it only when the last
        connection closes, and this process keeps its connections open)."""
        local = self._local
        if getattr(local, "pid", None) != os.getpid():
            self._check_wal()
            local.conn, local.pid = self.open(), os.getpid()
            with self._wal_lock:
                self._connections.append(local.conn)
        elif _identity(self.path) != self._identity:
            self.open()  # raises StoreUnavailable
        else:
            self._check_wal()
        return local.conn

    def _check_wal(self) -> None:
        wal = _identity(self.wal_path)
        with self._wal_lock:
            if self._wal is None or self._wal[0] != os.getpid():
                if wal is not None:
                    self._wal = (os.getpid(), wal)
                return
            if wal == self._wal[1]:
                return
            first = not self._wal_lost
            self._wal_lost = True
        if first:
            self._salvage()
        raise StoreUnavailable(
            f"the job store's write-ahead log {self.wal_path} was deleted or replaced "
            "while the service ran; new jobs are refused until the service is restarted "
            "(what the log held was moved into the database file)")

    def _salvage(self) -> None:
        """Move what the deleted write-ahead log (still open in this process's
        connections) holds into the database file, so that the jobs accepted before it
        was deleted survive."""
        for conn in list(self._connections):
            try:
                busy, _, _ = conn.execute("PRAGMA wal_checkpoint(FULL)").fetchone()
            except sqlite3.Error as exc:
                log.error("the job store's write-ahead log could not be saved: %s", exc)
                continue
            if not busy:
                log.error("the job store's write-ahead log %s was deleted; what it held was "
                          "moved into %s", self.wal_path, self.path)
                return
        log.error("the job store's write-ahead log %s was deleted and could not be moved "
                  "into %s entirely", self.wal_path, self.path)

    def rows(self, sql: str, params: tuple | dict = (), fresh: bool = False) -> list[tuple]:
        """Every row of one statement (fetched at once, so a write is complete); `fresh`:
        through a new connection, whose pages come from the file and not from a cache."""
        try:
            if fresh:
                self.connection()  # the checks of the files
                with contextlib.closing(self.open()) as conn:
                    return conn.execute(sql, params).fetchall()
            rows = self.connection().execute(sql, params).fetchall()
            if self._wal is None:
                self._check_wal()  # the log this process writes to, once there is one
            return rows
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise self.failure(exc) from exc

    def failure(self, exc: sqlite3.Error) -> StoreUnavailable:
        """What a failed statement means for the service (counted in `failures`):
        StoreDamaged when SQLite found the file damaged, else StoreUnavailable."""
        self.failures += 1
        if getattr(exc, "sqlite_errorcode", 0) & 0xFF in DAMAGED:
            return StoreDamaged(f"the job store {self.path} is damaged ({exc}); "
                                f"{RESTART_OR_RESTORE}")
        return StoreUnavailable(f"the job store {self.path} failed: {exc}")

    @contextlib.contextmanager
    def transaction(self, fresh: bool = False) -> Iterator[sqlite3.Connection]:
        """This thread's connection (`fresh`: a new one) inside BEGIN IMMEDIATE ... COMMIT
        (ROLLBACK on error)."""
        try:
            conn = self.connection()
            if fresh:
                conn = self.open()
            try:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    yield conn
                except BaseException:
                    conn.execute("ROLLBACK")
                    raise
                conn.execute("COMMIT")
            finally:
                if fresh:
                    conn.close()
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise self.failure(exc) from exc

    def close(self) -> None:
        """Close this thread's connection (the write-ahead log may go with the last one)."""
        conn = getattr(self._local, "conn", None)
        if conn is not None and self._local.pid == os.getpid():
            conn.close()
            with self._wal_lock:
                if conn in self._connections:
                    self._connections.remove(conn)
                if not self._connections:  # the log may go with the last connection
                    self._wal = None
                    if self._in_use and self._header_fd is not None:
                        release(self._header_fd[1])
                        self._in_use = False
        self._local = threading.local()
