"""The pipe between a supervisor (`app.supervisor`) and one of its solver workers
(`app.worker`): what each sends, and how the worker reads it.

Supervisor -> worker: WAKE when a job was queued, STOP to end. Worker -> supervisor: READY
once started, `Claimed` when it takes a job, `JobEnd` when the job ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from multiprocessing.connection import Connection

WAKE, STOP, READY = "wake", "stop", "ready"


@dataclass(frozen=True)
class Claimed:
    """Worker -> supervisor: the worker took a job whose budget is `budget` seconds."""

    job_id: str
    budget: float


@dataclass(frozen=True)
class JobEnd:
    """Worker -> supervisor: a job ended with this stored status after `elapsed` seconds;
    `exhausted` when it ran out of memory (the worker then leaves)."""

    job_id: str
    status: str
    elapsed: float
    exhausted: bool = False


def stop_requested(channel: Connection, wait: float) -> bool:
    """Read the supervisor's messages, waiting up to `wait` s for one; True on STOP or
    when the supervisor is gone."""
    try:
        while channel.poll(wait):
            if channel.recv() == STOP:
                return True
            wait = 0.0
    except (EOFError, OSError):
        return True
    return False
