"""Dependencies injected into routes: settings, store, job runner, API key (the compute
threads and memory budget: `app.routes._compute.LanesDep`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader

from app.auth import HEADER, accepted, unauthorized
from app.jobs import JobRunner
from app.settings import Settings
from app.store import JobStore

_api_key_header = APIKeyHeader(name=HEADER, auto_error=False,
                               description="required when the server sets UNDERTOW_API_KEY")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> JobStore:
    return request.app.state.store


def get_runner(request: Request) -> JobRunner:
    return request.app.state.runner


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[JobStore, Depends(get_store)]
RunnerDep = Annotated[JobRunner, Depends(get_runner)]


def require_api_key(settings: SettingsDep,
                    key: Annotated[str | None, Security(_api_key_header)] = None) -> None:
    """401 unless the server has no key or the request's X-API-Key matches it (also the
    OpenAPI declaration of the key; `app.auth.ApiKeyMiddleware` refuses before the body
    is read)."""
    if not accepted(settings.api_key, key):
        raise unauthorized()
