"""Running a synchronous library computation off the event loop, bounded in time and
memory.

A request is checked against the server's limits and its memory estimate against
UNDERTOW_SYNC_MEMORY_MB (`app.sync_memory`: 422 at the field when it alone needs more),
then waits at most UNDERTOW_COMPUTE_WAIT for room in that memory budget beside the
computations running and for a compute thread (503 `busy` with Retry-After when either
does not come), and runs with a deadline UNDERTOW_SYNC_WALL_TIME after it arrived: the
library stops there by itself (`planner.budget`), and the answer is a 422
`budget-exceeded` problem. Quick requests (dynamics or coupling at few points) have
threads of their own and reserve no memory, so that they are answered while long
computations hold every other thread or the whole budget. What the library refuses as
the caller's mistake (`planner.errors.InputError`) is a 422 at the field it names; any
other exception, a plain ValueError included, is a bug and goes on to become a 500.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from functools import partial
from typing import Annotated, TypeVar

import anyio
from anyio import CapacityLimiter, to_thread
from fastapi import Depends, Request
from pydantic import BaseModel

from app.errors import ApiError, from_input_error, invalid
from app.limits import check_request, points
from app.settings import Settings
from app.sync_memory import MemoryBudget, estimate, too_large
from planner.budget import BudgetExceeded
from planner.errors import InputError

R = TypeVar("R")


@dataclass(frozen=True)
class Lanes:
    """The compute threads (`main` for every computation, `quick` kept for quick ones) and
    the memory budget the computations on `main` share."""

    main: CapacityLimiter
    quick: CapacityLimiter
    memory: MemoryBudget


def _lanes(request: Request) -> Lanes:
    state = request.app.state
    return Lanes(main=state.limiter, quick=state.quick_limiter, memory=state.sync_memory)


LanesDep = Annotated[Lanes, Depends(_lanes)]


def busy(settings: Settings) -> ApiError:
    """503: no compute thread came free in time."""
    return ApiError(503, "busy", "Every compute thread is busy",
                    f"no compute thread came free within {settings.compute_wait:g} s "
                    f"(UNDERTOW_COMPUTE_WAIT); retry in {settings.retry_after} s",
                    headers={"Retry-After": str(settings.retry_after)})


def memory_busy(settings: Settings, mb: float, budget: MemoryBudget) -> ApiError:
    """503: the computations running left no room in the memory budget in time."""
    return ApiError(503, "busy", "The synchronous computations are at their memory bound",
                    f"the synchronous computations running hold {budget.used:.0f} MB of the "
                    f"{budget.total:.0f} MB this server gives them (UNDERTOW_SYNC_MEMORY_MB) "
                    f"and this one needs about {mb:.0f} MB; no room came free within "
                    f"{settings.compute_wait:g} s (UNDERTOW_COMPUTE_WAIT); retry in "
                    f"{settings.retry_after} s",
                    headers={"Retry-After": str(settings.retry_after)})


def over_budget(exc: BudgetExceeded, settings: Settings) -> ApiError:
    """422: the computation stopped at its deadline."""
    return ApiError(422, "budget-exceeded", "The computation ran out of time",
                    f"{exc}: this server gives a synchronous computation "
                    f"{settings.sync_wall_time:g} s (UNDERTOW_SYNC_WALL_TIME); ask for less "
                    "(fewer points, samples or starts, a shorter motion)")


@asynccontextmanager
async def running(settings: Settings, lanes: Lanes, mb: float,
                  quick: bool = False) -> AsyncIterator[None]:
    """Hold `mb` of the memory budget (none: 0) and a compute thread (`quick`: a quick
    one) while the block runs, both found within UNDERTOW_COMPUTE_WAIT (and the budget
    UNDERTOW_SYNC_WALL_TIME); 503 `busy` when either is not."""
    wait_until = time.monotonic() + min(settings.compute_wait, settings.sync_wall_time)
    if mb > 0.0 and not await lanes.memory.reserve(mb, wait_until - time.monotonic()):
        raise memory_busy(settings, mb, lanes.memory)
    try:
        limiter = lanes.quick if quick else lanes.main
        try:
            limiter.acquire_nowait()
        except anyio.WouldBlock:
            acquired = False
            with anyio.move_on_after(max(wait_until - time.monotonic(), 0.0)):
                await limiter.acquire()
                acquired = True
            if not acquired:
                raise busy(settings) from None
        try:
            yield
        finally:
            limiter.release()
    finally:
        if mb > 0.0:
            await lanes.memory.release(mb)


async def compute(function: Callable[..., R], request: BaseModel, settings: Settings,
                  lanes: Lanes, quick: bool = False) -> R:
    """Check the request's limits and memory estimate, then run `function(request,
    deadline=...)` in a worker thread; `quick`: the request may take a quick thread
    (reserving no memory) when it is small."""
    deadline = time.monotonic() + settings.sync_wall_time
    check_request(request, settings)
    small = quick and points(request) <= settings.quick_points
    mb = 0.0
    if not small:
        need = estimate(request)
        too_big = too_large(need, settings)
        if too_big:
            raise invalid(too_big)
        mb = need.mb
    async with running(settings, lanes, mb, quick=small):
        try:
            return await to_thread.run_sync(partial(function, request, deadline=deadline))
        except BudgetExceeded as exc:
            raise over_budget(exc, settings) from exc
        except InputError as exc:
            raise from_input_error(exc) from exc
