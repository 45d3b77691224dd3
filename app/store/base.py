"""The job store interface: what the service needs from a database of plan jobs.

A store must be safe to use from several threads and processes at once, and picklable:
worker processes receive the store object and reopen it on their side.

Workers take jobs by claiming them: one conditional update turns the oldest queued job
into a running one that names its worker and holds a lease until a given time. Whoever
supervises the worker renews the lease while the worker lives; a running job whose lease
ran out has lost its worker (killed, or its machine lost) and whoever notices (`expire`:
any server or worker sharing the store) requeues it once; a job that loses its worker a
second time (`MAX_ATTEMPTS` claims) is marked interrupted, and one whose cancel was
requested is cancelled.

A batch is a set of jobs created together (one transaction) with the specification they
came from; its members are read back with the few figures of their plans a summary needs.
"""

from __future__ import annotations

import builtins
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Literal

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
STATUSES: tuple[JobStatus, ...] = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL: frozenset[str] = frozenset({"succeeded", "failed", "cancelled"})
INTERRUPTED = "interrupted"
MAX_ATTEMPTS = 2
"""Claims a job may have: a job whose lease ran out is requeued until it has had these."""
CANCELLED_ON_REQUEST = "cancelled on request"
BUILDING: dict[str, Any] = {"phase": "building", "iteration": 0, "objective": None,
                            "inf_pr": None, "inf_du": None, "elapsed": 0.0, "mesh_pass": 0}
"""The progress of a job from its claim until the solver's first iteration."""


class StoreUnavailable(Exception):
    """The store cannot be used (file deleted or replaced, disk error, damaged database)."""


class StoreDamaged(StoreUnavailable):
    """The store failed its integrity check; the service must not start on it."""


@dataclass(frozen=True)
class JobRecord:
    """One stored job. Times are Unix seconds; scene, progress and plan are JSON objects.
    `worker` names the worker that claimed the job (None until claimed)."""

    id: str
    status: JobStatus
    scene: dict[str, Any]
    progress: dict[str, Any] | None
    plan: dict[str, Any] | None
    error: str | None
    cancel_requested: bool
    owner: str
    created: float
    started: float | None
    finished: float | None
    worker: str | None = None


@dataclass(frozen=True)
class MemberRecord:
    """One job of a batch as its summary shows it: `index` in the batch, `verified` and
    `objective` from its plan (None without a plan). Times are Unix seconds."""

    job_id: str
    index: int
    status: JobStatus
    error: str | None
    verified: bool | None
    objective: float | None
    started: float | None
    finished: float | None


@dataclass(frozen=True)
class BatchRecord:
    """One stored batch: its specification (a JSON object) and its members by index."""

    id: str
    spec: dict[str, Any]
    owner: str
    created: float
    members: list[MemberRecord]


class JobStore(ABC):
    """Persistence of plan jobs. Every transition is atomic and conditional on the status,
    so a late writer (an orphaned worker, a second server) can never overwrite a verdict.
    Every method raises StoreUnavailable when the store cannot be reached."""

    @abstractmethod
    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None) -> JobRecord | None:
        """Store a new queued job; None (nothing stored) when `owner` already has `limit`
        unfinished (queued or running) jobs."""

    @abstractmethod
    def get(self, job_id: str) -> JobRecord | None:
        """The job, or None when there is no such id."""

    @abstractmethod
    def list(self, status: JobStatus | None = None, limit: int = 50,
             offset: int = 0) -> list[JobRecord]:
        """Jobs, newest first, optionally of one status."""

    @abstractmethod
    def count_by_status(self) -> dict[str, int]:
        """How many jobs are in each status (every status present, zeros included)."""

    @abstractmethod
    def claim(self, owner: str | None, worker: str, lease_until: float) -> JobRecord | None:
        """The oldest queued job (of `owner`; of anyone when None) turned running for
        `worker`, with progress `BUILDING`; None when there is none."""

    @abstractmethod
    def release(self, job_id: str, worker: str) -> bool:
        """Give a claim back: running (by `worker`) -> queued, as if never claimed."""

    @abstractmethod
    def report_progress(self, job_id: str, progress: dict[str, Any],
                        worker: str | None = None) -> bool:
        """Record progress of a running job (held by `worker` when given); False when it
        should stop (cancel requested, or the job is no longer running there)."""

    @abstractmethod
    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None, solution: dict[str, Any] | None = None,
               worker: str | None = None) -> bool:
        """running (held by `worker` when given) -> a final status with its plan or error,
        and the NLP solution behind the plan (for warm starts); False if it was not
        running there (e.g. its lease ran out and another worker took it)."""

    @abstractmethod
    def solution(self, job_id: str) -> dict[str, Any] | None:
        """The NLP solution a finished job's plan came from, None when it kept none."""

    @abstractmethod
    def fail(self, job_id: str, error: str) -> bool:
        """queued or running -> failed with an error; False if it was already final."""

    @abstractmethod
    def fail_claimed(self, worker: str, error: str) -> builtins.list[str]:
        """Mark the running jobs of `worker` failed with `error`; their ids."""

    @abstractmethod
    def request_cancel(self, job_id: str) -> JobRecord | None:
        """Cancel: a queued job becomes cancelled at once, a running one is flagged for
        its worker to stop; a final job is left as it is. None when there is no such id."""

    @abstractmethod
    def renew(self, workers: builtins.list[str], lease_until: float) -> dict[str, bool]:
        """Extend the leases of the running jobs of `workers`; {job id: cancel requested}."""

    @abstractmethod
    def expire(self, now: float) -> dict[str, JobStatus]:
        """Settle the running jobs whose lease ended before `now`: cancelled when a cancel
        was requested, else queued again (claim forgotten) while they have had fewer than
        `MAX_ATTEMPTS` claims, else failed ("interrupted"). {job id: new status}."""

    @abstractmethod
    def interrupt(self, owner: str) -> builtins.list[str]:
        """Mark the running jobs of `owner` held by its own workers (named "owner/...")
        failed with error "interrupted"; their ids."""

    @abstractmethod
    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None) -> bool:
        """Store a batch and its members (job id, scene) as queued jobs, all or none;
        False (nothing stored) when `owner` would then hold more than `limit` unfinished
        jobs."""

    @abstractmethod
    def get_batch(self, batch_id: str) -> BatchRecord | None:
        """The batch with its members in index order, or None when there is no such id."""

    @abstractmethod
    def check(self) -> None:
        """Raise StoreUnavailable (with the reason) unless the store can be used."""

    @abstractmethod
    def checkpoint(self, final: bool = False) -> None:
        """Make every committed change durable in the store's main file (`final`: also
        when shutting down, leaving nothing in side files)."""

    @abstractmethod
    def close(self) -> None:
        """Release this process's connections."""
