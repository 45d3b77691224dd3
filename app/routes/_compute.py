"""Running a synchronous library computation off the event loop, bounded in time.

A request is checked against the server's limits, waits at most UNDERTOW_COMPUTE_WAIT
for a compute thread (503 with Retry-After when none comes free), and runs with a
deadline UNDERTOW_SYNC_WALL_TIME after it arrived: the library stops there by itself
(`planner.budget`), and the answer is a 422 `budget-exceeded` problem. Quick requests
(dynamics or coupling at few points) have threads of their own, so that they are
answered while long computations hold every other thread. What the library refuses as
the caller's mistake (`planner.errors.InputError`) is a 422 at the field it names; any
other exception, a plain ValueError included, is a bug and goes on to become a 500.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Annotated, TypeVar

import anyio
from anyio import CapacityLimiter, to_thread
from fastapi import Depends, Request
from pydantic import BaseModel

from app.errors import ApiError, from_input_error
from app.limits import check_request, points
from app.settings import Settings
from planner.budget import BudgetExceeded
from planner.errors import InputError

R = TypeVar("R")


@dataclass(frozen=True)
class Lanes:
    """The compute threads: `main` for every computation, `quick` kept for quick ones."""

    main: CapacityLimiter
    quick: CapacityLimiter


def _lanes(request: Request) -> Lanes:
    return Lanes(main=request.app.state.limiter, quick=request.app.state.quick_limiter)


LanesDep = Annotated[Lanes, Depends(_lanes)]


def busy(settings: Settings) -> ApiError:
    """503: no compute thread came free in time."""
    return ApiError(503, "busy", "Every compute thread is busy",
                    f"no compute thread came free within {settings.compute_wait:g} s "
                    f"(UNDERTOW_COMPUTE_WAIT); retry in {settings.retry_after} s",
                    headers={"Retry-After": str(settings.retry_after)})


def over_budget(exc: BudgetExceeded, settings: Settings) -> ApiError:
    """422: the computation stopped at its deadline."""
    return ApiError(422, "budget-exceeded", "The computation ran out of time",
                    f"{exc}: this server gives a synchronous computation "
                    f"{settings.sync_wall_time:g} s (UNDERTOW_SYNC_WALL_TIME); ask for less "
                    "(fewer points, samples or starts, a shorter motion)")


async def compute(function: Callable[..., R], request: BaseModel, settings: Settings,
                  lanes: Lanes, quick: bool = False) -> R:
    """Check the request's limits, then run `function(request, deadline=...)` in a
    worker thread; `quick`: the request may take a quick thread when it is small."""
    deadline = time.monotonic() + settings.sync_wall_time
    check_request(request, settings)
    limiter = lanes.quick if quick and points(request) <= settings.quick_points else lanes.main
    acquired = False
    with anyio.move_on_after(min(settings.compute_wait, settings.sync_wall_time)):
        await limiter.acquire()
        acquired = True
    if not acquired:
        raise busy(settings)
    try:
        return await to_thread.run_sync(partial(function, request, deadline=deadline))
    except BudgetExceeded as exc:
        raise over_budget(exc, settings) from exc
    except InputError as exc:
        raise from_input_error(exc) from exc
    finally:
        limiter.release()
