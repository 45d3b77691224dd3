"""Refuse request bodies over the size limit with a 413 problem, declared or streamed."""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import ApiError, problem

DETAIL = "the request body exceeds the limit of {limit} bytes (UNDERTOW_MAX_BODY_BYTES)"


class BodyTooLarge(HTTPException):
    """Raised while a streamed body is read; the app's handlers turn it into a problem."""

    def __init__(self, limit: int):
        super().__init__(413, DETAIL.format(limit=limit))


class BodyLimitMiddleware:
    """At most `limit` bytes of body: a larger Content-Length is refused before reading,
    a body without one is counted as it streams in."""

    def __init__(self, app: ASGIApp, limit: int):
        self.app, self.limit = app, limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.limit:
            error = ApiError(413, "request-too-large", "Request body too large",
                             DETAIL.format(limit=self.limit))
            await problem(Request(scope), error)(scope, receive, send)
            return
        received = 0

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        await self.app(scope, counted, send)
