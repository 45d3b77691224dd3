"""Errors by kind: what the caller got wrong is a 4xx at its field; anything else, a
ValueError from a bug included, a 500 problem, logged once, on a connection that stays
usable."""

from __future__ import annotations

import http.client
import importlib
import json
import logging
from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from service_fixtures import TWO_LINK, client, serving

from app.main import create_app
from app.settings import Settings
from planner.errors import InputError
from planner.examples import example


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


# --------------------------------------------------------------------------- errors by kind


BODIES = {  # a body each synchronous endpoint accepts, and a library function it calls
    "/v1/dynamics": ({"robot": TWO_LINK, "states": [{"q": [0.1, 0.2], "dq": [0.0, 0.0]}]},
                     "planner.evaluation", "at"),
    "/v1/coupling": ({"robot": TWO_LINK, "configurations": [[0.1, 0.2], [0.2, 0.4]]},
                     "planner.coupling", "along"),
    "/v1/inverse-dynamics": (example("two-link-waves").request, "planner.inverse", "along"),
    "/v1/simulate": ({"robot": TWO_LINK, "t": [0.0, 0.1], "tau": [[0.0], [0.0]],
                      "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]}},
                     "planner.simulate", "_trajectory"),
    "/v1/waves/design": (example("two-link-wave-design").request, "planner.waves.design",
                         "candidates"),
}
BLAME = "states.0.q: a message that names a field of the request"


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("kinds")) as c:
        yield c


def _raising(error: Exception):
    def raise_it(*args, **kwargs):
        raise error
    return raise_it


@pytest.mark.parametrize("path", BODIES)
def test_a_value_error_from_a_bug_in_a_computation_is_a_500_with_the_request_id(
        api, path, monkeypatch, records):
    body, module, name = BODIES[path]
    monkeypatch.setattr(importlib.import_module(module), name, _raising(ValueError(BLAME)))
    r = api.post(path, json=body, headers={"X-Request-ID": "bug-1"})
    assert (r.status_code, r.headers["content-type"]) == (500, "application/problem+json")
    assert r.json() == {"type": "urn:undertow:problem:internal", "title": "Internal server error",
                        "status": 500, "instance": path, "request_id": "bug-1",
                        "detail": "an unexpected error occurred; see the server log"}
    (logged,) = [r for r in records.records if r.exc_info]
    assert logged.exc_info[0] is ValueError and logged.getMessage() == f"unhandled error on {path}"


@pytest.mark.parametrize("path", BODIES)
def test_an_input_error_of_a_computation_is_a_422_at_the_field_it_names(api, path, monkeypatch):
    body, module, name = BODIES[path]
    monkeypatch.setattr(importlib.import_module(module), name, _raising(InputError(BLAME)))
    r = api.post(path, json=body, headers={"X-Request-ID": "input-1"})
    assert (r.status_code, r.headers["content-type"]) == (422, "application/problem+json")
    problem = r.json()
    assert (problem["type"], problem["request_id"]) == ("urn:undertow:problem:validation",
                                                        "input-1")
    assert problem["errors"] == [{"loc": ["body", "states", 0, "q"], "type": "value_error",
                                  "msg": "a message that names a field of the request"}]


def _json_routes(document: dict) -> list[tuple[str, str]]:
    """The operations that read a JSON body, as (method, path)."""
    return [(method.upper(), path) for path, operations in document["paths"].items()
            for method, operation in operations.items() if "requestBody" in operation]


@pytest.mark.parametrize("content_type", ["text/plain", "application/x-www-form-urlencoded",
                                          None])
def test_a_body_not_sent_as_json_is_415_on_every_json_route(tmp_path, content_type):
    """Every route that reads a JSON body answers a body labelled otherwise (or not at all)
    with 415 at the Content-Type header, not with a 422 about fields it never read."""
    body = json.dumps({"robot": TWO_LINK, "states": [{"q": [0.1, 0.2], "dq": [0.0, 0.0]}]})
    headers = {} if content_type is None else {"Content-Type": content_type}
    with client(tmp_path) as api:
        routes = _json_routes(api.get("/openapi.json").json())
        assert ("POST", "/v1/dynamics") in routes and ("POST", "/v1/plans") in routes
        for method, path in routes:
            r = api.request(method, path.replace("{job_id}", "x"), content=body,
                            headers=headers)
            assert r.status_code == 415, (method, path, r.text)
            assert "415" in api.app.openapi()["paths"][path][method.lower()]["responses"]
            assert r.headers["content-type"] == "application/problem+json"
            problem = r.json()
            given = content_type or "no Content-Type"
            assert problem["type"] == "urn:undertow:problem:unsupported-media-type"
            assert problem["errors"] == [{
                "loc": ["header", "content-type"], "type": "unsupported_media_type",
                "msg": f"this endpoint reads a JSON body: send it as application/json, not "
                       f"{given}"}]
        json_type = api.post("/v1/dynamics", content=body,
                             headers={"Content-Type": "application/json; charset=utf-8"})
        empty = api.post("/v1/dynamics", headers=headers)
    assert json_type.status_code == 200
    assert empty.status_code == 422  # no body: the models say what is missing
