"""Batch sweeps: one plan job per member of a sweep over a base scene, their summary (JSON,
or CSV for a spreadsheet), and their cancellation."""

from __future__ import annotations

import csv
import io
import uuid
from typing import Annotated, Any

from fastapi import APIRouter, Body, Request, Response
from starlette.concurrency import run_in_threadpool

from app.admission import admit_members
from app.deps import RunnerDep, SettingsDep, StoreDep
from app.errors import ApiError
from app.jobs import QueueFull
from app.openapi import UNAVAILABLE, problems
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
    admissions = await run_in_threadpool(admit_members, store, request.base, member_scenes)
    batch_id = uuid.uuid4().hex
    spec = {"base": request.base.model_dump(mode="json"), "parameters": parameters}
    jobs = [(f"{batch_id}-{k:04d}", scene.model_dump(mode="json"))
            for k, scene in enumerate(member_scenes)]
    try:
        await run_in_threadpool(runner.submit_batch, batch_id, spec, jobs,
                                settings.max_batch_members,
                                [admission.model_dump(mode="json") for admission in admissions])
    except QueueFull as exc:
        raise ApiError(429, "queue-full", "The job queue is full",
                       f"{len(jobs)} more plans would exceed the "
                       f"{runner.capacity + settings.max_batch_members} unfinished plans this "
                       f"server may hold with a batch; retry in {exc.retry_after} s",
                       headers={"Retry-After": str(exc.retry_after)}) from exc
    response.headers["Location"] = f"/v1/batches/{batch_id}"
    return Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))


CSV = "text/csv"
_CSV_COLUMNS = ("index", "job_id", "status", "verified", "objective", "time", "error")


def batch_csv(batch: Batch) -> str:
    """The members' table as CSV: index, job id, the swept parameters (one column each),
    status, verified, objective, time [s], error."""
    names = list(dict.fromkeys(name for m in batch.members for name in m.parameters))
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*_CSV_COLUMNS[:2], *names, *_CSV_COLUMNS[2:]])
    for m in batch.members:
        writer.writerow([m.index, m.job_id, *(m.parameters.get(n, "") for n in names),
                         m.status, "" if m.verified is None else str(m.verified).lower(),
                         "" if m.objective is None else repr(m.objective),
                         "" if m.time is None else f"{m.time:.3f}", m.error or ""])
    return out.getvalue()


_CSV_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"content": {CSV: {"schema": {"type": "string"}}},
          "description": "one row per member (Accept: text/csv)"}}


@router.get("/{batch_id}", summary="A batch: aggregate progress and a summary table of its "
            "members (status, verified, objective, time); CSV with Accept: text/csv",
            response_model=Batch, responses={**_CSV_RESPONSE, **problems(404)})
async def get_batch(batch_id: str, store: StoreDep, request: Request) -> Batch | Response:
    batch = Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))
    accept = request.headers.get("accept", "")
    if CSV in accept and "application/json" not in accept:
        return Response(batch_csv(batch), media_type=CSV)
    return batch


@router.get("/{batch_id}/results.csv", summary="A batch's members as CSV: index, job id, the "
            "swept parameters, status, verified, objective, time, error",
            response_class=Response, responses={**_CSV_RESPONSE, **problems(404)})
async def get_batch_csv(batch_id: str, store: StoreDep) -> Response:
    batch = Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))
    return Response(batch_csv(batch), media_type=CSV, headers={
        "Content-Disposition": f'attachment; filename="batch-{batch_id}.csv"'})


@router.delete("/{batch_id}", summary="Cancel a batch: its queued members at once, its "
               "running ones at their next iteration", responses=problems(404))
async def cancel_batch(batch_id: str, store: StoreDep) -> Batch:
    if not await run_in_threadpool(store.cancel_batch, batch_id):
        _found(None, batch_id)
    return Batch.of(_found(await run_in_threadpool(store.get_batch, batch_id), batch_id))
