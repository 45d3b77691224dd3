"""Plan jobs on a pool of worker processes: submit, progress, cooperative cancel, wait.

A worker claims its job in the store (queued -> running), solves it and writes the
verdict itself; its progress callback records each Ipopt iteration (throttled) and asks
Ipopt to stop when the job's cancel flag is set. A watchdog thread in every worker marks
its job interrupted and exits when the server process is gone. The parent process only
counts jobs in flight, updates metrics and wakes waiting requests.
"""

from __future__ import annotations

import asyncio
import dataclasses
import importlib
import logging
import math
import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from app.store import INTERRUPTED, JobStore
from planner.ocp.result import Plan, Progress
from planner.ocp.verify import unverified_reason
from planner.scene import Scene

log = logging.getLogger("undertow.jobs")

SolveFunction = Callable[..., Plan]
"""solve(scene, progress=callback) -> Plan; never raises for a solver failure."""

PROGRESS_INTERVAL = 0.2  # [s] between two progress writes of one job
WATCH_INTERVAL = 0.25  # [s] between two checks of a worker that its server still runs
WORKER_DIED = "the worker process died during the solve"
MAX_REQUEUES = 3  # times a queued job is resubmitted after a worker pool broke


def load_function(spec: str) -> SolveFunction:
    """The function named "package.module:function"."""
    module, _, name = spec.partition(":")
    if not name:
        raise ValueError(f"solve_function: expected 'module:function', got {spec!r}")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Outcome:
    """What a worker reports back: the final status it stored and the solve time [s]."""

    job_id: str
    status: str
    elapsed: float


def _finite(value: Any) -> Any:
    return value if not isinstance(value, float) or math.isfinite(value) else None


class _Reporter:
    """The progress callback of one job in a worker: throttled writes, cancel checks."""

    def __init__(self, store: JobStore, job_id: str):
        self.store, self.job_id = store, job_id
        self.last, self.go_on = -math.inf, True
        self.latest: dict[str, Any] | None = None
        self.written = True

    def __call__(self, progress: Progress) -> bool:
        self.latest = {k: _finite(v) for k, v in dataclasses.asdict(progress).items()}
        self.written = False
        if time.monotonic() - self.last >= PROGRESS_INTERVAL:
            self.flush()
        return self.go_on

    def flush(self) -> None:
        """Write the latest progress and read the cancel flag."""
        if not self.written and self.latest is not None:
            self.go_on = self.store.report_progress(self.job_id, self.latest)
            self.last, self.written = time.monotonic(), True


def _verdict(plan: Plan, cancel_requested: bool) -> tuple[str, str | None]:
    """Final status and error of a returned plan: an optimal plan that fails its
    re-simulation check has failed too."""
    if plan.solver.success:
        reason = unverified_reason(plan.verification)
        return ("succeeded", None) if reason is None else ("failed", f"unverified: {reason}")
    if cancel_requested:
        return "cancelled", "cancelled on request"
    message = plan.solver.message
    return "failed", f"{plan.solver.status}: {message}" if message else plan.solver.status


_current: tuple[JobStore, str] | None = None
"""The job this worker process is solving, for the orphan watchdog."""


def run_job(store: JobStore, job_id: str, solve: SolveFunction) -> Outcome:
    """Solve one job inside a worker process and store the verdict."""
    global _current
    start = time.monotonic()
    record = store.claim(job_id)
    if record is None:
        return Outcome(job_id, "skipped", 0.0)
    _current = (store, job_id)
    reporter = _Reporter(store, job_id)
    try:
        plan = solve(Scene.model_validate(record.scene), progress=reporter)
    except Exception as exc:  # noqa: BLE001 - any error fails the job, the worker lives
        store.finish(job_id, "failed", None, f"solver error: {type(exc).__name__}: {exc}")
        return Outcome(job_id, "failed", time.monotonic() - start)
    finally:
        _current = None
    reporter.flush()
    current = store.get(job_id)
    status, error = _verdict(plan, bool(current and current.cancel_requested))
    store.finish(job_id, status, plan.model_dump(mode="json"), error)
    return Outcome(job_id, status, time.monotonic() - start)


def _watch(parent: int) -> None:
    """Exit this worker when the server process is gone (e.g. killed with SIGKILL), first
    marking its job interrupted: an orphan must not keep solving or hold the store."""
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL)
    current = _current
    if current is not None:
        current[0].fail(current[1], INTERRUPTED)
    os._exit(0)


def _init_worker(module: str, parent: int) -> None:
    """Worker initializer: start the orphan watchdog, import the solver once."""
    threading.Thread(target=_watch, args=(parent,), daemon=True, name="orphan-watch").start()
    importlib.import_module(module)


