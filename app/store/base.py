"""The job store interface: what the service needs from a database of plan jobs.

A store must be safe to use from several threads and processes at once, and picklable:
worker processes receive the store object and reopen it on their side.

Workers take jobs by claiming them: one conditional update turns the oldest queued job
(whose retry time, if any, has come) into a running one that names its worker and holds a
lease until a given time. Whoever supervises the worker renews the lease of each job it
knows the worker runs (by job and worker, never by worker alone) while the worker lives.

Two kinds of failure are counted apart. A solver failure (the solver did not converge,
raised, ran out of its budget) is the job's verdict: `failed`, never retried by itself.
An infrastructure failure (the worker process died, its node's main process died, the
lease ran out because a node or its machine was lost, the server restarted under the
job) is not the job's fault: the job is requeued (`requeue`) with a growing pause before
it may be claimed again (`RetryPolicy`), up to `RetryPolicy.max_retries` times; one more
and it ends `failed` as a *dead letter* (`dead_letter`, error "dead letter: ..."), with
its `history` of claims and failures. A job whose cancel was requested is cancelled
instead. A claim given back on purpose (`release`: a node stopping, SIGTERM) is no
failure and not counted. A failed or cancelled job can be queued again by id (`retry`).

A batch is a set of jobs created together (one transaction) with the specification they
came from; its members are read back with the few figures of their plans a summary needs.
"""

from __future__ import annotations

import builtins
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
STATUSES: tuple[JobStatus, ...] = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL: frozenset[str] = frozenset({"succeeded", "failed", "cancelled"})
INTERRUPTED = "interrupted"
DEAD_LETTER = "dead letter"
"""The start of the error of a job that failed for infrastructure reasons too often."""
CANCELLED_ON_REQUEST = "cancelled on request"
SILENCE = 2.0
"""[s] A claim is taken as lost only once it has been silent this long (its whole lease,
if that is shorter): a look that takes the claims whose lease runs out before the next
look must not take a shorter lease's claim that is being renewed (four times a second)."""
BUILDING: dict[str, Any] = {"phase": "building", "iteration": 0, "objective": None,
                            "inf_pr": None, "inf_du": None, "elapsed": 0.0, "mesh_pass": 0}
"""The progress of a job from its claim until the solver's first iteration."""


@dataclass(frozen=True)
class RetryPolicy:
    """How infrastructure failures are retried: the n-th requeue waits
    min(`max_backoff`, `backoff` * 2**(n-1)) seconds before the job may be claimed again;
    after `max_retries` requeues the next failure makes the job a dead letter."""

    max_retries: int = 3
    backoff: float = 1.0
    max_backoff: float = 60.0

    def delay(self, failures: int) -> float:
        """The pause after the job's `failures`-th infrastructure failure [s]."""
        return min(self.max_backoff, self.backoff * 2.0 ** max(0, failures - 1))


@dataclass(frozen=True)
class Retention:
    """How long finished jobs are kept: at most `age` seconds after they ended, the newest
    `count` of them, and the newest within `size` bytes of what the store holds of them
    (scene, progress, plan, NLP solution). Queued and running jobs are always kept."""

    age: float
    count: int
    size: int


class StoreUnavailable(Exception):
    """The store cannot be used (file deleted or replaced, disk error, damaged database)."""


class DuplicateKey(Exception):
    """Another job was created with the same idempotency key."""


class StoreDamaged(StoreUnavailable):
    """The store failed its integrity check, or its database reported itself damaged: no
    job is accepted into it, and the service does not start on it."""


class NewerSchema(StoreUnavailable):
    """The store's schema is of a newer version than the newest migration this code knows
    (a newer version of the service migrated it): the process does not start on it."""


class EarlierNodes(StoreUnavailable):
    """Nodes of a release too early to run beside this one are alive on the store: the
    process does not start until they are replaced (`app.store.postgres_status`)."""


class NameTaken(StoreUnavailable):
    """A live server of the same name already runs on the store (`JobStore.hold_name`)."""


