"""Replanning sessions: a finished plan's `Replanner` kept hot in this server process for
one client, which sends it measured states (`app.routes.sessions`).

A session holds the replanner (its cached NLP, its last solution and multipliers) and is
freed when its client deletes it, or when no request has touched it for
UNDERTOW_SESSION_IDLE seconds: every access sweeps the expired ones first, and the app
sweeps every few seconds besides, so that an abandoned session frees its memory without a
further request. At most UNDERTOW_MAX_SESSIONS live at once; a session runs one update at
a time (`Session.lock`). Sessions are this process's: another server does not know them.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field

from planner.service import Replanner


@dataclass
class Session:
    """One client's replanner. Times are `time.monotonic()` seconds."""

    id: str
    plan_id: str
    replanner: Replanner
    created: float
    touched: float
    updates: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


class Full(Exception):
    """Every session place is taken."""


class Sessions:
    """The live sessions of this process: at most `limit`, each freed after `idle` seconds
    without a request. Safe to use from threads and the event loop alike."""

    def __init__(self, limit: int, idle: float):
        self.limit, self.idle = limit, idle
        self._sessions: dict[str, Session] = {}
        self._guard = threading.Lock()

    def open(self, plan_id: str, replanner: Replanner) -> Session:
        """A new session on the replanner; Full when `limit` live ones already exist."""
        now = time.monotonic()
        with self._guard:
            self._sweep(now)
            if len(self._sessions) >= self.limit:
                raise Full
            session = Session(secrets.token_urlsafe(16), plan_id, replanner, now, now)
            self._sessions[session.id] = session
            return session

    def get(self, session_id: str) -> Session | None:
        """The live session of that id, touched (None when there is none, or it expired)."""
        now = time.monotonic()
        with self._guard:
            self._sweep(now)
            session = self._sessions.get(session_id)
            if session is not None:
                session.touched = now
            return session

    def close(self, session_id: str) -> bool:
        """Free a session; False when there was none of that id."""
        with self._guard:
            return self._sessions.pop(session_id, None) is not None

    def sweep(self) -> int:
        """Free the sessions idle for longer than `idle`; how many were freed."""
        with self._guard:
            return self._sweep(time.monotonic())

    def __len__(self) -> int:
        with self._guard:
            return len(self._sessions)

    def expires_in(self, session: Session) -> float:
        """[s] until the session expires unless a request touches it."""
        return max(session.touched + self.idle - time.monotonic(), 0.0)

    def _sweep(self, now: float) -> int:
        expired = [k for k, s in self._sessions.items()
                   if now - s.touched > self.idle and not s.lock.locked()]
        for key in expired:
            del self._sessions[key]
        return len(expired)
