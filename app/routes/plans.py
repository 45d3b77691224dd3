"""Plan jobs: submit a scene, follow its progress, fetch the plan, cancel it."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Body, Header, Query, Response
from starlette.concurrency import run_in_threadpool

from app import stored_plan
from app.admission import admit_plan
from app.capacity import capacity_errors
from app.deps import RunnerDep, SettingsDep, StoreDep
from app.errors import ApiError, field_error, invalid
from app.jobs import JobRunner, QueueFull
from app.limits import check_scene
from app.openapi import UNAVAILABLE, problems
from app.schema_examples import body_examples
from app.schemas import Job, JobList, JobSummary
from app.store import FINAL, DuplicateKey, JobRecord, JobStatus, JobStore
from planner.service import Plan, Scene

router = APIRouter(prefix="/v1/plans", tags=["plans"])
_LINKS = {name: {"operationId": op, "parameters": {"job_id": "$response.body#/id"}}
          for name, op in (("GetPlan", "get_plan"), ("CancelPlan", "cancel_plan"))}


def current_plan(record: JobRecord, use: str) -> Plan:
    """The job's plan (it has one) under today's schema, or a 409 `legacy-plan` saying
    that `use` ("a plot", "sampling") needs one."""
    plan = stored_plan.current(record.plan or {})
    if plan is None:
        raise ApiError(409, "legacy-plan", "The plan is of another schema",
                       f"plan job {record.id!r} holds a plan stored by a version of the service "
                       f"whose schema this one cannot read (plan_schema legacy); {use} needs "
                       "a plan of today's schema: submit the scene again")
    return plan


def _found_key(job_id: str | None) -> str:
    if job_id is None:  # the other submission's job is gone again (it cannot be)
        raise ApiError(409, "conflict", "Idempotency key in use", "retry the request")
    return job_id


def _found(record: JobRecord | None, job_id: str) -> JobRecord:
    if record is None:
        raise ApiError(404, "not-found", "No such plan job", f"there is no plan job {job_id!r}")
    return record


@router.post("", status_code=202, summary="Submit a scene for planning",
             responses={200: {"model": Job, "description": "the job ended within `wait`"},
                        202: {"description": "queued; poll the Location", "links": _LINKS},
                        **problems(429, 503, s503=UNAVAILABLE)})
async def create_plan(scene: Annotated[Scene, Body(openapi_examples=body_examples("plan"))],
                      response: Response, settings: SettingsDep,
                      runner: RunnerDep, store: StoreDep,
                      wait: Annotated[float, Query(ge=0.0, description=(
                          "seconds to wait for the job to end (at most UNDERTOW_MAX_WAIT)"))] = 0.0,
                      idempotency_key: Annotated[str | None, Header(
                          min_length=1, max_length=200, description=(
                              "a key of the client's choosing: a second submission with the "
                              "same key creates no job and answers with the first one"))] = None
                      ) -> Job:
    if wait > settings.max_wait:
        raise invalid([field_error(["query", "wait"], f"at most {settings.max_wait:g} s on "
                                   "this server (UNDERTOW_MAX_WAIT)", "limit")])
    scene = check_scene(scene, settings)
    too_big = capacity_errors(scene, settings)
    if too_big:
        raise invalid(too_big)
    admission = await run_in_threadpool(admit_plan, store, scene)
    job_id = uuid.uuid4().hex
    try:
        earlier = (None if idempotency_key is None
                   else await run_in_threadpool(store.find_key, idempotency_key))
        if earlier is None:
            await run_in_threadpool(runner.submit, scene.model_dump(mode="json"), job_id,
                                    idempotency_key, admission.model_dump(mode="json"))
        else:
            job_id = earlier
    except DuplicateKey as exc:  # submitted concurrently with the same key
        job_id = _found_key(await run_in_threadpool(store.find_key, str(exc.args[0])))
    except QueueFull as exc:
        raise ApiError(429, "queue-full", "The job queue is full",
                       f"this server already holds {runner.capacity} unfinished plans; "
                       f"retry in {exc.retry_after} s",
                       headers={"Retry-After": str(exc.retry_after)}) from exc
    if wait > 0.0:
        await runner.wait(job_id, wait)
    record = _found(await run_in_threadpool(store.get, job_id), job_id)
    response.headers["Location"] = f"/v1/plans/{job_id}"
    response.status_code = 200 if record.status in FINAL else 202
    return Job.of(record)


@router.get("", summary="List plan jobs, newest first")
async def list_plans(store: StoreDep,
                     status: Annotated[JobStatus | None, Query()] = None,
                     limit: Annotated[int, Query(ge=1, le=100)] = 20,
                     offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
                     dead_letter: Annotated[bool | None, Query(description=(
                         "true: only dead letters (failed for infrastructure reasons more "
                         "often than UNDERTOW_MAX_RETRIES allows); false: none of them"))] = None
                     ) -> JobList:
    records = await run_in_threadpool(store.list, status, limit + 1, offset, dead_letter, True)
    items = [JobSummary.of(r) for r in records[:limit]]
    return JobList(items=items, limit=limit, offset=offset,
                   next_offset=offset + limit if len(records) > limit else None)


@router.get("/{job_id}", summary="A plan job: status, progress, and the plan when done",
            responses=problems(404))
async def get_plan(job_id: str, store: StoreDep) -> Job:
    return Job.of(_found(await run_in_threadpool(store.get, job_id), job_id))


def _cancel(store: JobStore, job_id: str) -> JobRecord:
    before = _found(store.get(job_id), job_id)
    if before.status in ("succeeded", "failed"):
        raise ApiError(409, "already-finished", "The job has already ended",
                       f"plan job {job_id!r} ended as {before.status}; nothing to cancel")
    return _found(store.request_cancel(job_id), job_id)


def _retry(runner: JobRunner, job_id: str) -> JobRecord:
    before = _found(runner.store.get(job_id), job_id)
    if before.status not in ("failed", "cancelled"):
        raise ApiError(409, "not-finished", "Only a failed or cancelled job can be retried",
                       f"plan job {job_id!r} is {before.status}")
    if not runner.retry(job_id):
        now = _found(runner.store.get(job_id), job_id)
        if now.status not in ("failed", "cancelled"):  # retried meanwhile by someone else
            return now
        raise ApiError(429, "queue-full", "The job queue is full",
                       f"this server already holds {runner.capacity} unfinished plans; "
                       f"retry in {runner.retry_after} s",
                       headers={"Retry-After": str(runner.retry_after)})
    return _found(runner.store.get(job_id), job_id)


@router.post("/{job_id}/retry", status_code=202, summary="Queue a failed or cancelled plan "
             "job again, by id (a dead letter included)",
             responses={202: {"description": "queued again; poll the Location"},
                        **problems(404, 409, 429, 503, s503=UNAVAILABLE)})
async def retry_plan(job_id: str, runner: RunnerDep, response: Response) -> Job:
    record = await run_in_threadpool(_retry, runner, job_id)
    response.headers["Location"] = f"/v1/plans/{job_id}"
    return Job.of(record)


@router.delete("/{job_id}", summary="Cancel a plan job (Ipopt stops at its next iteration)",
               responses={200: {"model": Job, "description": "the job is cancelled"},
                          202: {"description": "cancellation requested; the solver stops "
                                "at its next iteration"}, **problems(404, 409)})
async def cancel_plan(job_id: str, store: StoreDep, response: Response) -> Job:
    record = await run_in_threadpool(_cancel, store, job_id)
    response.status_code = 200 if record.status in FINAL else 202
    return Job.of(record)
