"""JSON routes read JSON: a body sent as another media type is a 415 problem.

FastAPI reads a body as JSON only when its Content-Type is application/json or another
application/*+json type; any other body, or one without a Content-Type, reached the
models unread and came back as a 422 about the fields, which blames the content for what
is the label's fault. `require_json` answers 415 `unsupported-media-type` instead, at the
Content-Type header.
"""

from __future__ import annotations

import email.message

from fastapi import Request

from app.errors import ApiError, field_error


def is_json(content_type: str) -> bool:
    """Whether a Content-Type is JSON as FastAPI reads it (application/json or
    application/*+json, parameters aside)."""
    message = email.message.Message()
    message["content-type"] = content_type
    subtype = message.get_content_subtype()
    return message.get_content_maintype() == "application" and (
        subtype == "json" or subtype.endswith("+json"))


async def require_json(request: Request) -> None:
    """415 when the route reads a JSON body and the request sends one not labelled JSON
    (an empty body is left to the models, which say what is missing)."""
    if getattr(request.scope.get("route"), "body_field", None) is None:
        return
    content_type = request.headers.get("content-type")
    if content_type is not None and is_json(content_type) or not await request.body():
        return
    given = "no Content-Type" if content_type is None else (
        content_type.split(";")[0].strip() or "an empty media type")
    message = f"this endpoint reads a JSON body: send it as application/json, not {given}"
    raise ApiError(415, "unsupported-media-type", "The body is not JSON", message,
                   [field_error(["header", "content-type"], message, "unsupported_media_type")])
