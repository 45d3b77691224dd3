"""The live solver workers: every server with workers of its own and every worker node
sharing the job store, as their supervisors' heartbeats (every 5 s) left them."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from fastapi import APIRouter
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from app.deps import StoreDep
from app.supervisor import HEARTBEAT

router = APIRouter(prefix="/v1/workers", tags=["service"])
LIVE = 3 * HEARTBEAT  # [s] a supervisor silent longer than this is not listed


class WorkerInfo(BaseModel):
    """One server's or worker node's solver processes."""

    name: str = Field(description="the server's UNDERTOW_INSTANCE, or a node's "
                      "{instance}:worker:{pid}; its running jobs' `worker` starts with it")
    processes: int = Field(description="solver processes")
    busy: int = Field(description="solver processes running a job")
    started: datetime
    seen: datetime = Field(description="its last heartbeat")


class WorkerList(BaseModel):
    """The supervisors heard from within the last 15 s, by name."""

    items: list[WorkerInfo]
    processes: int = Field(description="solver processes of all of them")
    busy: int = Field(description="of which running a job")


@router.get("", summary="The live solver workers: servers with workers and worker nodes "
            "sharing the job store")
async def list_workers(store: StoreDep) -> WorkerList:
    records = await run_in_threadpool(store.workers, time.time() - LIVE)
    items = [WorkerInfo(name=r.name, processes=r.processes, busy=r.busy,
                        started=datetime.fromtimestamp(r.started, UTC),
                        seen=datetime.fromtimestamp(r.seen, UTC)) for r in records]
    return WorkerList(items=items, processes=sum(r.processes for r in records),
                      busy=sum(r.busy for r in records))