class Held(Protocol):
    """A server name held on a store (`JobStore.hold_name`) until `release`."""

    def release(self) -> None:
        """Give the name back (it is given back anyway when the process ends)."""


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
    attempts: int = 0
    """Claims the job has had."""
    infra_failures: int = 0
    """Infrastructure failures it has had (each one requeued it, or made it a dead letter)."""
    dead_letter: bool = False
    history: list[dict[str, Any]] | None = None
    """Claims, releases, infrastructure failures, retries and the verdict, oldest first:
    {"at": Unix seconds, "event": ..., "worker": ..., "reason": ...}."""
    admission: dict[str, Any] | None = None
    """What was decided about the scene when the job was submitted (`app.admission`);
    None in jobs stored without it (by an earlier version, or a caller that decided
    nothing)."""


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
class WorkerRecord:
    """A supervisor of solver processes (a server's or a worker node's) as its last
    heartbeat left it. Times are Unix seconds."""

    name: str
    processes: int
    busy: int
    started: float
    seen: float


@dataclass(frozen=True)
class BatchRecord:
    """One stored batch: its specification (a JSON object) and its members by index."""

    id: str
    spec: dict[str, Any]
    owner: str
    created: float
    members: list[MemberRecord]


class Listener(Protocol):
    """A connection of a store's own on which it announces queued jobs: readable (its
    `fileno`, to wait on with `select` or `multiprocessing.connection.wait`) once one was
    announced."""

    def fileno(self) -> int:
        """The descriptor to wait on."""

    def drain(self) -> list[float]:
        """The pause [s] of each job announced since the last drain: 0.0 for one that may
        be claimed now, else how long after its announcement it may be (a job queued
        again after an infrastructure failure); raises when the connection broke."""

    def close(self) -> None:
        """End the connection."""


