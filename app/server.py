"""The HTTP protocol the service runs with: uvicorn's h11 with a time limit on request heads.

uvicorn closes an idle keep-alive connection after `--timeout-keep-alive`, but once a
client has sent the first bytes of a request head (or on a new connection before any
byte) nothing bounds how long it may take to finish it: a connection sending a header
line now and then stays open for good. This protocol closes a connection whose request
head is not complete within UNDERTOW_READ_TIMEOUT seconds of the connection opening or
of the previous response. The head's size is bounded by h11 (16 KiB, uvicorn's
`--h11-max-incomplete-event-size`); the body's time by `app.body_limit`.

    uvicorn app.main:app --http app.server:HeadTimeoutProtocol
"""

from __future__ import annotations

import asyncio

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from app.settings import get_settings

PROTOCOL = "app.server:HeadTimeoutProtocol"
"""The value of uvicorn's --http option (or `http=` of uvicorn.run)."""


class HeadTimeoutProtocol(H11Protocol):
    """H11Protocol closing connections whose request head is late."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.head_timeout = get_settings().read_timeout
        self._head_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._await_head()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.conn.their_state is not h11.IDLE:  # the head is complete
            self._cancel_head_timer()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._await_head()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)

    def _await_head(self) -> None:
        """Start the clock for the next request head, unless it has already arrived."""
        self._cancel_head_timer()
        if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
            self._head_timer = self.loop.call_later(self.head_timeout, self._head_late)

    def _cancel_head_timer(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_late(self) -> None:
        self._head_timer = None
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self.logger.info("closed a connection whose request head did not arrive within "
                             "%g s (UNDERTOW_READ_TIMEOUT)", self.head_timeout)
            self.transport.close()
