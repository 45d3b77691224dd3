"""The PostgreSQL store's connection pool: psycopg_pool's, replacing a lost connection at
most `RECONNECT_EVERY` seconds apart, so that after an outage of any length the store
answers within about a second of the database's return."""

from __future__ import annotations

from psycopg_pool import ConnectionPool
from psycopg_pool.base import AttemptWithBackoff

RECONNECT_EVERY = 1.0
"""[s] longest pause between two attempts of the pool to replace a lost connection."""


class Reconnect(AttemptWithBackoff):
    """psycopg_pool's attempts to replace a lost connection, at most RECONNECT_EVERY apart
    (its own pause doubles without bound, 1, 2, 4, ... s, so that its next attempt could
    come nearly as long after the database's return as the outage had lasted, and every
    verdict held meanwhile waited for it)."""

    def update_delay(self, now: float) -> None:
        super().update_delay(now)
        self.delay = min(self.delay, RECONNECT_EVERY)


class Pool(ConnectionPool):
    """A connection pool that replaces lost connections `Reconnect`'s way."""

    def _add_connection(self, attempt: AttemptWithBackoff | None,
                        growing: bool = False) -> None:
        super()._add_connection(attempt or Reconnect(timeout=self.reconnect_timeout),
                                growing)
