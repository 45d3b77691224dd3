"""Refuse request bodies over the size limit with a 413 problem, declared or streamed, and
bodies that take longer than the read timeout to arrive with a 408 problem."""

from __future__ import annotations

import anyio
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import ApiError, problem
from app.middleware import HttpMiddleware

DETAIL = "the request body exceeds the limit of {limit} bytes (UNDERTOW_MAX_BODY_BYTES)"
LATE = "the request body did not arrive within {timeout:g} s (UNDERTOW_READ_TIMEOUT)"


class BodyTooLarge(HTTPException):
    """Raised while a streamed body is read; the app's handlers turn it into a problem."""

    def __init__(self, limit: int):
        super().__init__(413, DETAIL.format(limit=limit))


class BodyTooSlow(HTTPException):
    """Raised when the rest of a body does not arrive in time (the connection then closes)."""

    def __init__(self, timeout: float):
        super().__init__(408, LATE.format(timeout=timeout), headers={"Connection": "close"})


class BodyLimitMiddleware(HttpMiddleware):
    """At most `limit` bytes of body: a larger Content-Length is refused before reading,
    a body without one is counted as it streams in. The whole body must arrive within
    `timeout` seconds of the request's head."""

    def __init__(self, app: ASGIApp, limit: int, timeout: float):
        super().__init__(app)
        self.limit, self.timeout = limit, timeout

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.limit:
            error = ApiError(413, "request-too-large", "Request body too large",
                             DETAIL.format(limit=self.limit))
            await problem(Request(scope), error)(scope, receive, send)
            return
        received, complete = 0, False
        deadline = anyio.current_time() + self.timeout

        async def counted() -> Message:
            nonlocal received, complete
            if complete:  # later reads wait for a disconnect: no time limit
                return await receive()
            with anyio.move_on_after(deadline - anyio.current_time()) as late:
                message = await receive()
            if late.cancelled_caught:
                raise BodyTooSlow(self.timeout)
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                complete = not message.get("more_body", False)
                if received > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        await self.app(scope, counted, send)
