"""The OpenAPI document of the app, with problem+json error responses.

FastAPI documents validation errors as its own JSON shape; the service answers with
RFC 9457 problems, so every error response is documented as `Problem`.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from app.errors import MEDIA_TYPE, Problem

_REF = {"$ref": "#/components/schemas/Problem"}
_DESCRIPTIONS = {
    400: "the body could not be read as JSON",
    401: "missing or wrong X-API-Key",
    404: "no such resource",
    408: "the request body did not arrive within UNDERTOW_READ_TIMEOUT",
    409: "the resource is in a state that does not allow this",
    413: "the request body is too large",
    415: "the request body is labelled as another media type than JSON (Content-Type)",
    422: "invalid request: `errors` lists each offending field",
    429: "the job queue is full; retry after the Retry-After header's seconds",
    431: "the request head (request line with its query, and header fields) exceeds 16 KiB; "
         "the connection is closed (app/server.py)",
    503: "no compute thread, or no room in the synchronous computations' memory budget "
         "(UNDERTOW_SYNC_MEMORY_MB), came free within UNDERTOW_COMPUTE_WAIT; retry after the "
         "Retry-After header's seconds",
}


UNAVAILABLE = ("the job store or the solver workers cannot be used (type unavailable; "
               "`detail` says why); retry after the Retry-After header's seconds. Type "
               "store-damaged: the job store failed its integrity check, and no job is "
               "accepted until the service is restarted on a sound store (`detail` says how)")
"""The 503 of the health, metrics and plan endpoints."""

BUDGET = (f"{_DESCRIPTIONS[422]}; or type budget-exceeded: the computation ran out of its "
          "time budget (UNDERTOW_SYNC_WALL_TIME)")
"""The 422 of a synchronous computation."""


def problem_response(status: int, description: str | None = None) -> dict[str, Any]:
    """The OpenAPI response object of a problem with this status."""
    response: dict[str, Any] = {"description": description or _DESCRIPTIONS[status],
                                "content": {MEDIA_TYPE: {"schema": _REF}}}
    if status in (429, 503):
        response["headers"] = {"Retry-After": {"description": "seconds to wait",
                                               "schema": {"type": "integer"}}}
    return response


def problems(*statuses: int, **descriptions: str) -> dict[int | str, dict[str, Any]]:
    """`responses=` argument of a route that can answer with these problems;
    `descriptions` (as `s422=...`) replace the default description of a status."""
    return {status: problem_response(status, descriptions.get(f"s{status}"))
            for status in statuses}


def _problem_schemas() -> dict[str, Any]:
    schema = Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    defs = schema.pop("$defs", {})
    return {"Problem": schema, **defs}


def document(app: FastAPI) -> dict[str, Any]:
    """The app's OpenAPI document (built once)."""
    if app.openapi_schema is not None:
        return app.openapi_schema
    doc = get_openapi(title=app.title, version=app.version, description=app.description,
                      routes=app.routes)
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    schemas.update(_problem_schemas())
    for operations in doc["paths"].values():
        for operation in operations.values():
            responses = operation["responses"]
            if responses.get("422", {}).get("description") == "Validation Error":
                responses["422"] = problem_response(422)  # FastAPI's own shape
            if "requestBody" in operation:
                for status in (400, 408, 413, 415):
                    responses[str(status)] = problem_response(status)
            if operation.get("security"):
                responses["401"] = problem_response(401)
            responses["431"] = problem_response(431)  # refused before routing, any path
    app.openapi_schema = doc
    return doc
