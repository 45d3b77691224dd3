"""A live server's solver worker processes, watched from outside: which started, which
ended while the server ran, and what its supervisor logged about them.

A worker is a child process of the server started by multiprocessing's spawn
(`app.supervisor`); a watch thread lists the server's children every `POLL` seconds from
/proc. A worker that ended was either stopped by its supervisor (a job past its budget, a
cancel its solver ignored: a log line each) or died (killed, a crash, out of memory, or
it left after a job ran out of memory): `dead` counts those.
"""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

from app.supervisor import CANCELLED_STOPPED, WORKER_DIED

POLL = 0.1  # [s] between two looks at the server's children
SPAWNED = "multiprocessing.spawn"  # in the command line of a worker process
STOPPED = ("its worker process was stopped", CANCELLED_STOPPED)
"""What the supervisor logs when it stops a worker (a job past its budget, an ignored
cancel)."""
STARTUP = "exited during start-up"


def children(parent: int) -> dict[tuple[int, int], str]:
    """The children of process `parent`: (pid, start time in clock ticks) -> command line."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            if int(fields[1]) != parent:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                command = f.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
        found[(int(entry), int(fields[19]))] = command
    return found


def workers_of(parent: int) -> set[tuple[int, int]]:
    """The worker processes (pid, start time) of the server process `parent` now."""
    return {key for key, command in children(parent).items() if SPAWNED in command
            and "spawn_main" in command}


@dataclass
class WorkerWatch:
    """Watches the worker processes of the server process `pid` from `start` to `stop`."""

    pid: int
    seen: set[tuple[int, int]] = field(default_factory=set)
    ended: set[tuple[int, int]] = field(default_factory=set)
    _halt: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def _look(self) -> None:
        now = workers_of(self.pid)
        self.ended |= self.seen - now
        self.seen |= now

    def _run(self) -> None:
        while not self._halt.wait(POLL):
            self._look()

    def start(self) -> WorkerWatch:
        self._look()
        self._thread = threading.Thread(target=self._run, name="worker-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop watching (before the server stops: its workers leave then)."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join()
        self._look()


def supervisor_lines(log: Path) -> dict[str, int]:
    """Counts of what the server's log (JSON lines) says: `stopped` workers (by their
    supervisor), `died` (a job's worker died), `startup` (a worker that ended before it was
    ready), `errors` (lines of level ERROR or above)."""
    counts = dict.fromkeys(("stopped", "died", "startup", "errors"), 0)
    for line in log.read_text(errors="replace").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        message = str(entry.get("message", ""))
        counts["stopped"] += any(text in message for text in STOPPED)
        counts["died"] += WORKER_DIED in message
        counts["startup"] += STARTUP in message
        counts["errors"] += entry.get("level") in ("ERROR", "CRITICAL")
    return counts


def dead(watch: WorkerWatch, lines: dict[str, int]) -> int:
    """Worker processes that ended while watched other than by their supervisor's order,
    or the deaths the supervisor logged, whichever is more (a worker replaced between two
    looks is missed by the watch, not by the log)."""
    return max(len(watch.ended) - lines["stopped"], lines["died"] + lines["startup"], 0)
