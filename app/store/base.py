"""The job store interface: what the service needs from a database of plan jobs.

A store must be safe to use from several threads and processes at once, and picklable:
worker processes receive the store object and reopen it on their side.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Literal

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
STATUSES: tuple[JobStatus, ...] = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL: frozenset[str] = frozenset({"succeeded", "failed", "cancelled"})
INTERRUPTED = "interrupted"


@dataclass(frozen=True)
class JobRecord:
    """One stored job. Times are Unix seconds; scene, progress and plan are JSON objects."""

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


class JobStore(ABC):
    """Persistence of plan jobs. Every transition is atomic and conditional on the status,
    so a late writer (an orphaned worker, a second server) can never overwrite a verdict."""

    @abstractmethod
    def create(self, job_id: str, scene: dict[str, Any], owner: str) -> JobRecord:
        """Store a new queued job."""

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
    def claim(self, job_id: str) -> JobRecord | None:
        """queued -> running; None when the job is no longer queued (e.g. cancelled)."""

    @abstractmethod
    def report_progress(self, job_id: str, progress: dict[str, Any]) -> bool:
        """Record progress of a running job; False when it should stop (cancel requested,
        or the job is no longer running)."""

    @abstractmethod
    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None) -> bool:
        """running -> a final status with its plan or error; False if it was not running."""

    @abstractmethod
    def fail(self, job_id: str, error: str) -> bool:
        """queued or running -> failed with an error; False if it was already final."""

    @abstractmethod
    def request_cancel(self, job_id: str) -> JobRecord | None:
        """Cancel: a queued job becomes cancelled at once, a running one is flagged for
        its worker to stop; a final job is left as it is. None when there is no such id."""

    @abstractmethod
    def interrupt(self, owner: str) -> list[str]:
        """Mark the running jobs of `owner` failed with error "interrupted"; their ids."""

    @abstractmethod
    def queued(self, owner: str) -> list[str]:
        """Ids of the queued jobs of `owner`, oldest first."""

    @abstractmethod
    def close(self) -> None:
        """Release this process's connections."""
