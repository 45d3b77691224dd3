"""A solver worker: a process that claims queued plan jobs from the store and solves them,
one at a time, until it is told to stop.

The worker writes everything about its job to the store itself: the claim (with progress
`{"phase": "building"}`), Ipopt's iterations (throttled; a cancel flag or a lost claim
stops the solve at the next iteration), and the verdict. Each job gets its own progress
reporter and its own scene; nothing of one job is kept for the next. A job's wall-time
budget, `solver.max_wall_time`, counts from the claim, NLP build included: once it is
spent, the next iteration stops the solve.

Its supervisor (`app.supervisor`) talks to it over a pipe: WAKE when a job was queued,
STOP to end; the worker answers READY once started, CLAIMED when it takes a job and the
job's `JobEnd` when it ends. The worker limits its own memory (UNDERTOW_WORKER_MEMORY_MB)
and leaves after a job that ran out of it, so a fresh process takes its place. A watchdog
thread requeues its job (an infrastructure failure: the node's main process died) and
exits when the supervising process is gone. SIGINT and SIGTERM are for the supervisor to
handle: it gives the running jobs back before it stops its workers.

The store may fail for a while during a solve (a database restart): progress that cannot
be written is written later, and the verdict (and the reads before it) are retried with
backoff until the store answers, so a row is never left running by a worker that moved
on. A claim whose answer was lost (the connection broke after the database committed it)
is given back as soon as the store answers again. On PostgreSQL an idle worker LISTENs for
queued jobs and claims one within milliseconds; otherwise it looks every `IDLE_POLL`
seconds (or when its supervisor says WAKE).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import logging
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any, TypeVar

from app.logging import configure
from app.procmem import limit_growth
from app.store import (
    CANCELLED_ON_REQUEST,
    JobRecord,
    JobStatus,
    JobStore,
    Listener,
    StoreUnavailable,
)
from app.stored_plan import current
from planner.service import (
    NEAREST,
    NlpSolution,
    Plan,
    Progress,
    Scene,
    nearest,
    unverified_reason,
)

log = logging.getLogger("undertow.worker")

SolveFunction = Callable[..., Plan]
"""solve(scene, progress=callback) -> Plan; never raises for a solver failure."""

PROGRESS_INTERVAL = 0.2  # [s] between two progress writes of one job
IDLE_POLL = 1.0  # [s] an idle worker looks for queued jobs at least this often
WATCH_INTERVAL = 0.25  # [s] between two checks that the supervising process still runs
STORE_RETRY = 0.05  # [s] first pause before retrying a store that failed; doubled each time
STORE_RETRY_MAX = 2.0  # [s] longest pause between two tries
ORPHAN_TRIES = 20.0  # [s] an orphaned worker tries this long to give its job back
LISTEN_RETRY = 5.0  # [s] between two tries to LISTEN again after the connection broke
MEMORY = 1000
"""How many of the latest succeeded plans solver.warm_start "nearest" looks through."""
PARENT_DIED = "the node's main process died (killed?) while the job ran"
T = TypeVar("T")
WAKE, STOP, READY = "wake", "stop", "ready"


def load_function(spec: str) -> SolveFunction:
    """The function named "package.module:function"."""
    module, _, name = spec.partition(":")
    if not name:
        raise ValueError(f"solve_function: expected 'module:function', got {spec!r}")
    return getattr(importlib.import_module(module), name)


def out_of_memory(limit_mb: float | None) -> str:
    """The error of a job whose solve ran out of memory."""
    where = (f"the {limit_mb:g} MB a solver worker may use (UNDERTOW_WORKER_MEMORY_MB)"
             if limit_mb is not None else "the memory available")
    return (f"out of memory: the NLP needed more than {where}; use fewer intervals, a "
            "lower degree or fewer links")


@dataclass(frozen=True)
class Claimed:
    """Worker -> supervisor: the worker took a job whose budget is `budget` seconds."""

    job_id: str
    budget: float


@dataclass(frozen=True)
class JobEnd:
    """Worker -> supervisor: a job ended with this stored status after `elapsed` seconds;
    `exhausted` when it ran out of memory (the worker then leaves)."""

    job_id: str
    status: str
    elapsed: float
    exhausted: bool = False


@dataclass(frozen=True)
class WorkerSpec:
    """What a worker needs; picklable (the store reopens itself in the worker).
    `owner` None claims the jobs of every server sharing the store (a standalone worker);
    `lease` [s] is how long a claim holds without renewal."""

    store: JobStore
    solve: SolveFunction
    owner: str | None
    name: str
    memory_mb: float | None
    lease: float
    log_level: str = "INFO"


def _finite(value: Any) -> Any:
    return value if not isinstance(value, float) or math.isfinite(value) else None


class _Reporter:
    """The progress callback of one job: throttled writes, cancel checks, the budget."""

    def __init__(self, store: JobStore, job_id: str, deadline: float, worker: str | None):
        self.store, self.job_id, self.deadline, self.worker = store, job_id, deadline, worker
        self.last, self.go_on, self.expired = -math.inf, True, False
        self.latest: dict[str, Any] | None = None
        self.written = True

    def __call__(self, progress: Progress) -> bool:
        self.latest = {"phase": "solving",
                       **{k: _finite(v) for k, v in dataclasses.asdict(progress).items()}}
        self.written = False
        if time.monotonic() - self.last >= PROGRESS_INTERVAL:
            self.flush()
        if time.monotonic() > self.deadline:
            self.expired = True
        return self.go_on and not self.expired

    def flush(self) -> None:
        """Write the latest progress and read the cancel flag; a store that cannot be
        written now is written at a later iteration (the solve goes on meanwhile)."""
        if not self.written and self.latest is not None:
            self.last = time.monotonic()
            try:
                self.go_on = self.store.report_progress(self.job_id, self.latest, self.worker)
            except StoreUnavailable as exc:
                log.warning("job %s: progress not written (will retry): %s", self.job_id, exc)
                return
            self.written = True


def persist(action: Callable[[], T], what: str, give_up: float = math.inf) -> T:
    """`action()`, retried with backoff while the store is unavailable, for up to
    `give_up` seconds (then its StoreUnavailable is raised)."""
    pause, deadline, warned = STORE_RETRY, time.monotonic() + give_up, False
    while True:
        try:
            return action()
        except StoreUnavailable as exc:
            if time.monotonic() + pause > deadline:
                raise
            if not warned:
                log.warning("%s: the store failed, retrying: %s", what, exc)
                warned = True
            time.sleep(pause)
            pause = min(STORE_RETRY_MAX, 2 * pause)


def _verdict(plan: Plan, cancel_requested: bool, expired: bool,
             budget: float) -> tuple[JobStatus, str | None]:
    """Final status and error of a returned plan: an optimal plan that fails its
    re-simulation check has failed too; a plan that holds the task infeasible fails with
    an error "infeasible: ..." (its evidence in `plan.infeasibility`)."""
    if plan.solver.success:
        reason = unverified_reason(plan.verification)
        return ("succeeded", None) if reason is None else ("failed", f"unverified: {reason}")
    if cancel_requested:
        return "cancelled", CANCELLED_ON_REQUEST
    if plan.infeasibility is not None:
        return "failed", f"infeasible: {plan.infeasibility.summary}"
    if expired:
        return "failed", (f"Maximum_WallTime_Exceeded: the job's wall-time budget of "
                          f"{budget:g} s (solver.max_wall_time, NLP build included) ran out")
    message = plan.solver.message
    return "failed", f"{plan.solver.status}: {message}" if message else plan.solver.status


_current: tuple[JobStore, str, str | None] | None = None
"""The job this worker process is solving (store, job id, worker), for the orphan
watchdog."""


def run_job(store: JobStore, job_id: str, scene: Scene, solve: SolveFunction,
            memory_mb: float | None = None, worker: str | None = None) -> JobEnd:
    """Solve one job claimed by `worker` and store its verdict (unless the job was taken
    from `worker` meanwhile: its lease ran out and another worker holds it)."""
    global _current
    start, budget = time.monotonic(), scene.solver.max_wall_time
    _current = (store, job_id, worker)
    reporter = _Reporter(store, job_id, start + budget, worker)
    try:
        warm = persist(lambda: _warm_start(store, scene), f"job {job_id}: warm start")
        plan = solve(scene, progress=reporter, **({"warm_start": warm[0]} if warm else {}))
        if warm is not None:
            plan = _started_from(plan, *warm[1:])
    except MemoryError:
        return _failed(store, job_id, out_of_memory(memory_mb), start, worker, exhausted=True)
    except Exception as exc:  # noqa: BLE001 - any error fails the job, the worker lives
        if "bad_alloc" in str(exc):  # C++ allocation failure, raised through CasADi
            return _failed(store, job_id, out_of_memory(memory_mb), start, worker,
                           exhausted=True)
        return _failed(store, job_id, f"solver error: {type(exc).__name__}: {exc}", start,
                       worker)
    finally:
        _current = None
    reporter.flush()
    current = persist(lambda: store.get(job_id), f"job {job_id}: reading its cancel flag")
    status, error = _verdict(plan, bool(current and current.cancel_requested),
                             reporter.expired, budget)
    solution = plan.solution.model_dump(mode="json") if plan.solution is not None else None
    body = plan.model_dump(mode="json")
    persist(lambda: store.finish(job_id, status, body, error, solution, worker),
            f"job {job_id}: writing its verdict")
    return JobEnd(job_id, status, time.monotonic() - start)


def _start_from(store: JobStore, scene: Scene) -> tuple[str, float | None] | None:
    """The id of the earlier job the scene starts from (solver.warm_start: its own, or
    with "nearest" the nearest of the MEMORY latest succeeded ones within reach, with its
    distance [rad]); None for a cold start."""
    wanted = scene.solver.warm_start
    if wanted != NEAREST:
        return (wanted, None) if wanted else None
    return nearest(scene, store.succeeded_scenes(MEMORY))


def _warm_start(store: JobStore, scene: Scene) -> tuple[Plan, str, float | None] | None:
    """The earlier plan the scene starts from, its job's id and distance (`_start_from`);
    None for a cold start, or when that job has no plan (any more)."""
    start_from = _start_from(store, scene)
    if start_from is None:
        return None
    earlier = _earlier(store, start_from[0])
    return None if earlier is None else (earlier, *start_from)


def _started_from(plan: Plan, job_id: str, distance: float | None) -> Plan:
    """The plan with the job it started from in its solver report."""
    report = plan.solver.model_copy(update={"warm_start": job_id,
                                            "warm_start_distance": distance})
    return plan.model_copy(update={"solver": report})


def _earlier(store: JobStore, job_id: str) -> Plan | None:
    """The plan of an earlier job with the NLP solution it came from, to warm-start from
    (None when there is none, or only one of an older schema: `app.stored_plan`)."""
    record = store.get(job_id)
    plan = None if record is None or record.plan is None else current(record.plan)
    if plan is None:
        return None
    solution = store.solution(job_id)
    if solution is None:
        return plan
    return plan.model_copy(update={"solution": NlpSolution.model_validate(solution)})


def _failed(store: JobStore, job_id: str, error: str, start: float, worker: str | None,
            exhausted: bool = False) -> JobEnd:
    persist(lambda: store.finish(job_id, "failed", None, error, worker=worker),
            f"job {job_id}: writing its verdict")
    return JobEnd(job_id, "failed", time.monotonic() - start, exhausted)


def _stop_requested(channel: Connection, wait: float) -> bool:
    """Read the supervisor's messages, waiting up to `wait` s for one; True on STOP or
    when the supervisor is gone."""
    try:
        while channel.poll(wait):
            if channel.recv() == STOP:
                return True
            wait = 0.0
    except (EOFError, OSError):
        return True
    return False


def _watch(parent: int) -> None:
    """Exit this worker when its supervising process is gone (e.g. killed with SIGKILL),
    first requeueing its job (an infrastructure failure, so another worker or node runs
    it again): an orphan must not keep solving."""
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL)
    current = _current
    if current is not None:
        store, job_id, worker = current
        with contextlib.suppress(StoreUnavailable):  # else its lease runs out
            status = persist(lambda: store.requeue(job_id, worker, PARENT_DIED),
                             f"job {job_id}: giving it back", give_up=ORPHAN_TRIES)
            log.warning("job %s: %s; %s", job_id, PARENT_DIED, status or "already settled")
    os._exit(0)


def _take(spec: WorkerSpec, channel: Connection, record: JobRecord) -> JobEnd | None:
    """Run a claimed job; None when it was given back (STOP arrived meanwhile)."""
    if _stop_requested(channel, 0.0):
        persist(lambda: spec.store.release(record.id, spec.name, "the worker was stopping"),
                f"job {record.id}: giving it back", give_up=spec.lease)
        return None
    try:
        scene = Scene.model_validate(record.scene)
    except ValueError as exc:  # a scene stored by another version of the service
        return _failed(spec.store, record.id, f"invalid stored scene: {exc}", time.monotonic(),
                       spec.name)
    channel.send(Claimed(record.id, scene.solver.max_wall_time))
    return run_job(spec.store, record.id, scene, spec.solve, spec.memory_mb, spec.name)


class _Listening:
    """An idle worker's wait for work: its supervisor's pipe and the store's announcements
    of queued jobs (`JobStore.listen`; reopened after a failure, polling meanwhile; never
    on a store that announces nothing)."""

    def __init__(self, store: JobStore, channel: Connection):
        self.store, self.channel = store, channel
        self.listener: Listener | None = None
        self.retry_at = 0.0

    def _open(self) -> None:
        if self.listener is not None or time.monotonic() < self.retry_at:
            return
        try:
            self.listener = self.store.listen()
        except Exception as exc:  # noqa: BLE001 - any failure: poll, try again later
            log.warning("LISTEN failed (polling meanwhile): %s", exc)
            self.retry_at = time.monotonic() + LISTEN_RETRY
            return
        if self.listener is None:  # the store announces nothing: poll for good
            self.retry_at = math.inf

    def _drop(self) -> None:
        if self.listener is not None:
            self.listener.close()
        self.listener, self.retry_at = None, time.monotonic() + LISTEN_RETRY

    def stop_requested(self, timeout: float) -> bool:
        """Wait up to `timeout` s for a message or an announcement; True on STOP or when
        the supervisor is gone."""
        self._open()
        if self.listener is None or timeout <= 0.0:
            return _stop_requested(self.channel, timeout)
        try:
            announced = self.listener.fileno()
            if announced in wait([self.channel, announced], timeout):
                self.listener.drain()
        except Exception as exc:  # noqa: BLE001 - the listening connection broke
            log.warning("LISTEN connection lost (polling meanwhile): %s", exc)
            self._drop()
        return _stop_requested(self.channel, 0.0)

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()


def serve(spec: WorkerSpec, channel: Connection) -> None:
    """The worker process: claim and run jobs until STOP, a lost supervisor, or a job
    that ran out of memory."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C and SIGTERM are for the
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # supervisor to handle
    configure(spec.log_level)
    threading.Thread(target=_watch, args=(os.getppid(),), daemon=True,
                     name="orphan-watch").start()
    if spec.memory_mb is not None:
        limit_growth(spec.memory_mb)
    idle = _Listening(spec.store, channel)
    channel.send(READY)
    wait_for, unsure = 0.0, False
    try:
        while not idle.stop_requested(wait_for):
            try:
                if unsure:  # a claim whose answer was lost may have been made
                    spec.store.release_claimed(spec.name, "the answer to its claim was lost")
                    unsure = False
                unsure = True
                record = spec.store.claim(spec.owner, spec.name, time.time() + spec.lease)
                unsure = False
                end = None if record is None else _take(spec, channel, record)
            except StoreUnavailable as exc:
                log.error("worker %s: %s", spec.name, exc)
                wait_for = IDLE_POLL
                continue
            if record is not None and end is None:
                return
            wait_for = IDLE_POLL if record is None else 0.0
            if end is not None:
                channel.send(end)
                if end.exhausted:
                    return
    finally:
        idle.close()
