"""The API key gate: refused before anything reads the request's body.

As a route dependency the key was checked only after FastAPI had read and parsed the
body, so a request without the key was answered 422 (or 413) about a body it had no
right to send. This middleware answers 401 first, for every path under /v1 and for
/metrics; /healthz, the viewer and the API description stay open.
"""

from __future__ import annotations

import secrets

from starlette.requests import Request
from starlette.types import ASGIApp, Receive, Scope, Send

from app.errors import ApiError, problem
from app.middleware import HttpMiddleware

HEADER = "X-API-Key"


def accepted(expected: str | None, given: str | None) -> bool:
    """Whether a request with key `given` may pass a server whose key is `expected`
    (None: no key needed); compared in constant time."""
    if not expected:
        return True
    return given is not None and secrets.compare_digest(given.encode(), expected.encode())


def unauthorized() -> ApiError:
    """The 401 problem of a missing or wrong key."""
    return ApiError(401, "unauthorized", "Missing or wrong API key",
                    f"send the server's API key in the {HEADER} header")


def protected(path: str) -> bool:
    """Whether a path needs the key."""
    return path == "/metrics" or path == "/v1" or path.startswith("/v1/")


class ApiKeyMiddleware(HttpMiddleware):
    """401 for a protected path without the server's key, before the body is read."""

    def __init__(self, app: ASGIApp, key: str | None):
        super().__init__(app)
        self.key = key

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.key and protected(scope["path"]):
            given = dict(scope["headers"]).get(HEADER.lower().encode())
            if not accepted(self.key, given.decode("latin-1") if given is not None else None):
                await problem(Request(scope), unauthorized())(scope, receive, send)
                return
        await self.app(scope, receive, send)
