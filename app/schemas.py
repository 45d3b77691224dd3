"""Response schemas of the job endpoints (request schemas come from `planner`)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

from pydantic import BaseModel, Field

from app.store import JobRecord, JobStatus
from planner.ocp.result import Plan


def _time(seconds: float | None) -> datetime | None:
    return None if seconds is None else datetime.fromtimestamp(seconds, UTC)


class JobProgress(BaseModel):
    """How far a running job is: `building` from its start until Ipopt's first iteration
    (iteration 0, no figures yet), then `solving` with Ipopt's latest iteration (None
    where Ipopt gave no finite value)."""

    phase: Literal["building", "solving"] = Field(
        default="solving", description="building: the NLP is being built; solving: Ipopt runs")
    iteration: int
    objective: float | None
    inf_pr: float | None = Field(description="primal infeasibility")
    inf_du: float | None = Field(description="dual infeasibility")
    elapsed: float = Field(description="wall time since the solve started [s] (0 while "
                           "building)")
    mesh_pass: int = Field(default=0, description="the mesh pass the solve belongs to (0: the "
                           "first mesh)")


class JobSummary(BaseModel):
    """A plan job without its plan."""

    id: str
    status: JobStatus = Field(description="queued, running, succeeded (the solver converged), "
                              "failed (solver failure, error or interruption), cancelled")
    progress: JobProgress | None
    error: str | None = Field(description='why the job failed ("interrupted": the server '
                              "stopped during the solve) or was cancelled")
    cancel_requested: bool
    created: datetime
    started: datetime | None
    finished: datetime | None

    @classmethod
    def of(cls, record: JobRecord) -> JobSummary:
        return cls(**_fields(record))


class Job(JobSummary):
    """A plan job; `plan` is set once the solver returned (also for failed or cancelled
    jobs: then it is the solver's last iterate)."""

    plan: Plan | None

    @classmethod
    def of(cls, record: JobRecord) -> Job:
        return cls(**_fields(record), plan=record.plan)


def _fields(record: JobRecord) -> dict:
    return {"id": record.id, "status": record.status, "progress": record.progress,
            "error": record.error, "cancel_requested": record.cancel_requested,
            "created": _time(record.created), "started": _time(record.started),
            "finished": _time(record.finished)}


class JobList(BaseModel):
    """A page of jobs, newest first."""

    items: list[JobSummary]
    limit: int
    offset: int
    next_offset: int | None = Field(description="offset of the next page; null on the last")


class Health(BaseModel):
    """Liveness."""

    status: str = "ok"
