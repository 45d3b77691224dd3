"""Liveness and Prometheus metrics."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from app.deps import require_api_key
from app.schemas import Health

router = APIRouter(tags=["service"])


@router.get("/healthz", summary="Liveness (never needs the API key)")
async def healthz() -> Health:
    return Health()


@router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {CONTENT_TYPE_LATEST: {"schema": {"type": "string"}}},
                             "description": "metrics in the Prometheus text format"}})
async def metrics(request: Request, _: Annotated[None, Depends(require_api_key)]) -> Response:
    # collecting reads the job store (SQLite): off the event loop
    body = await run_in_threadpool(generate_latest, request.app.state.metrics.registry)
    return Response(body, media_type=CONTENT_TYPE_LATEST)
