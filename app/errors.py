"""RFC 9457 problem details (application/problem+json) for every error the service returns.

Each problem has type, title, status, detail and instance, the request id, and for
validation errors `errors: [{loc, msg, type}]`, one entry per offending field. Library
messages of the form "field.path: what is wrong" are split so that `loc` names the field.
What the caller got wrong is a 4xx; anything else, a library ValueError from a bug
included, is a 500 `internal` problem with the request id (`UnexpectedErrorMiddleware`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount
from starlette.types import Message, Receive, Scope, Send

from app.middleware import HttpMiddleware
from planner.errors import InputError, located

log = logging.getLogger("undertow.errors")

MEDIA_TYPE = "application/problem+json"
TYPE_PREFIX = "urn:undertow:problem:"

Loc = list[str | int]


class FieldError(BaseModel):
    """One offending field: where it is (`loc`, from "body" or "query") and what is wrong."""

    loc: Loc
    msg: str
    type: str = Field(description="machine-readable kind, e.g. greater_than, value_error")


class Problem(BaseModel):
    """An RFC 9457 problem detail."""

    type: str = Field(description="URI naming the kind of problem", examples=[
        TYPE_PREFIX + "validation"])
    title: str
    status: int
    detail: str
    instance: str = Field(description="path of the request that failed")
    request_id: str | None = Field(default=None, description="the X-Request-ID of the request")
    errors: list[FieldError] | None = None


class ApiError(Exception):
    """An error with a known problem type; raised by routes and dependencies."""

    def __init__(self, status: int, slug: str, title: str, detail: str,
                 errors: Sequence[FieldError] | None = None,
                 headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status, self.slug, self.title, self.detail = status, slug, title, detail
        self.errors = list(errors) if errors is not None else None
        self.headers = headers


def field_error(loc: Sequence[str | int], message: str, kind: str = "value_error") -> FieldError:
    """A field error, with a "field.path: " message prefix moved into `loc`."""
    where, msg = located(message)
    return FieldError(loc=[*loc, *where], msg=msg, type=kind)


def invalid(errors: Sequence[FieldError]) -> ApiError:
    """A 422 validation problem listing the offending fields."""
    lines = [f"{'.'.join(map(str, e.loc))}: {e.msg}" for e in errors]
    detail = "; ".join(lines[:3]) + (f"; and {len(lines) - 3} more" if len(lines) > 3 else "")
    return ApiError(422, "validation", "The request is not valid", detail, errors)


def from_input_error(exc: InputError, loc: Sequence[str | int] = ("body",)) -> ApiError:
    """A 422 at the field a library InputError ("field.path: what is wrong") names."""
    return invalid([field_error(loc, str(exc))])


def from_pydantic(errors: Sequence[dict[str, Any]], prefix: Sequence[str | int] = ()) -> ApiError:
    """A 422 for pydantic error dicts."""
    return invalid([field_error([*prefix, *e["loc"]], e["msg"], e["type"]) for e in errors])


def problem(request: Request, error: ApiError) -> JSONResponse:
    """The problem+json response of an error."""
    body = Problem(type=TYPE_PREFIX + error.slug, title=error.title, status=error.status,
                   detail=error.detail, instance=request.url.path,
                   request_id=getattr(request.state, "request_id", None), errors=error.errors)
    return JSONResponse(body.model_dump(mode="json", exclude_none=True), status_code=error.status,
                        media_type=MEDIA_TYPE, headers=error.headers)


_HTTP_SLUGS = {400: "malformed-body", 401: "unauthorized", 404: "not-found",
               405: "method-not-allowed", 408: "request-timeout", 413: "request-too-large",
               429: "queue-full"}


_HTTP_TITLES = {400: "The body is not valid JSON", 408: "Request body too slow",
                413: "Request body too large"}


async def _on_api_error(request: Request, exc: ApiError) -> JSONResponse:
    return problem(request, exc)


async def _on_validation(request: Request, exc: RequestValidationError) -> JSONResponse:
    unreadable = [e for e in exc.errors() if e["type"] == "json_invalid"]
    if unreadable:  # FastAPI reports a body it cannot parse as a validation error
        where = unreadable[0]["loc"][-1]
        why = unreadable[0].get("ctx", {}).get("error", "not JSON")
        return problem(request, ApiError(400, "malformed-body", _HTTP_TITLES[400],
                                         f"{why} at character {where} of the body"))
    return problem(request, from_pydantic(exc.errors()))


_METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT")


def _allowed(request: Request) -> str:
    """Every method some route of the app serves at this path (Starlette's 405 names only
    those of the first route it found: GET but not DELETE of /v1/plans/{job_id})."""
    def served(method: str) -> bool:
        scope = {**request.scope, "method": method,  # as the app saw it, not a mount
                 "root_path": request.scope.get("app_root_path", "")}
        return any(route.matches(scope)[0] == Match.FULL for route in request.app.routes
                   if not isinstance(route, Mount) or method in ("GET", "HEAD"))  # files
    return ", ".join(filter(served, _METHODS))


async def _on_http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    title = _HTTP_TITLES.get(exc.status_code, str(exc.detail))
    detail = str(exc.detail)
    slug = _HTTP_SLUGS.get(exc.status_code, "http-error")
    headers = getattr(exc, "headers", None)
    if exc.status_code == 405:
        headers = {**(headers or {}), "Allow": _allowed(request)}
    return problem(request, ApiError(exc.status_code, slug, title, detail, headers=headers))


class UnexpectedErrorMiddleware(HttpMiddleware):
    """Answer an unhandled exception with a 500 problem and log it once.

    Starlette's last-resort handler answers too, but then re-raises to the server, which
    logs the exception a second time and closes the connection: a keep-alive client's
    next request on it fails with a reset. Here the exception ends with the answer. One
    raised after the response started cannot be answered and still goes to the server.
    """

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        started = False

        async def watch(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, watch)
        except Exception:
            if started:
                raise
            log.exception("unhandled error on %s", scope["path"])
            error = ApiError(500, "internal", "Internal server error",
                             "an unexpected error occurred; see the server log")
            await problem(Request(scope), error)(scope, receive, send)


def install(app: FastAPI) -> None:
    """Register the problem+json handlers on an app (and `UnexpectedErrorMiddleware`,
    added with the app's middleware, for everything else)."""
    app.exception_handler(ApiError)(_on_api_error)
    app.exception_handler(RequestValidationError)(_on_validation)
    app.exception_handler(StarletteHTTPException)(_on_http)
