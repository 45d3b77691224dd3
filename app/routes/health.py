"""Health and Prometheus metrics: both answer 503 while the job store or the solver
workers cannot be used, or the store was found damaged."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from app.deps import RunnerDep, SettingsDep, require_api_key
from app.errors import ApiError
from app.jobs import JobRunner
from app.openapi import UNAVAILABLE, problems
from app.schemas import Health
from app.settings import Settings

router = APIRouter(tags=["service"])


def unavailable(detail: str, settings: Settings) -> ApiError:
    """The 503 of a service whose job store or solver workers cannot be used."""
    return ApiError(503, "unavailable", "The service is unavailable", detail,
                    headers={"Retry-After": str(settings.retry_after)})


def damaged(detail: str) -> ApiError:
    """The 503 of a service whose job store failed its integrity check: no Retry-After,
    since waiting does not mend it (`detail` says what does)."""
    return ApiError(503, "store-damaged", "The job store is damaged", detail)


async def _available(runner: JobRunner, settings: Settings) -> None:
    """503 when the job store or the solver workers cannot be used (checked off the
    event loop: it reads the store; a damaged store raises StoreDamaged, `damaged`)."""
    problem = await run_in_threadpool(runner.problem)
    if problem is not None:
        raise unavailable(problem, settings)


@router.get("/healthz", summary="Health: the job store and the solver workers (never needs "
            "the API key)", responses=problems(503, s503=UNAVAILABLE))
async def healthz(runner: RunnerDep, settings: SettingsDep) -> Health:
    await _available(runner, settings)
    return Health()


@router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {CONTENT_TYPE_LATEST: {"schema": {"type": "string"}}},
                             "description": "metrics in the Prometheus text format"},
                       **problems(503, s503=UNAVAILABLE)})
async def metrics(request: Request, runner: RunnerDep, settings: SettingsDep,
                  _: Annotated[None, Depends(require_api_key)]) -> Response:
    await _available(runner, settings)
    # collecting reads the job store (SQLite): off the event loop
    body = await run_in_threadpool(generate_latest, request.app.state.metrics.registry)
    return Response(body, media_type=CONTENT_TYPE_LATEST)
