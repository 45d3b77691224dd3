"""The undertow HTTP service: `app.main:app`.

`create_app(settings, solve)` builds an app; its lifespan opens the job store (SQLite, or
PostgreSQL when UNDERTOW_DB_URL is set; refusing to start on one that fails its integrity
check, cannot be reached, or has a schema newer than this version knows), takes the
server's name on it (refusing to start while a live server of that name runs on it),
recovers jobs a previous run left behind, and starts the solver workers (none on an
API-only server); on shutdown it stops them, checkpoints the store and gives the name
back.
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from anyio import CapacityLimiter
from fastapi import Depends, FastAPI, Request
from fastapi.responses import JSONResponse
from fastapi_offline import FastAPIOffline

from app import errors, startup_objects, viewer
from app.auth import ApiKeyMiddleware
from app.body_limit import BodyLimitMiddleware
from app.deps import require_api_key
from app.job_run import SolveFunction
from app.jobs import JobRunner
from app.logging import RequestIdMiddleware, configure
from app.media_type import require_json
from app.metrics import Metrics, MetricsMiddleware
from app.openapi import document
from app.refusal import QuietRefusal, refuse
from app.routes import (
    batches,
    dynamics,
    examples,
    health,
    plans,
    plots,
    samples,
    sessions,
    workers,
)
from app.sessions import Sessions
from app.settings import PLAN_PROCESSES, Settings, get_settings
from app.store import StoreDamaged, StoreUnavailable
from app.store.open import open_store
from app.store_wait import StoreWaitMiddleware
from app.sync_memory import MemoryBudget
from app.worker import load_function
from planner import prebuild

log = logging.getLogger("undertow.main")

DESCRIPTION = """Feed-forward torque planning for underactuated planar manipulators whose
active joints carry a small-amplitude wave. Angles in radians, SI units, 0-based joint
indices, time-major trajectories. Errors are RFC 9457 problem details."""


def create_app(settings: Settings | None = None, solve: SolveFunction | None = None) -> FastAPI:
    """An app for `settings` (default: from the environment); `solve` replaces the
    configured solve function (it must be a module-level function)."""
    settings = settings or get_settings()
    configure(settings.log_level)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        runner = _start(app, settings, solve)
        builder = prebuild.start()  # the examples' compiled kernels, at the lowest priority
        app.state.store, app.state.runner = runner.store, runner
        app.state.limiter = CapacityLimiter(settings.compute_threads)
        app.state.sync_memory = MemoryBudget(settings.sync_memory_mb)
        app.state.metrics.watch_memory(app.state.sync_memory)
        sweeper = asyncio.create_task(_sweep_sessions(app.state.sessions))
        startup_objects.freeze()
        try:
            yield
        finally:
            sweeper.cancel()
            runner.shutdown()
            if builder is not None and builder.poll() is None:
                builder.terminate()

    app = FastAPIOffline(title="undertow", version="0.1.0", description=DESCRIPTION,
                         lifespan=lifespan, generate_unique_id_function=lambda route: route.name)
    app.state.settings = settings
    app.state.metrics = Metrics()
    app.state.quick_limiter = CapacityLimiter(settings.quick_threads)
    app.state.sessions = Sessions(settings.max_sessions, settings.session_idle)
    errors.install(app)
    app.exception_handler(StoreUnavailable)(_store_unavailable)
    app.include_router(health.router)
    secured = [Depends(require_api_key), Depends(require_json)]
    for router in (dynamics.router, plans.router, batches.router, examples.router,
                   plots.router, samples.router, sessions.router, workers.router):
        app.include_router(router, dependencies=secured)
    _add_middleware(app, settings)
    app.openapi = lambda: document(app)  # type: ignore[method-assign]  # FastAPI's documented override of its schema
    app.router.routes.extend(viewer.routes())
    return app


async def _sweep_sessions(live: Sessions) -> None:
    """Free the sessions left idle, every quarter of the idle time (at most 5 s), so that
    an abandoned one goes without a further request."""
    while True:
        await asyncio.sleep(min(live.idle / 4, 5.0))
        freed = live.sweep()
        if freed:
            log.info("freed %d idle replanning session(s)", freed)


def _start(app: FastAPI, settings: Settings, solve: SolveFunction | None) -> JobRunner:
    """Open the store and start the job runner on it. A start refused (a damaged or
    unreachable store, the server's name held by a live server) is one log line and
    touches nothing more in the store (`app.refusal`)."""
    try:
        store = open_store(settings)
    except StoreUnavailable as exc:
        refuse(app, exc)
    app.state.metrics.watch(store)
    os.environ[PLAN_PROCESSES] = str(settings.plan_processes())
    runner = JobRunner(store, solve or load_function(settings.solve_function),
                       owner=settings.instance, workers=settings.workers,
                       max_queued=settings.max_queued, retry_after=settings.retry_after,
                       memory_mb=settings.worker_memory_mb,
                       grace=settings.wall_time_grace, log_level=settings.log_level,
                       on_done=app.state.metrics.job_done, lease=settings.lease,
                       retention=settings.retention(), drain=settings.drain)
    try:
        runner.start()
    except StoreUnavailable as exc:
        store.close()
        refuse(app, exc)
    return runner


def _add_middleware(app: FastAPI, settings: Settings) -> None:
    """The app's middleware, innermost first: a request passes the request id, the metrics,
    the API key, the body limit, the catch-all for unexpected errors and the bound on its
    store waits, in that order; the lifespan passes `QuietRefusal`."""
    app.add_middleware(StoreWaitMiddleware)
    app.add_middleware(errors.UnexpectedErrorMiddleware)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_body_bytes,
                       timeout=settings.read_timeout)
    app.add_middleware(ApiKeyMiddleware, key=settings.api_key)
    app.add_middleware(MetricsMiddleware, metrics=app.state.metrics)
    app.add_middleware(RequestIdMiddleware)
    app.add_middleware(QuietRefusal)


async def _store_unavailable(request: Request, exc: StoreUnavailable) -> JSONResponse:
    """503 for any request that needed the job store while it could not be used, or
    once it was found damaged (type store-damaged)."""
    log.error("%s", exc)
    if isinstance(exc, StoreDamaged):
        return errors.problem(request, health.damaged(str(exc)))
    return errors.problem(request, health.unavailable(str(exc), request.app.state.settings))


app = create_app()
