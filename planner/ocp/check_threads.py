"""The process's threads for a plan's checks.

A plan's replays run beside its other checks in threads of their own
(`planner.ocp.verify`); the threads are kept for the process's later plans rather than
started and joined for each one. A forked child (a plan's companion) has only the thread
that forked: it starts threads of its own.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

WORKERS = 8
"""At most this many checking threads: two per plan whose checks run at once in the process
(a server's replanning sessions); a plan alone keeps two busy."""

_POOL: ThreadPoolExecutor | None = None
_GUARD = threading.Lock()  # guards _POOL


def pool() -> ThreadPoolExecutor:
    """The process's pool of checking threads, started on first use."""
    global _POOL
    with _GUARD:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="checks")
        return _POOL


def _forked() -> None:
    """In a forked child: no pool yet (the parent's threads are not in the child)."""
    global _POOL, _GUARD
    _POOL, _GUARD = None, threading.Lock()


os.register_at_fork(after_in_child=_forked)
