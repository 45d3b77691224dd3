"""LISTEN on a PostgreSQL channel through a connection of its own: how the PostgreSQL
store announces queued jobs to idle workers (`JobStore.listen`).

An announcement's payload says when its job may be claimed: procrastinate's of a new job
(`{"type": "job_inserted", ...}`) and the store's of a job queued again at once (empty)
mean now; the store's of a job queued again after a pause (`due_in`: `{"type":
"job_due", "in": seconds}`) mean once that pause has passed, so that an idle worker
looks again then instead of at its next poll. Other payloads on the channel (procrastinate's
abort requests) announce no job."""

from __future__ import annotations

import contextlib
import json

import psycopg
from psycopg.sql import SQL, Identifier

DUE = "job_due"
"""The type of the payload announcing a job that may be claimed after a pause."""
_NOW = {"job_inserted"}  # procrastinate's payload types that announce a claimable job


def due_in(seconds: float) -> str:
    """The payload announcing a job queued again that may be claimed `seconds` from now."""
    return json.dumps({"type": DUE, "in": round(seconds, 3)})


def pause(payload: str) -> float | None:
    """[s] how long after it arrived the job an announcement's `payload` names may be
    claimed (0.0: now), or None when it announces no job."""
    if not payload:
        return 0.0
    try:
        message = json.loads(payload)
    except ValueError:
        return None
    if not isinstance(message, dict):
        return None
    if message.get("type") == DUE and isinstance(message.get("in"), int | float):
        return max(0.0, float(message["in"]))
    return 0.0 if message.get("type") in _NOW else None


class PostgresListener:
    """LISTEN on `channel` (the one notified of queued jobs) at `url`, connecting within
    `timeout` seconds: `fileno()` to wait on with select, `drain()` to read what arrived.
    After any failure its caller closes it, polls meanwhile and opens a new one later."""

    def __init__(self, url: str, timeout: float, channel: str):
        self.conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, int(timeout)))
        self.conn.execute(SQL("LISTEN {}").format(Identifier(channel)))

    def fileno(self) -> int:
        return self.conn.fileno()

    def drain(self) -> list[float]:
        """The pause [s] of each job announced since the last drain (`pause`: 0.0 for one
        that may be claimed now); raises psycopg.Error when the connection broke."""
        pgconn = self.conn.pgconn
        pgconn.consume_input()
        pauses: list[float] = []
        while (note := pgconn.notifies()) is not None:
            found = pause(note.extra.decode(errors="replace"))
            if found is not None:
                pauses.append(found)
        if pgconn.status != psycopg.pq.ConnStatus.OK:
            raise psycopg.OperationalError("the listening connection broke")
        return pauses

    def close(self) -> None:
        with contextlib.suppress(psycopg.Error):
            self.conn.close()
