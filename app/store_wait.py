"""Every HTTP request's store calls wait at most `app.store.waits.REQUEST_WAIT` for a
database connection, so that a request needing the store answers (503 `unavailable`
while the database is away) within a container's health-check timeout; the store's
background work keeps its own, longer timeout."""

from __future__ import annotations

from starlette.types import Receive, Scope, Send

from app.middleware import HttpMiddleware
from app.store.waits import bounded


class StoreWaitMiddleware(HttpMiddleware):
    """ASGI middleware: the request runs under `app.store.waits.bounded()`."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        with bounded():
            await self.app(scope, receive, send)
