"""The integrity of an SQLite job store's file, by SQLite's own checks: at start-up, on a
cadence, and before a job is accepted, so that no job is accepted into a damaged store.

- At start-up `PRAGMA integrity_check` (every page, every index against its table) must
  pass, else the store is refused (StoreDamaged, saying how to restore a backup). A file
  whose first page (SQLite's header) was overwritten while the write-ahead log still held
  that page passes it, since SQLite reads the page from the log: the page is then written
  back into the file (a checkpoint) and the file checked again.
- While the service runs, `verify` runs `PRAGMA quick_check` (every page, no index
  against its table) whenever the file changed since the last check passed, or a
  statement failed since: SQLite writes the database file only when it checkpoints the
  write-ahead log, so between two checkpoints a passed check stands, and a file
  overwritten in place shows as changed (its size, modification or change time). Every
  `interval` seconds `verify` runs the full `integrity_check` instead, changed or not.
- A store found damaged stays damaged for this process: every `verify` raises until the
  service restarts, and the start checks it again.

Both checks read the whole file: about 1 ms per MB of it, measured on stores of 300 and
1000 finished plan jobs (docs/deploy.md, "Store size and retention"), so a store bounded
by UNDERTOW_RETENTION_MB is checked within about a second per GB.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import NoReturn

from app.store.base import StoreDamaged, StoreUnavailable
from app.store.sqlite_file import HEADER, RESTART_OR_RESTORE, SqliteFile

log = logging.getLogger("undertow.store")

Stamp = tuple[int, int, int, int, int]
"""(inode, size, modification time, change time [ns], failed statements) of the file."""


def refused(path: str, finding: str) -> str:
    """Why the service refuses to start on the store at `path`, and what to do."""
    return (f"the job store {path} failed its integrity check ({finding}); refusing to start "
            "on it. Restore the last backup: `undertow restore BACKUP` moves the damaged file "
            "aside (with its -wal and -shm files, for `sqlite3 FILE .recover`) and puts the "
            "backup in its place; then start again (docs/deploy.md, \"Backups\"). Without a "
            "backup, move the files aside yourself to start with an empty store")


class Integrity:
    """The integrity verdict of this process on `file`, with a full check every
    `interval` seconds."""

    def __init__(self, file: SqliteFile, interval: float = 300.0):
        self.file, self.interval = file, interval
        self._lock = threading.Lock()
        self._passed: Stamp | None = None
        self._damage: str | None = None
        self._next_full = time.monotonic() + interval

    def _stamp(self) -> Stamp | None:
        try:
            stat = os.stat(self.file.path)
        except FileNotFoundError:
            return None
        return (stat.st_ino, stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns,
                self.file.failures)

    def _findings(self, pragma: str) -> list[str]:
        """What `PRAGMA pragma` found, through a new connection (whose pages come from
        the file and the log, not from a cache): ["ok"] when nothing is wrong."""
        return [" ".join(str(row[0]).split()) for row in
                self.file.rows(f"PRAGMA {pragma}", fresh=True)]

    def at_start(self) -> None:
        """StoreDamaged (saying what to do) unless the file passes integrity_check,
        with SQLite's header in the file (written back from the log if need be)."""
        try:
            findings = self._findings("integrity_check")
            if findings == ["ok"] and self.file.header() not in (HEADER, b""):
                findings = self._rewrite_header()
        except StoreUnavailable as exc:
            raise StoreDamaged(refused(self.file.path, str(exc.__cause__ or exc))) from exc
        if findings != ["ok"]:
            raise StoreDamaged(refused(self.file.path, "; ".join(findings[:5])))
        self._passed = self._stamp()

    def _rewrite_header(self) -> list[str]:
        """Write the first page back from the write-ahead log (a full checkpoint), then
        check the file again; the findings."""
        busy, _, _ = self.file.rows("PRAGMA wal_checkpoint(TRUNCATE)")[0]
        if busy or self.file.header() != HEADER:
            return ["its first page, with SQLite's header, was overwritten and could not be "
                    "written back from the write-ahead log"]
        findings = self._findings("integrity_check")
        if findings == ["ok"]:
            log.warning("the job store %s had its first page overwritten; it was written back "
                        "from the write-ahead log, which held it, and the store passed its "
                        "integrity check", self.file.path)
        return findings

    def verify(self) -> None:
        """StoreDamaged when the store was found damaged, now or before in this process:
        quick_check when the file changed since the last check passed, integrity_check
        when one is due (StoreUnavailable when the file cannot be checked at all)."""
        with self._lock:
            if self._damage is not None:
                raise StoreDamaged(self._damage)
            now, stamp = time.monotonic(), self._stamp()
            full = now >= self._next_full
            if stamp == self._passed and not full:
                return
            try:
                findings = self._findings("integrity_check" if full else "quick_check")
            except StoreDamaged as exc:
                self._damaged(str(exc))
            if findings != ["ok"]:
                self._damaged(f"the job store {self.file.path} failed its integrity check "
                              f"while the service ran ({'; '.join(findings[:5])}); "
                              f"{RESTART_OR_RESTORE}")
            self._passed = stamp
            if full:
                self._next_full = now + self.interval

    def _damaged(self, why: str) -> NoReturn:
        """Hold the store damaged for good (logged once) and raise StoreDamaged."""
        self._damage = why
        log.critical("%s", why)
        raise StoreDamaged(why)
