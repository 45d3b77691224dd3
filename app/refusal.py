"""A start the service refuses for a reason it states (a damaged or unreachable job store,
one of a newer schema, a server name that a live server holds) ends with that reason as
one log line and uvicorn's non-zero exit status (3), not with the traceback Starlette
attaches to a failed lifespan.

The lifespan logs the reason and calls `refuse`; `QuietRefusal`, the app's outermost
layer, then sends uvicorn the failure without the traceback, which uvicorn would log as
a second, longer line. Any other failure of the start keeps its traceback.
"""

from __future__ import annotations

import logging
from typing import NoReturn

from fastapi import FastAPI
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("undertow.main")


def refuse(app: FastAPI, exc: Exception) -> NoReturn:
    """Log why the start is refused (`exc`, whose message says what to do) and raise it."""
    log.critical("%s", exc)
    app.state.refused = True
    raise exc


class QuietRefusal:
    """ASGI layer: a lifespan whose start was refused (`refuse`) fails without the
    traceback; every other message passes unchanged."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "lifespan":
            await self.app(scope, receive, send)
            return

        async def quiet(message: Message) -> None:
            if (message["type"] == "lifespan.startup.failed"
                    and getattr(scope["app"].state, "refused", False)):
                message = {"type": message["type"], "message": ""}
            await send(message)

        await self.app(scope, receive, quiet)
