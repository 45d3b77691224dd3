"""Response schemas of the job endpoints (request schemas come from `planner`)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

from pydantic import BaseModel, Field

from app import stored_plan
from app.store import FINAL, STATUSES, BatchRecord, JobRecord, JobStatus, MemberRecord
from app.stored_plan import PlanSchema, StoredPlan
from planner.service import Plan


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


class JobEvent(BaseModel):
    """One entry of a job's history."""

    at: datetime
    event: Literal["claimed", "released", "infrastructure-failure", "retried", "finished"]
    worker: str | None = Field(default=None, description="the worker that held the job")
    reason: str | None = Field(default=None, description="why (the final status for "
                               "`finished`)")


class JobSummary(BaseModel):
    """A plan job without its plan."""

    id: str
    status: JobStatus = Field(description="queued, running, succeeded (the solver converged), "
                              "failed (solver failure or error; or a dead letter), cancelled")
    progress: JobProgress | None
    error: str | None = Field(description="why the job failed or was cancelled")
    cancel_requested: bool
    created: datetime
    started: datetime | None
    finished: datetime | None
    attempts: int = Field(default=0, description="claims the job has had (a claim released "
                          "by a stopping node is not counted)")
    infra_failures: int = Field(default=0, description=(
        "infrastructure failures the job has had (worker process or node died, lease ran "
        "out, server stopped under it); each requeued it, up to UNDERTOW_MAX_RETRIES"))
    dead_letter: bool = Field(default=False, description=(
        "failed because infrastructure failed it more often than UNDERTOW_MAX_RETRIES "
        "allows (not the solver's verdict); POST /v1/plans/{id}/retry queues it again"))

    @classmethod
    def of(cls, record: JobRecord) -> JobSummary:
        return cls(**_fields(record))


class Job(JobSummary):
    """A plan job; `plan` is set once the solver returned (also for failed or cancelled
    jobs: then it is the solver's last iterate)."""

    plan: Plan | StoredPlan | None = Field(description=(
        "the plan: a `Plan` when `plan_schema` is current; as stored, unvalidated, when it "
        "is legacy"))
    plan_schema: PlanSchema | None = Field(default=None, description=(
        "current: `plan` follows today's Plan schema; legacy: it was stored by a version "
        "of the service whose schema this one cannot read, and is served as stored "
        "(non-finite numbers as null; no figure, sample or warm start from it); null "
        "without a plan"))
    history: list[JobEvent] = Field(default_factory=list, description=(
        "claims, releases, infrastructure failures, retries and the verdict, oldest first"))

    @classmethod
    def of(cls, record: JobRecord) -> Job:
        plan = None if record.plan is None else stored_plan.read(record.plan)
        return cls(**_fields(record), plan=plan, plan_schema=stored_plan.schema_of(plan),
                   history=record.history or [])


def _fields(record: JobRecord) -> dict:
    return {"id": record.id, "status": record.status, "progress": record.progress,
            "error": record.error, "cancel_requested": record.cancel_requested,
            "created": _time(record.created), "started": _time(record.started),
            "finished": _time(record.finished), "attempts": record.attempts,
            "infra_failures": record.infra_failures, "dead_letter": record.dead_letter}


class JobList(BaseModel):
    """A page of jobs, newest first."""

    items: list[JobSummary]
    limit: int
    offset: int
    next_offset: int | None = Field(description="offset of the next page; null on the last")


class BatchMember(BaseModel):
    """One member of a batch: its parameters and how its plan job went."""

    index: int
    job_id: str = Field(description="the member's plan job, at /v1/plans/{job_id}")
    parameters: dict[str, float] = Field(description="what the member sets on the base scene")
    status: JobStatus
    verified: bool | None = Field(description="the plan passed its re-simulation check "
                                  "(null until the job has a plan)")
    objective: float | None = Field(description="the plan's objective (null without a plan)")
    time: float | None = Field(description="wall time from the job's claim to its verdict "
                                           "[s] (null until it ends)")
    error: str | None

    @classmethod
    def of(cls, member: MemberRecord, parameters: dict[str, float]) -> BatchMember:
        time = (member.finished - member.started
                if member.finished is not None and member.started is not None else None)
        return cls(index=member.index, job_id=member.job_id, parameters=parameters,
                   status=member.status, verified=member.verified, objective=member.objective,
                   time=time, error=member.error)


class Batch(BaseModel):
    """A batch sweep: aggregate progress and the summary table of its members."""

    id: str
    created: datetime
    size: int = Field(description="members")
    counts: dict[str, int] = Field(description="members in each status")
    finished: int = Field(description="members whose job has ended (succeeded, failed or "
                          "cancelled)")
    verified: int = Field(description="members that succeeded with a plan that passed its "
                          "re-simulation check")
    members: list[BatchMember]

    @classmethod
    def of(cls, record: BatchRecord) -> Batch:
        counts: dict[str, int] = dict.fromkeys(STATUSES, 0)
        for member in record.members:
            counts[member.status] += 1
        parameters = record.spec["parameters"]
        return cls(id=record.id, created=_time(record.created), size=len(record.members),
                   counts=counts, finished=sum(counts[s] for s in FINAL),
                   verified=sum(m.status == "succeeded" and bool(m.verified)
                                for m in record.members),
                   members=[BatchMember.of(m, parameters[m.index]) for m in record.members])


class Health(BaseModel):
    """Liveness."""

    status: str = "ok"
