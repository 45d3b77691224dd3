"""Running a synchronous library computation off the event loop, with ValueErrors as 422."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from anyio import CapacityLimiter, to_thread
from pydantic import BaseModel

from app.errors import from_value_error
from app.limits import check_request
from app.settings import Settings

R = TypeVar("R")


async def compute(function: Callable[[BaseModel], R], request: BaseModel,
                  settings: Settings, limiter: CapacityLimiter) -> R:
    """Check the request's limits, then run `function(request)` in a worker thread."""
    check_request(request, settings)
    try:
        return await to_thread.run_sync(function, request, limiter=limiter)
    except ValueError as exc:
        raise from_value_error(exc) from exc
