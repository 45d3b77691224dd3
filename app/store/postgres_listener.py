"""LISTEN on a PostgreSQL channel through a connection of its own: how the PostgreSQL
store announces queued jobs to idle workers (`JobStore.listen`)."""

from __future__ import annotations

import contextlib

import psycopg
from psycopg.sql import SQL, Identifier


class PostgresListener:
    """LISTEN on `channel` (the one notified of queued jobs) at `url`, connecting within
    `timeout` seconds: `fileno()` to wait on with select, `drain()` to read what arrived.
    After any failure its caller closes it, polls meanwhile and opens a new one later."""

    def __init__(self, url: str, timeout: float, channel: str):
        self.conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, int(timeout)))
        self.conn.execute(SQL("LISTEN {}").format(Identifier(channel)))

    def fileno(self) -> int:
        return self.conn.fileno()

    def drain(self) -> int:
        """How many notifications arrived (0 or more); raises psycopg.Error when the
        connection broke."""
        pgconn = self.conn.pgconn
        pgconn.consume_input()
        count = 0
        while pgconn.notifies() is not None:
            count += 1
        if pgconn.status != psycopg.pq.ConnStatus.OK:
            raise psycopg.OperationalError("the listening connection broke")
        return count

    def close(self) -> None:
        with contextlib.suppress(psycopg.Error):
            self.conn.close()
