"""Plan jobs as the HTTP service sees them: submit, wait, recover, health, shutdown.

The store is the single record of every job. Submitting stores a queued job, unless this
server already holds as many unfinished ones as it may (one conditional insert, so the
count and the new job agree); the server's workers (`app.supervisor`, `app.worker`) claim
queued jobs from the store and write their progress and verdicts there. Waiting for a job
reads the store, so every way a job can end (its worker, a cancel, the supervisor's
verdict) ends the wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from anyio import to_thread

from app.job_run import SolveFunction
from app.store import FINAL, Held, JobStore, Retention, StoreDamaged, StoreUnavailable
from app.supervisor import Supervisor
from app.worker_pipe import JobEnd

log = logging.getLogger("undertow.jobs")

WAIT_POLL = 0.05  # [s] between two looks at a waited-for job


class QueueFull(Exception):
    """No room for another job; retry after `retry_after` seconds."""

    def __init__(self, retry_after: int):
        super().__init__("the job queue is full")
        self.retry_after = retry_after


class JobRunner:
    """Runs the plan jobs of one server instance (`owner`) on `workers` processes.

    `solve` is a module-level function (sent to the workers by reference); `on_done(end)`
    runs when a job ends, e.g. to update metrics. At most `workers + max_queued` jobs of
    the instance are unfinished at once. `memory_mb` caps each worker's memory growth and
    `grace` is how long a job may run past its wall-time budget before its worker is
    stopped; `lease` how long a claim holds without renewal; `drain` how long a stop lets
    running jobs end before it releases them. With no workers the server
    only accepts jobs, for workers elsewhere (`undertow worker`) to run.
    """

    def __init__(self, store: JobStore, solve: SolveFunction, owner: str, workers: int,
                 max_queued: int, retry_after: int = 5, memory_mb: float | None = None,
                 grace: float = 30.0, log_level: str = "INFO",
                 on_done: Callable[[JobEnd], None] | None = None, lease: float = 60.0,
                 retention: Retention | None = None, drain: float = 0.0):
        self.store, self.owner = store, owner
        self.capacity, self.retry_after = workers + max_queued, retry_after
        self._on_done = on_done
        self._name: Held | None = None
        self._waiters: dict[str, list[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}
        self._waiters_lock = threading.Lock()
        self.supervisor = Supervisor(store, solve, owner, workers, memory_mb, grace,
                                     log_level, self._ended, lease=lease, retention=retention,
                                     drain=drain)

    def start(self) -> list[str]:
        """Take the server's name on the store (NameTaken, touching nothing, when a live
        server of that name runs on it), then recover after a restart: running jobs of
        this owner held by its own workers had an infrastructure failure (the server
        stopped under them) and are requeued; queued ones run (the workers start now if
        any job waits, else with the first submitted one). Returns the recovered ids."""
        self._name = self.store.hold_name(self.owner)
        try:
            recovered = self.store.recover(self.owner)
        except StoreUnavailable:
            self._name.release()
            raise
        self.supervisor.start()
        if self.store.count_by_status()["queued"]:
            self.supervisor.wake()
        return list(recovered)

    def submit(self, scene: dict[str, Any], job_id: str, key: str | None = None,
               admission: dict[str, Any] | None = None) -> None:
        """Store a new queued job with its `admission` (`app.admission`; with idempotency
        key `key`: DuplicateKey when another job has it); QueueFull when the instance is at
        capacity."""
        if self.store.create(job_id, scene, self.owner, limit=self.capacity, key=key,
                             admission=admission) is None:
            raise QueueFull(self.retry_after)
        self.supervisor.wake()

    def retry(self, job_id: str) -> bool:
        """Queue a failed or cancelled job again as this server's; False when it is not
        failed or cancelled, or the server is at capacity."""
        if not self.store.retry(job_id, self.owner, limit=self.capacity):
            return False
        self.supervisor.wake()
        return True

    def submit_batch(self, batch_id: str, spec: dict[str, Any],
                     members: list[tuple[str, dict[str, Any]]], extra: int = 0,
                     admissions: list[dict[str, Any]] | None = None) -> None:
        """Store a batch and its member jobs with their `admissions` (one per member), all
        or none; QueueFull when they would take the instance past its capacity plus `extra`
        (the room one batch may take beyond the queue, UNDERTOW_MAX_BATCH_MEMBERS)."""
        if not self.store.create_batch(batch_id, spec, members, self.owner,
                                       limit=self.capacity + extra, admissions=admissions):
            raise QueueFull(self.retry_after)
        self.supervisor.wake()

    async def wait(self, job_id: str, timeout: float) -> None:
        """Return when the job has ended or after `timeout` seconds: at once when one of
        this server's workers ends it, else at the store read that sees it ended (every
        WAIT_POLL seconds: a cancel, another server's worker)."""
        deadline = time.monotonic() + timeout
        ended = asyncio.Event()
        entry = (asyncio.get_running_loop(), ended)
        with self._waiters_lock:
            self._waiters.setdefault(job_id, []).append(entry)
        try:
            while time.monotonic() < deadline:
                status = await to_thread.run_sync(self.store.status, job_id)
                if status is None or status in FINAL:
                    return
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(ended.wait(), min(
                        WAIT_POLL, max(0.0, deadline - time.monotonic())))
                ended.clear()
        finally:
            with self._waiters_lock:
                waiting = self._waiters.get(job_id, [])
                waiting.remove(entry)
                if not waiting:
                    self._waiters.pop(job_id, None)

    def _ended(self, end: JobEnd) -> None:
        """A job ended by one of this server's workers (in the supervising thread): wake
        its waiters, then call `on_done`."""
        with self._waiters_lock:
            waiting = list(self._waiters.get(end.job_id, []))
        for loop, event in waiting:
            with contextlib.suppress(RuntimeError):  # its loop has closed
                loop.call_soon_threadsafe(event.set)
        if self._on_done is not None:
            self._on_done(end)

    def problem(self) -> str | None:
        """Why this server cannot take or run jobs (store or workers), or None; a store
        that failed its integrity check raises StoreDamaged, which has an answer of its
        own (`app.main`)."""
        try:
            self.store.check()
        except StoreDamaged:
            raise
        except StoreUnavailable as exc:
            return str(exc)
        return self.supervisor.problem

    def shutdown(self) -> None:
        """Stop: running jobs that do not end within the drain are released (queued again),
        queued ones stay queued in the store for the next start or another server's
        workers; the store is then checkpointed, the server's name given back and the store
        closed."""
        self.supervisor.stop()
        try:
            self.store.checkpoint(final=True)
        except StoreUnavailable as exc:
            log.error("shutdown: %s", exc)
        if self._name is not None:
            self._name.release()
        self.store.close()
