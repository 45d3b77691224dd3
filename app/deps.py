"""Dependencies injected into routes: settings, store, job runner, compute limiter, API key."""

from __future__ import annotations

import secrets
from typing import Annotated

from anyio import CapacityLimiter
from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader

from app.errors import ApiError
from app.jobs import JobRunner
from app.settings import Settings
from app.store import JobStore

_api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                               description="required when the server sets UNDERTOW_API_KEY")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> JobStore:
    return request.app.state.store


def get_runner(request: Request) -> JobRunner:
    return request.app.state.runner


def get_limiter(request: Request) -> CapacityLimiter:
    return request.app.state.limiter


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[JobStore, Depends(get_store)]
RunnerDep = Annotated[JobRunner, Depends(get_runner)]
LimiterDep = Annotated[CapacityLimiter, Depends(get_limiter)]


def require_api_key(settings: SettingsDep,
                    key: Annotated[str | None, Security(_api_key_header)] = None) -> None:
    """401 unless the server has no key or the request's X-API-Key matches it."""
    expected = settings.api_key
    if expected and not (key and secrets.compare_digest(key.encode(), expected.encode())):
        raise ApiError(401, "unauthorized", "Missing or wrong API key",
                       "send the server's API key in the X-API-Key header")
