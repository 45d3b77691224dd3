"""Batch sweeps: one plan job per member of a sweep over a base scene, and their summary."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Body, Response
from starlette.concurrency import run_in_threadpool

from app.deps import RunnerDep, SettingsDep, StoreDep
from app.errors import ApiError
from app.jobs import QueueFull
from app.openapi import UNAVAILABLE, problems
from app.routes.plans import check_warm_start
from app.schema_examples import body_examples
from app.schemas import Batch
from app.store import BatchRecord
from app.sweep import BatchRequest, members, scenes

router = APIRouter(prefix="/v1/batches", tags=["batches"])


def _found(record: BatchRecord | None, batch_id: str) -> BatchRecord:
    if record is None:
        raise ApiError(404, "not-found", "No such batch", f"there is no batch {batch_id!r}")
    return record


@router.post("", status_code=202, summary="Submit a sweep: one plan job per member",
             responses={202: {"description": "queued; poll the Location"},
                        **problems(429, 503, s503=UNAVAILABLE)})
async def create_batch(request: Annotated[BatchRequest, Body(
                           openapi_examples=body_examples("batch"))],
                       response: Response, settings: SettingsDep, runner: RunnerDep,
                       store: StoreDep) -> Batch:
    parameters = members(request, settings)
    member_scenes = scenes(request, parameters, settings)
    if request.base.solver.warm_start is not None:
        await run_in_threadpool(check_warm_start, store, request.base.solver.warm_start,
                                ("body", "base"))
    batch_id = uuid.uuid4().hex
    spec = {"base": request.base.model_dump(mode="json"), "parameters": parameters}
    jobs = [(f"{batch_id}-{k:04d}", scene) for k, scene in enumerate(member_scenes)]
    try:
        await run_in_threadpool(runner.submit_batch, batch_id, spec, jobs)
    except QueueFull as exc:
        raise ApiError(429, "queue-full", "The job queue is full",
                       f"{len(jobs)} more plans would exceed the {runner.capacity} unfinished "
                       f"plans this server may hold; retry in {exc.retry_after} s",
                       headers={"Retry-After": str(exc.retry_after)}) from exc
    response.headers["Location"] = f"/v1/batches/{batch_id}"
    return Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))


@router.get("/{batch_id}", summary="A batch: aggregate progress and a summary table of its "
            "members (status, verified, objective, time)", responses=problems(404))
async def get_batch(batch_id: str, store: StoreDep) -> Batch:
    return Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))
