"""Supervision of local solver workers: independent processes (spawn), each of which
claims jobs from the store (`app.worker`), watched by one thread of the service.

The supervisor starts `workers` processes once there is work (the first `wake`) and
replaces any that exits. It learns what each worker runs from the worker's own messages
and holds it to three bounds:

- wall time: a job still running `grace` seconds after its budget (`solver.max_wall_time`,
  counted from the claim) has its worker killed and fails, saying so;
- cancellation: a job whose cancel flag has been set for `CANCEL_GRACE` seconds without
  the solver stopping (e.g. during the NLP build) has its worker killed and is cancelled;
- the worker's death (killed, the OOM killer, a crash): an infrastructure failure of its
  job alone, which is requeued at once (`JobStore.requeue`: after a pause, up to
  UNDERTOW_MAX_RETRIES times, then a dead letter).

Every round it has the store verify its integrity (`JobStore.verify`: a check whenever
one is due), so that damage is found without waiting for a request; every
`PURGE_INTERVAL` it deletes the finished jobs past their retention (age, count or bytes).
It also renews the leases of the jobs it knows its workers run (by job and worker, reading
their cancel flags in the same statement) and settles jobs whose lease ran out, of any
server or worker sharing the store (`JobStore.expire`, an infrastructure failure too). A
supervisor with no workers (an API-only server) still does that. A server's supervisor
runs workers that claim the server's own jobs; `undertow worker` runs one whose workers
claim anyone's. On stop (SIGTERM, Ctrl-C), every worker is told to claim nothing more and
the busy ones get `drain` seconds to end their jobs (renewed and held to their bounds
meanwhile); then idle workers leave at once, busy ones are killed and their jobs released
(queued again at once, not counted as a failure) for another worker or node, or the next
start; queued jobs stay queued.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import multiprocessing
import signal
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess

from app.job_run import SolveFunction
from app.store import JobStatus, JobStore, Retention, StoreUnavailable
from app.store_retry import persist
from app.worker import WorkerSpec, serve
from app.worker_pipe import READY, STOP, WAKE, Claimed, JobEnd

log = logging.getLogger("undertow.supervisor")

TICK = 0.25  # [s] between two rounds of checks
LEASE = 60.0  # [s] a claim holds without renewal (default of UNDERTOW_LEASE)
EXPIRE_INTERVAL = 15.0  # [s] longest time between two looks for jobs whose lease ran out
CANCEL_GRACE = 2.0  # [s] a cancelled job's solver has to stop before its worker is killed
STOP_WAIT = 5.0  # [s] idle workers have to leave on stop
MAX_BACKOFF = 30.0  # [s] longest pause before restarting a worker that failed to start
FAILED_STARTS = 3  # workers in a row that exit before they are ready: the workers are broken
WORKER_DIED = "the worker process died during the solve"
STOPPING = "the worker's node or server was stopping"
HEARTBEAT = 5.0  # [s] between two heartbeats of a supervisor with workers (GET /v1/workers)
PURGE_INTERVAL = 600.0  # [s] between two deletions of jobs past their retention
RELEASE_TRIES = 5.0  # [s] a stopping supervisor tries this long to give its jobs back


def _how(exitcode: int | None) -> str:
    """How a process ended: "killed by signal SIGKILL", "exit status 1"."""
    if exitcode is not None and exitcode < 0:
        return f"killed by signal {signal.Signals(-exitcode).name}"
    return f"exit status {exitcode}"


def died(exitcode: int | None) -> str:
    """The error of a job whose worker process died: how, and the likely cause."""
    return f"{WORKER_DIED} ({_how(exitcode)}; out of memory?)"


def over_budget(budget: float, grace: float) -> str:
    """The error of a job whose worker was stopped for running past its budget."""
    return (f"the job ran past its wall-time budget of {budget:g} s (solver.max_wall_time, "
            f"NLP build included) plus {grace:g} s grace (UNDERTOW_WALL_TIME_GRACE); its "
            "worker process was stopped")


CANCELLED_STOPPED = (f"cancelled on request; the solver did not stop within {CANCEL_GRACE:g} s "
                     "(e.g. during the NLP build), so its worker process was stopped")


@dataclass
class _Worker:
    """One worker process as the supervisor sees it."""

    name: str
    process: BaseProcess
    channel: Connection
    ready: bool = False
    job: str | None = None
    job_started: float = 0.0
    deadline: float = float("inf")
    budget: float = 0.0
    cancel_seen: float | None = None
    fate: tuple[str, JobStatus, str] | None = field(default=None)
    """(job id, status, error) the job gets once the killed process is gone."""


class Supervisor:
    """Runs `workers` solver processes claiming jobs of `owner` from `store` (of anyone
    when `any_owner`; the workers' names start with "owner/" either way).

    `on_done(end)` runs in the supervising thread whenever a job ends, by its worker's
    report or by the supervisor's verdict. `lease` [s] is how long a claim holds without
    renewal; `drain` [s] how long `stop` lets running jobs end before it releases them."""

    def __init__(self, store: JobStore, solve: SolveFunction, owner: str, workers: int,
                 memory_mb: float | None, grace: float, log_level: str = "INFO",
                 on_done: Callable[[JobEnd], None] | None = None, lease: float = LEASE,
                 any_owner: bool = False, retention: Retention | None = None,
                 drain: float = 0.0):
        self.store, self.solve, self.owner = store, solve, owner
        self.count, self.memory_mb, self.grace = workers, memory_mb, grace
        self.log_level, self.on_done = log_level, on_done
        self.lease, self.any_owner, self.retention = lease, any_owner, retention
        self.drain = drain
        self._next_purge = self._next_heartbeat = 0.0
        self._started = time.time()
        self._expire_interval = min(EXPIRE_INTERVAL, lease / 4)
        self._context = multiprocessing.get_context("spawn")
        self._slots: list[_Worker | None] = [None] * workers
        self._restart_at = [0.0] * workers
        self._failed_starts = 0
        self._last_exit: int | None = None
        self._send_lock = threading.Lock()
        self._stopping = threading.Event()
        self._draining = False
        self._thread = threading.Thread(target=self._run, name="supervisor", daemon=True)
        self._next_expiry = 0.0
        self._store_error: str | None = None
        self._wanted = False

    def start(self) -> None:
        """Start the supervising thread; the workers start with the first `wake`."""
        self._thread.start()

    @property
    def problem(self) -> str | None:
        """Why the workers cannot run jobs, or None when they can."""
        if not self._thread.is_alive() and not self._stopping.is_set():
            return "the solver worker supervisor is not running"
        if self._failed_starts >= FAILED_STARTS and not any(w and w.ready for w in self._slots):
            return (f"no solver worker process could start ({self._failed_starts} tries in a "
                    f"row, the last one ended with {_how(self._last_exit)}; see the log)")
        return None

    def busy(self) -> int:
        """Worker processes running a job now."""
        return sum(w is not None and w.job is not None for w in self._slots)

    def wake(self) -> None:
        """Tell the idle workers that a job was queued (starting them the first time)."""
        self._wanted = True
        for worker in self._slots:
            if worker is not None and worker.job is None:
                self._send(worker, WAKE)

    def stop(self) -> None:
        """Stop every worker: queued jobs stay queued, running ones that do not end within
        `drain` seconds are released (queued again at once for another worker, or the next
        start) once their worker is gone."""
        self._draining = True  # no worker is started again
        for worker in self._slots:
            if worker is not None:
                self._send(worker, STOP)  # read by the worker before it claims again
        self._let_jobs_end()
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join()
        workers = [w for w in self._slots if w is not None]
        for worker in workers:
            self._send(worker, STOP)  # again, for one started as the stop began
            self._drain(worker)
        deadline = time.monotonic() + STOP_WAIT
        for worker in workers:
            if worker.job is None:
                worker.process.join(max(0.0, deadline - time.monotonic()))
        for worker in workers:
            if worker.process.is_alive():
                worker.process.kill()
            worker.process.join()
            worker.channel.close()
        for worker in workers:
            try:
                released = persist(functools.partial(self.store.release_claimed, worker.name,
                                                     STOPPING),
                                   f"stopping worker {worker.name}", give_up=RELEASE_TRIES)
            except StoreUnavailable as exc:  # their leases run out instead
                log.error("stopping worker %s: %s", worker.name, exc)
                continue
            for job_id in released:
                log.warning("job %s released: %s", job_id, STOPPING)
        if self.count:
            with contextlib.suppress(StoreUnavailable):
                self.store.forget_worker(self.owner)

    def _let_jobs_end(self) -> None:
        """Wait up to `drain` seconds for the workers to leave (idle ones at once, busy ones
        when their job ends; a job claimed but not yet reported is waited for too), while
        the supervising thread goes on renewing the jobs' leases and holding them to their
        bounds."""
        if self.drain <= 0.0:
            return
        deadline = time.monotonic() + self.drain
        log.info("stopping: the running jobs have %g s to end", self.drain)
        while (any(w is not None for w in self._slots) and time.monotonic() < deadline
               and self._thread.is_alive()):
            time.sleep(TICK)

    def _spawn(self, slot: int) -> None:
        name = f"{self.owner}/{slot}/{uuid.uuid4().hex[:8]}"
        spec = WorkerSpec(self.store, self.solve, None if self.any_owner else self.owner, name,
                          self.memory_mb, self.lease, self.log_level)
        ours, theirs = self._context.Pipe()
        process = self._context.Process(target=serve, args=(spec, theirs), name=name,
                                        daemon=True)
        process.start()
        theirs.close()
        worker = self._slots[slot] = _Worker(name, process, ours)
        if self._draining:  # started as the stop began: it claims nothing
            self._send(worker, STOP)

    def _send(self, worker: _Worker, message: str) -> None:
        # a gone worker raises OSError here; its sentinel tells the supervisor
        with self._send_lock, contextlib.suppress(OSError):
            worker.channel.send(message)

    def _run(self) -> None:
        while not self._stopping.is_set():
            try:
                self._step()
                if self._store_error is not None:
                    log.info("the job store is available again")
                    self._store_error = None
            except StoreUnavailable as exc:
                if str(exc) != self._store_error:
                    log.error("supervisor: %s", exc)
                    self._store_error = str(exc)
                self._stopping.wait(TICK)
            except Exception:  # the supervisor must outlive any one error
                log.exception("supervisor step failed")
                self._stopping.wait(TICK)

    def _step(self) -> None:
        """Wait for messages and exits, then enforce budgets, cancels and leases."""
        waitables: dict[object, tuple[int, _Worker]] = {}
        handles: list[Connection | int] = []
        for slot, worker in enumerate(self._slots):
            if worker is not None:
                waitables[worker.channel] = waitables[worker.process.sentinel] = (slot, worker)
                handles += [worker.channel, worker.process.sentinel]
        for ready in wait(handles, timeout=TICK):
            slot, worker = waitables[ready]
            if self._slots[slot] is not worker:
                continue  # reaped in this round already
            if ready is worker.process.sentinel:
                self._reap(slot, worker)
            else:
                self._drain(worker)
        now = time.monotonic()
        for slot, worker in enumerate(self._slots):
            if (worker is None and self._wanted and not self._draining
                    and now >= self._restart_at[slot]):
                self._spawn(slot)
            elif (worker is not None and worker.job is not None and worker.fate is None
                  and now > worker.deadline):
                self._kill(worker, worker.job, "failed", over_budget(worker.budget, self.grace))
        self._enforce_cancels(now)
        if now >= self._next_expiry:
            self._next_expiry = now + self._expire_interval
            # a claim whose lease runs out before the next look is taken now: a job of a
            # dead process stays `running` for at most a lease after its last renewal
            upcoming = time.time() + self._expire_interval
            for job_id, status in self.store.expire(upcoming).items():
                log.warning("job %s lost its worker (lease ran out): %s", job_id,
                            "requeued" if status == "queued" else status)
                if status == "queued":
                    self.wake()
        if self.count and now >= self._next_heartbeat:
            self._next_heartbeat = now + HEARTBEAT
            self.store.heartbeat(self.owner, self.count, self.busy(), self._started)
        self.store.verify()
        if self.retention is not None and now >= self._next_purge:
            self._next_purge = now + PURGE_INTERVAL
            kept = self.retention
            purged = self.store.purge(time.time() - kept.age, kept.count, kept.size)
            if purged:
                log.info("%d finished jobs past their retention deleted", purged)

    def _drain(self, worker: _Worker) -> None:
        """Handle every message the worker has sent."""
        try:
            while worker.channel.poll():
                self._handle(worker, worker.channel.recv())
        except (EOFError, OSError):
            pass  # the process ended; its sentinel tells the supervisor

    def _handle(self, worker: _Worker, message: object) -> None:
        if message == READY:
            worker.ready, self._failed_starts = True, 0
        elif isinstance(message, Claimed):
            now = time.monotonic()
            worker.job, worker.job_started, worker.budget = message.job_id, now, message.budget
            worker.deadline, worker.cancel_seen = now + message.budget + self.grace, None
        elif isinstance(message, JobEnd):
            worker.job, worker.deadline = None, float("inf")
            self._done(message)

    def _done(self, end: JobEnd) -> None:
        if self.on_done is not None:
            self.on_done(end)

    def _enforce_cancels(self, now: float) -> None:
        """Renew the leases of running jobs; kill workers that ignore a cancel."""
        busy = {w.job: w for w in self._slots if w is not None and w.job is not None}
        if not busy:
            return
        flags = self.store.renew([(job, w.name) for job, w in busy.items()],
                                 time.time() + self.lease)
        for job_id, cancelled in flags.items():
            worker = busy.get(job_id)
            if worker is None or not cancelled or worker.fate is not None:
                continue
            if worker.cancel_seen is None:
                worker.cancel_seen = now
            elif now - worker.cancel_seen > CANCEL_GRACE:
                self._kill(worker, job_id, "cancelled", CANCELLED_STOPPED)

    def _kill(self, worker: _Worker, job_id: str, status: JobStatus, error: str) -> None:
        """Kill the worker running job `job_id`; the job ends `status` once it is gone."""
        log.warning("job %s: %s", job_id, error)
        worker.fate = (job_id, status, error)
        worker.process.kill()

    def _reap(self, slot: int, worker: _Worker) -> None:
        """A worker process ended: settle its job, schedule its replacement."""
        self._drain(worker)
        worker.process.join()
        exitcode = worker.process.exitcode
        self._slots[slot] = None
        worker.channel.close()
        if not worker.ready:
            self._failed_starts += 1
            self._last_exit = exitcode
            backoff = min(MAX_BACKOFF, 0.5 * 2 ** (self._failed_starts - 1))
            self._restart_at[slot] = time.monotonic() + backoff
            log.error("worker %s exited during start-up (%s); restarting in %g s",
                      worker.name, _how(exitcode), backoff)
        if worker.fate is not None:
            job_id, status, error = worker.fate
            if self.store.finish(job_id, status, None, error, worker=worker.name):
                self._done(JobEnd(job_id, status, time.monotonic() - worker.job_started))
        reason = died(exitcode)
        for job_id, status in self.store.requeue_claimed(worker.name, reason).items():
            log.warning("job %s: %s; %s", job_id, reason,
                        "requeued" if status == "queued" else status)
            if status != "queued":
                self._done(JobEnd(job_id, status, time.monotonic() - worker.job_started))
