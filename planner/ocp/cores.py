"""The machine's cores as tokens that every plan on it shares: a plan forks its companion
process only onto a core that no other plan is using.

Each core is a lock file in one directory of the user (`UNDERTOW_CORE_DIR`, default
`<tempdir>/undertow-cores-<uid>`). A plan takes a free token for its own process when there
is one, and its companion needs one more; a plan that finds none runs alone. Tokens are
`flock` locks, which the kernel drops when the process holding them ends, so a killed plan
never keeps a core. A forked child (a plan's companion) closes the tokens it inherits: a
core is held by the plan that took it, which gives it back when it returns, not by a killed
companion still releasing its memory. Two solver workers of the service on two cores thus
give a lone plan both cores, and each of two concurrent plans one.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from pathlib import Path

DIRECTORY = "UNDERTOW_CORE_DIR"


def directory() -> Path:
    """Where the tokens are (`UNDERTOW_CORE_DIR`, else a directory of the user's in the
    temporary directory)."""
    configured = os.environ.get(DIRECTORY, "").strip()
    if configured:
        return Path(configured)
    return Path(tempfile.gettempdir()) / f"undertow-cores-{os.getuid()}"


_HELD: set[int] = set()
"""The descriptors of the tokens this process holds."""


def _close_inherited() -> None:
    """In a forked child: close the tokens' descriptors it inherited (the lock stays its
    parent's)."""
    for fd in _HELD:
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD.clear()


os.register_at_fork(after_in_child=_close_inherited)


class Token:
    """One core, held until `release` (or the holder's death)."""

    def __init__(self, fd: int, index: int):
        self.fd, self.index = fd, index
        _HELD.add(fd)

    def release(self) -> None:
        """Give the core back."""
        if self.fd in _HELD:
            _HELD.discard(self.fd)
            with contextlib.suppress(OSError):
                os.close(self.fd)


def available() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0))


def take(count: int | None = None) -> Token | None:
    """A free token of the machine's `count` cores (default: `available()`), or None when
    every one is held. Never blocks."""
    folder = directory()
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    for index in range(count or available()):
        fd = os.open(folder / f"core-{index}.lock", os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        return Token(fd, index)
    return None


def release(*tokens: Token | None) -> None:
    """Give back every token given (None: none was taken)."""
    for token in tokens:
        if token is not None:
            token.release()
