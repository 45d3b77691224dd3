"""The HTTP protocol the service runs with: uvicorn's h11 with a time and a size limit on
request heads.

uvicorn closes an idle keep-alive connection after `--timeout-keep-alive`, but once a
client has sent the first bytes of a request head (or on a new connection before any
byte) nothing bounds how long it may take to finish it: a connection sending a header
line now and then stays open for good. This protocol closes a connection whose request
head is not complete within UNDERTOW_READ_TIMEOUT seconds of the connection opening or
of the previous response.

h11 bounds a head only while it is incomplete: a head of 70 KB that arrived in one read
was served. This protocol answers a head longer than MAX_HEAD bytes (16 KiB, or uvicorn's
`--h11-max-incomplete-event-size` when given), however it arrived, with a 431
`head-too-large` problem, then ends its side of the connection and discards what still
comes until the client closes its side or the head's time runs out (closing at once, with
unread bytes, would reset the connection and could lose the answer). The body's size and
time are `app.body_limit`'s.

    uvicorn app.main:app --http app.server:HeadTimeoutProtocol
"""

from __future__ import annotations

import asyncio
import json
import re

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from app.errors import MEDIA_TYPE, TYPE_PREFIX, Problem
from app.settings import get_settings

MAX_HEAD = 16 * 1024
"""Largest request head [bytes], request line, header fields and the blank line after
them (h11's own bound on an incomplete head)."""
_HEAD_END = re.compile(rb"\r?\n\r?\n")

PROTOCOL = "app.server:HeadTimeoutProtocol"
"""The value of uvicorn's --http option (or `http=` of uvicorn.run)."""


class HeadTimeoutProtocol(H11Protocol):
    """H11Protocol closing connections whose request head is late."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.head_timeout = get_settings().read_timeout
        self.max_head = self.config.h11_max_incomplete_event_size or MAX_HEAD
        self._head_timer: asyncio.TimerHandle | None = None
        self._refused = False  # a head was too large: what comes is discarded

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._await_head()

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        super().data_received(data)
        if self.conn.their_state is not h11.IDLE:  # the head is complete
            self._cancel_head_timer()

    def handle_events(self) -> None:
        """uvicorn's, once the head waiting to be read (a new one, or one pipelined behind
        the last response) is known to be no longer than `max_head`."""
        if self.conn.their_state is h11.IDLE:
            pending, _ = self.conn.trailing_data
            end = _HEAD_END.search(pending)
            if (end.end() if end else len(pending)) > self.max_head:
                self._refuse_head(pending)
                return
        super().handle_events()

    def _refuse_head(self, pending: bytes) -> None:
        """Answer 431 head-too-large (problem+json) and close the connection."""
        line = pending.split(b"\n", 1)[0].split()
        path = line[1].decode("latin-1") if len(line) > 1 else "/"
        body = json.dumps(Problem(
            type=TYPE_PREFIX + "head-too-large", title="Request head too large", status=431,
            detail=f"the request head (request line and header fields) exceeds "
                   f"{self.max_head} bytes", instance=path).model_dump(exclude_none=True))
        self.transport.write(
            f"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: {MEDIA_TYPE}\r\n"
            f"content-length: {len(body)}\r\nconnection: close\r\n\r\n{body}".encode())
        self._refused = True
        if self.transport.can_write_eof():
            self.transport.write_eof()
        else:
            self.transport.close()

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
        if self._refused:
            self.transport.close()
        elif self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self.logger.info("closed a connection whose request head did not arrive within "
                             "%g s (UNDERTOW_READ_TIMEOUT)", self.head_timeout)
            self.transport.close()
