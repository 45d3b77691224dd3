"""GET /v1/plans/{id}/sample: a finished plan evaluated at any times within its duration,
by the library (`Plan.sample`, reached through `planner.service`), on a compute thread and
within the synchronous computations' memory budget (`app.routes._compute`)."""

from __future__ import annotations

from typing import Annotated

from anyio import to_thread
from fastapi import APIRouter, Query

from app.deps import SettingsDep, StoreDep
from app.errors import ApiError, field_error, invalid
from app.openapi import problems
from app.routes._compute import LanesDep, running
from app.routes.plans import current_plan
from app.store import JobRecord
from app.sync_memory import PLAN_SAMPLE_MB
from planner.errors import InputError
from planner.service import MAX_SAMPLE_TIMES, PlanSample, Scene

router = APIRouter(prefix="/v1/plans", tags=["plans"])


def _sample(record: JobRecord | None, job_id: str, times: list[float]) -> PlanSample:
    if record is None:
        raise ApiError(404, "not-found", "No such plan job", f"there is no plan job {job_id!r}")
    if record.plan is None:
        why = f" ({record.error})" if record.error else ""
        raise ApiError(409, "no-plan", "The job has no plan yet",
                       f"plan job {job_id!r} is {record.status}{why}; sampling needs its plan")
    plan = current_plan(record, "sampling")
    if plan.states is None or plan.torque is None:
        raise ApiError(409, "no-states", "The plan cannot be sampled",
                       f"plan job {job_id!r} was stored before plans kept their states")
    try:
        return plan.sample(Scene.model_validate(record.scene).robot, times)
    except InputError as exc:
        raise invalid([field_error(["query"], str(exc))]) from exc


@router.get("/{job_id}/sample", responses=problems(404, 409, 503),
            summary="The plan at given times: angles, rates, delivered torque, tip, sigma_min")
async def sample_plan(job_id: str, store: StoreDep, settings: SettingsDep, lanes: LanesDep,
                      t: Annotated[list[float], Query(min_length=1, description=(
                          f"times [s] within [0, duration], repeated (?t=0.1&t=0.5); at "
                          f"most {MAX_SAMPLE_TIMES}"))]) -> PlanSample:
    record = await to_thread.run_sync(store.get, job_id)
    async with running(settings, lanes, PLAN_SAMPLE_MB):
        return await to_thread.run_sync(_sample, record, job_id, t)
