"""Unexpected errors: a 500 problem, logged once, on a connection that stays usable."""

from __future__ import annotations

import http.client
import json
import logging
from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from service_fixtures import serving

from app.main import create_app
from app.settings import Settings


class Records(logging.Handler):
    """Keeps the records of the loggers it is attached to (the service's do not propagate)."""

    def __init__(self):
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _boom() -> None:
    raise RuntimeError("boom")


@pytest.fixture(scope="module")
def failing_app(tmp_path_factory) -> FastAPI:
    settings = Settings(db_path=str(tmp_path_factory.mktemp("errors") / "jobs.sqlite3"),
                        workers=1, instance="test")
    app = create_app(settings)
    app.router.routes.insert(0, APIRoute("/v1/boom", _boom, methods=["GET"]))
    return app


@pytest.fixture
def records() -> Iterator[Records]:
    handler = Records()
    loggers = [logging.getLogger(name) for name in ("undertow", "uvicorn", "uvicorn.error")]
    for logger in loggers:
        logger.addHandler(handler)
    yield handler
    for logger in loggers:
        logger.removeHandler(handler)


def test_a_500_keeps_the_connection_and_is_logged_once(failing_app, records):
    with serving(failing_app) as port:
        connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        connection.request("GET", "/v1/boom", headers={"X-Request-ID": "boom-1"})
        first = connection.getresponse()
        body = json.loads(first.read())
        connection.request("GET", "/healthz")  # the same keep-alive connection
        second = connection.getresponse()
        second.read()
        connection.close()
    assert (first.status, first.getheader("content-type")) == (500, "application/problem+json")
    assert body == {"type": "urn:undertow:problem:internal", "title": "Internal server error",
                    "status": 500, "instance": "/v1/boom", "request_id": "boom-1",
                    "detail": "an unexpected error occurred; see the server log"}
    assert second.status == 200
    tracebacks = [r for r in records.records if r.exc_info]
    assert [(r.name, r.getMessage()) for r in tracebacks] == [
        ("undertow.errors", "unhandled error on /v1/boom")]