class JobStore(ABC):
    """Persistence of plan jobs. Every transition is atomic and conditional on the status,
    so a late writer (an orphaned worker, a second server) can never overwrite a verdict.
    Every method raises StoreUnavailable when the store cannot be reached."""

    policy: RetryPolicy = RetryPolicy()
    """How this store's users retry infrastructure failures (set by `app.store.open`)."""

    @abstractmethod
    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None, key: str | None = None,
               admission: dict[str, Any] | None = None) -> JobRecord | None:
        """Store a new queued job with its `admission`; None (nothing stored) when `owner`
        already has `limit` unfinished (queued or running) jobs. `key`: an idempotency key,
        unique among jobs (IntegrityError when another job has it)."""

    @abstractmethod
    def get(self, job_id: str) -> JobRecord | None:
        """The job, or None when there is no such id."""

    @abstractmethod
    def status(self, job_id: str) -> JobStatus | None:
        """The job's status alone (its plan is not read), or None when there is no such
        id."""

    @abstractmethod
    def list(self, status: JobStatus | None = None, limit: int = 50,
             offset: int = 0, dead_letter: bool | None = None,
             summaries: bool = False) -> list[JobRecord]:
        """Jobs, newest first, optionally of one status, and dead letters or not;
        summaries: without their scenes, plans, histories and admissions (empty scene,
        None), which are neither read from the database nor decoded."""

    @abstractmethod
    def count_by_status(self) -> dict[str, int]:
        """How many jobs are in each status (every status present, zeros included)."""

    @abstractmethod
    def claim(self, owner: str | None, worker: str, lease_until: float) -> JobRecord | None:
        """The oldest queued job (of `owner`; of anyone when None) whose retry time has
        come, turned running for `worker`, with progress `BUILDING`; None when there is
        none."""

    @abstractmethod
    def release(self, job_id: str, worker: str, reason: str = "released") -> bool:
        """Give a claim back: running (by `worker`) -> queued, as if never claimed (a
        cancel requested meanwhile cancels it instead)."""

    @abstractmethod
    def release_claimed(self, worker: str, reason: str) -> builtins.list[str]:
        """`release` every running job of `worker`; their ids."""

    @abstractmethod
    def requeue(self, job_id: str, worker: str | None, reason: str) -> JobStatus | None:
        """An infrastructure failure of a running job (held by `worker` when given):
        cancelled when a cancel was requested, else queued again after the policy's pause,
        or failed as a dead letter once it has had `max_retries` requeues. The new status,
        None when the job was not running there."""

    @abstractmethod
    def requeue_claimed(self, worker: str, reason: str) -> dict[str, JobStatus]:
        """`requeue` every running job of `worker`; {job id: new status}."""

    @abstractmethod
    def retry(self, job_id: str, owner: str, limit: int | None = None) -> bool:
        """A failed or cancelled job queued again for `owner` (verdict, plan and failure
        count cleared, history kept); False when it is not failed or cancelled, or when
        `owner` already has `limit` unfinished jobs."""

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
    def request_cancel(self, job_id: str) -> JobRecord | None:
        """Cancel: a queued job becomes cancelled at once, a running one is flagged for
        its worker to stop; a final job is left as it is. None when there is no such id."""

    @abstractmethod
    def renew(self, claims: builtins.list[tuple[str, str]],
              lease_until: float) -> dict[str, bool]:
        """Extend the leases of the running jobs of (job id, worker) `claims`; {job id:
        cancel requested} of those still running there."""

    @abstractmethod
    def expire(self, now: float) -> dict[str, JobStatus]:
        """`requeue` the running jobs whose lease ends before `now` and whose claim has
        been silent for `SILENCE` at least (their worker or node was lost); {job id: new
        status}."""

    @abstractmethod
    def hold_name(self, name: str) -> Held:
        """Hold server name `name` on this store while this process runs it (NameTaken
        when a live process holds it already): a server takes its name before it touches
        a job, since it treats its name's running jobs as its own."""

    @abstractmethod
    def recover(self, owner: str) -> dict[str, JobStatus]:
        """`requeue` the running jobs of `owner` held by its own workers (named
        "owner/..."): they ran when the server stopped; {job id: new status}."""

    @abstractmethod
    def cancel_batch(self, batch_id: str) -> bool:
        """`request_cancel` every unfinished member of the batch; False when there is no
        such batch."""

    @abstractmethod
    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None,
                     admissions: Sequence[dict[str, Any] | None] | None = None) -> bool:
        """Store a batch and its members (job id, scene) as queued jobs, all or none, with
        their `admissions` (one per member, in order; none by default); False (nothing
        stored) when `owner` would then hold more than `limit` unfinished jobs."""

    @abstractmethod
    def purge(self, before: float, keep: int, size: int | None = None) -> int:
        """Delete the finished jobs that ended before `before`, those beyond the newest
        `keep` finished ones, and those beyond the newest that the store holds within
        `size` bytes (of their scenes, progress, plans and NLP solutions); then the
        batches left without members. How many jobs."""

    @abstractmethod
    def heartbeat(self, name: str, processes: int, busy: int, started: float) -> None:
        """Record that supervisor `name` lives, with `busy` of its `processes` running a
        job (and forget supervisors silent for an hour)."""

    @abstractmethod
    def forget_worker(self, name: str) -> None:
        """Remove supervisor `name` (it stopped)."""

    @abstractmethod
    def workers(self, since: float) -> builtins.list[WorkerRecord]:
        """The supervisors heard from since `since`, by name."""

    @abstractmethod
    def find_key(self, key: str) -> str | None:
        """The id of the job created with idempotency key `key`, or None."""

    @abstractmethod
    def succeeded_scenes(self, limit: int) -> builtins.list[tuple[str, dict[str, Any]]]:
        """The ids and scenes of the `limit` succeeded jobs that finished last, newest
        first: where a plan with solver.warm_start "nearest" looks for its start."""

    @abstractmethod
    def get_batch(self, batch_id: str) -> BatchRecord | None:
        """The batch with its members in index order, or None when there is no such id."""

    @abstractmethod
    def listen(self) -> Listener | None:
        """A connection of its own on which queued jobs are announced, for an idle worker
        to wait on; None when the store announces nothing (the worker then polls). Raises
        when the connection cannot be opened (the worker polls meanwhile)."""

    @abstractmethod
    def check(self) -> None:
        """Raise StoreUnavailable (with the reason) unless the store can be used."""

    @abstractmethod
    def verify(self) -> None:
        """Raise StoreDamaged when the store fails the integrity check due now (cheap when
        none is due); one found damaged stays damaged for this process."""

    @abstractmethod
    def checkpoint(self, final: bool = False) -> None:
        """Make every committed change durable in the store's main file (`final`: also
        when shutting down, leaving nothing in side files)."""

    @abstractmethod
    def close(self) -> None:
        """Release this process's connections."""
