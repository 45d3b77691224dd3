"""Structured JSON logs (one object a line) and the X-Request-ID of every request."""

from __future__ import annotations

import contextvars
import json
import logging
import re
import sys
import time
import uuid

from starlette.types import Message, Receive, Scope, Send

from app.middleware import HttpMiddleware

HEADER = "X-Request-ID"
_VALID_ID = re.compile(r"^[A-Za-z0-9._:-]{1,128}$")
request_id: contextvars.ContextVar[str | None] = contextvars.ContextVar("request_id", default=None)
access = logging.getLogger("undertow.access")


class JsonFormatter(logging.Formatter):
    """time, level, logger, message, request_id, any `extra` fields, and the traceback."""

    _RESERVED = set(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {
        "message", "color_message"}

    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        rid = getattr(record, "request_id", None) or request_id.get()
        if rid is not None:
            entry["request_id"] = rid
        entry.update({k: v for k, v in vars(record).items() if k not in self._RESERVED})
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str)


LIBRARIES = ("psycopg", "procrastinate")
"""Libraries whose own warnings (the connection pool's during a database outage, say) go
to the same JSON lines, from WARNING up."""


def configure(level: str = "INFO") -> None:
    """Send the service's, uvicorn's and LIBRARIES' logs as JSON lines to stderr, so that
    every line of a process's log is one JSON object. uvicorn's own access log is
    silenced: `undertow.access` logs every request, with its id."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter())
    for name in ("undertow", "uvicorn", "uvicorn.error", "uvicorn.access", *LIBRARIES):
        logger = logging.getLogger(name)
        logger.handlers[:] = [handler]
        logger.propagate = False
    logging.getLogger("undertow").setLevel(level.upper())
    for name in ("uvicorn.access", *LIBRARIES):
        logging.getLogger(name).setLevel(logging.WARNING)


class RequestIdMiddleware(HttpMiddleware):
    """Take X-Request-ID from the request (or make one), log the request, echo the header."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        given = dict(scope["headers"]).get(HEADER.lower().encode(), b"").decode("latin-1")
        rid = given if _VALID_ID.match(given) else uuid.uuid4().hex
        scope.setdefault("state", {})["request_id"] = rid
        token = request_id.set(rid)
        start, status = time.perf_counter(), 500

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                message.setdefault("headers", [])
                message["headers"] = [*message["headers"], (HEADER.lower().encode(), rid.encode())]
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            access.info("request", extra={
                "request_id": rid, "method": scope["method"], "path": scope["path"],
                "status": status,
                "duration_ms": round(1e3 * (time.perf_counter() - start), 3)})
            request_id.reset(token)