class QueueFull(Exception):
    """No room for another job; retry after `retry_after` seconds."""

    def __init__(self, retry_after: int):
        super().__init__("the job queue is full")
        self.retry_after = retry_after


class JobRunner:
    """Runs plan jobs of one server instance on `workers` processes.

    `solve` is a module-level function (it is sent to the workers by reference);
    `on_done(outcome)` runs in the parent when a job ends, e.g. to update metrics.
    At most `workers + max_queued` jobs are in flight at once.
    """

    def __init__(self, store: JobStore, solve: SolveFunction, owner: str, workers: int,
                 max_queued: int, retry_after: int = 5,
                 on_done: Callable[[Outcome], None] | None = None):
        self.store, self.solve, self.owner = store, solve, owner
        self.workers, self.capacity = workers, workers + max_queued
        self.retry_after = retry_after
        self.on_done = on_done
        self._lock = threading.Lock()
        self._inflight: set[str] = set()
        self._requeued: dict[str, int] = {}
        self._waiters: dict[str, list[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}
        self._pool = self._new_pool()
        self._closed = False

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_worker,
                                   initargs=(self.solve.__module__, os.getpid()))

    @property
    def inflight(self) -> int:
        """Jobs of this instance submitted and not yet ended."""
        return len(self._inflight)

    def start(self) -> list[str]:
        """Recover after a restart: running jobs of this owner become failed
        ("interrupted"), queued ones are submitted again. Returns the interrupted ids."""
        interrupted = self.store.interrupt(self.owner)
        for job_id in self.store.queued(self.owner):
            self._submit(job_id)
        return interrupted

    def submit(self, scene: dict[str, Any], job_id: str) -> None:
        """Store a new job and queue it; QueueFull when the instance is at capacity."""
        with self._lock:
            if len(self._inflight) >= self.capacity:
                raise QueueFull(self.retry_after)
            self._inflight.add(job_id)
        try:
            self.store.create(job_id, scene, self.owner)
        except Exception:
            self._inflight.discard(job_id)
            raise
        self._submit(job_id)

    def _submit(self, job_id: str) -> None:
        with self._lock:
            self._inflight.add(job_id)
            try:
                future = self._pool.submit(run_job, self.store, job_id, self.solve)
            except BrokenProcessPool:
                self._pool = self._new_pool()
                future = self._pool.submit(run_job, self.store, job_id, self.solve)
        future.add_done_callback(lambda f: self._done(job_id, f))

    def _done(self, job_id: str, future: Future) -> None:
        """In the parent, when a worker returns (or dies)."""
        if future.cancelled():
            outcome = None
        elif isinstance(future.exception(), BrokenProcessPool) and not self._closed:
            record = self.store.get(job_id)
            if record is not None and record.status == "queued" and self._retry(job_id):
                self._resubmit(job_id)
                return
            self.store.fail(job_id, WORKER_DIED)
            outcome = Outcome(job_id, "failed", 0.0)
        elif future.exception() is not None:
            log.error("job %s: %s", job_id, future.exception())
            self.store.fail(job_id, f"internal error: {future.exception()}")
            outcome = Outcome(job_id, "failed", 0.0)
        else:
            outcome = future.result()
        with self._lock:
            self._inflight.discard(job_id)
            waiters = self._waiters.pop(job_id, [])
        for loop, event in waiters:
            if not loop.is_closed():
                loop.call_soon_threadsafe(event.set)
        if outcome is not None and outcome.status != "skipped" and self.on_done:
            self.on_done(outcome)

    def _retry(self, job_id: str) -> bool:
        """Whether a queued job hit by another job's crashed worker is tried again."""
        with self._lock:
            self._requeued[job_id] = self._requeued.get(job_id, 0) + 1
            return self._requeued[job_id] <= MAX_REQUEUES

    def _resubmit(self, job_id: str) -> None:
        with self._lock:
            if self._pool._broken:  # the executor exposes no public flag
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = self._new_pool()
        self._submit(job_id)

    async def wait(self, job_id: str, timeout: float) -> None:
        """Return when the job ends in this instance or after `timeout` seconds."""
        event = asyncio.Event()
        with self._lock:
            if job_id not in self._inflight:
                return
            self._waiters.setdefault(job_id, []).append((asyncio.get_running_loop(), event))
        try:
            await asyncio.wait_for(event.wait(), timeout)
        except TimeoutError:
            pass

    def shutdown(self) -> None:
        """Stop: running jobs are marked interrupted (their workers then stop at the next
        iteration), queued ones stay queued in the store for the next start."""
        self._closed = True
        self.store.interrupt(self.owner)
        self._pool.shutdown(wait=False, cancel_futures=True)
