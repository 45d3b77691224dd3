"""Who holds an SQLite job store, told by flock(2) locks on files of the one host the store
lives on (the SQLite store is never shared between hosts):

- a server's name: a server holds `PATH-server-NAME.lock` exclusively while it runs, so a
  second server of the same name on the same store is refused before it touches a job
  (it would take the first one's running jobs for its own, left behind by a stopped
  server, and requeue them);
- the store itself: every process that uses the store holds a shared lock on its
  database file (`SqliteFile`), so that `undertow restore` refuses to replace a store in
  use. SQLite's own locks are fcntl(2) locks, which flock(2) locks do not meet.

A flock lock belongs to its open file description: a process that ends, killed or not,
holds none.
"""

from __future__ import annotations

import fcntl
import os
import re
import time
import zlib

from app.store.base import NameTaken


def _slug(name: str) -> str:
    """`name` as part of a file name: its letters, digits and `._-` (others become `_`),
    with a checksum of the name when any was replaced."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", name)[:64]
    return safe if safe == name else f"{safe}-{zlib.crc32(name.encode()):08x}"


def name_path(path: str, name: str) -> str:
    """The lock file of server name `name` on the store at `path`."""
    return f"{path}-server-{_slug(name)}.lock"


class NameLock:
    """Server name `name` held on the store at `path` by this process (NameTaken when
    another process holds it)."""

    def __init__(self, path: str, name: str):
        self.path = name_path(path, name)
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._fd, 200, 0).decode(errors="replace").strip()
            self.release()
            raise NameTaken(
                f"another server named {name!r} runs on the job store {path} "
                f"({holder or 'a live process'}): a second server of that name would take "
                "its running jobs for its own. Stop that server first, or give this one "
                "another name (UNDERTOW_INSTANCE)") from None
        os.ftruncate(self._fd, 0)
        started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        os.pwrite(self._fd, f"process {os.getpid()}, since {started}\n".encode(), 0)

    def release(self) -> None:
        """Give the name back."""
        if self._fd is not None:
            os.close(self._fd)  # the lock ends with its file description
            self._fd = None


def hold_shared(fd: int) -> None:
    """A shared lock on the store's database file `fd` (the store is in use)."""
    fcntl.flock(fd, fcntl.LOCK_SH)


def release(fd: int) -> None:
    """End this description's lock (the descriptor stays open)."""
    fcntl.flock(fd, fcntl.LOCK_UN)


def unused(fd: int) -> bool:
    """Whether no process uses the store whose database file `fd` is: an exclusive lock
    on it, held until `fd` is closed; False when some process holds a shared one."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True
