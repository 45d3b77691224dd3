"""A solver worker: a process that claims queued plan jobs from the store and solves them,
one at a time (`app.job_run`), until it is told to stop.

Its supervisor (`app.supervisor`) talks to it over a pipe (`app.worker_pipe`): WAKE when a
job was queued, STOP to end; the worker answers READY once started, `Claimed` when it
takes a job (its claim writes progress `{"phase": "building"}`) and the job's `JobEnd`
when it ends. The worker limits its own memory (UNDERTOW_WORKER_MEMORY_MB) and leaves
after a job that ran out of it, so a fresh process takes its place. A watchdog thread
requeues its job (an infrastructure failure: the node's main process died) and exits
when the supervising process is gone. SIGINT and SIGTERM are for the supervisor to
handle: it gives the running jobs back before it stops its workers.

A claim whose answer was lost (the connection broke after the database committed it) is
given back as soon as the store answers again. A job whose messages are of a newer version
than this one knows (`app.admission.MESSAGE_VERSION`: stored by a server of a newer version
during a rolling upgrade) is given back the same way, and the worker claims nothing more:
its node is outdated, and waits to be replaced. An idle worker waits for its supervisor
and for the store's announcements of queued jobs (`app.idle_wait`), and looks every
`IDLE_POLL` seconds regardless.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

from app import startup_objects
from app.admission import MESSAGE_VERSION, message_version, stored
from app.idle_wait import IdleWait
from app.job_run import SolveFunction, fail, run_job, running
from app.logging import configure
from app.procmem import limit_growth
from app.store import JobRecord, JobStore, StoreUnavailable
from app.store_retry import persist
from app.worker_pipe import READY, Claimed, JobEnd, stop_requested
from planner.service import Scene

log = logging.getLogger("undertow.worker")

IDLE_POLL = 1.0  # [s] an idle worker looks for queued jobs at least this often
WATCH_INTERVAL = 0.25  # [s] between two checks that the supervising process still runs
ORPHAN_TRIES = 20.0  # [s] an orphaned worker tries this long to give its job back
PARENT_DIED = "the node's main process died (killed?) while the job ran"
LOST_ANSWER = "the answer to its claim was lost"


def load_function(spec: str) -> SolveFunction:
    """The function named "package.module:function"."""
    module, _, name = spec.partition(":")
    if not name:
        raise ValueError(f"solve_function: expected 'module:function', got {spec!r}")
    return getattr(importlib.import_module(module), name)


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


def _watch(parent: int) -> None:
    """Exit this worker when its supervising process is gone (e.g. killed with SIGKILL),
    first requeueing its job (an infrastructure failure, so another worker or node runs
    it again): an orphan must not keep solving."""
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL)
    current = running()
    if current is not None:
        store, job_id, worker = current
        with contextlib.suppress(StoreUnavailable):  # else its lease runs out
            status = persist(lambda: store.requeue(job_id, worker, PARENT_DIED),
                             f"job {job_id}: giving it back", give_up=ORPHAN_TRIES)
            log.warning("job %s: %s; %s", job_id, PARENT_DIED, status or "already settled")
    os._exit(0)


def outdated(spec: WorkerSpec, record: JobRecord) -> str | None:
    """Why the claimed job is to be given back (released: queued again at once, counted
    as nothing) when its messages are of a newer version than this worker knows, else
    None."""
    found = message_version(record)
    if found <= MESSAGE_VERSION:
        return None
    reason = (f"its messages are of version {found}, newer than version {MESSAGE_VERSION} "
              "that this node knows: left to a node of a newer version")
    log.warning("worker %s: job %s %s; this worker claims nothing more (upgrade its node)",
                spec.name, record.id, reason)
    return reason


def _take(spec: WorkerSpec, channel: Connection, record: JobRecord) -> JobEnd | None:
    """Run a claimed job; None when it was given back (STOP arrived meanwhile)."""
    if stop_requested(channel, 0.0):
        persist(lambda: spec.store.release(record.id, spec.name, "the worker was stopping"),
                f"job {record.id}: giving it back", give_up=spec.lease)
        return None
    try:
        scene = Scene.model_validate(record.scene)
    except ValueError as exc:  # a scene stored by another version of the service
        return fail(spec.store, record.id, f"invalid stored scene: {exc}", time.monotonic(),
                    spec.name)
    channel.send(Claimed(record.id, scene.solver.max_wall_time))
    return run_job(spec.store, record.id, scene, spec.solve, spec.memory_mb, spec.name,
                   stored(record))


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
    idle = IdleWait(spec.store, channel)
    startup_objects.freeze()
    channel.send(READY)
    wait_for, retired = 0.0, False
    give_back: str | None = None  # why this worker's claims are to be given back
    try:
        while not idle.stop_requested(wait_for):
            try:
                if give_back is not None:
                    spec.store.release_claimed(spec.name, give_back)
                    give_back = None
                if retired:
                    wait_for = IDLE_POLL
                    continue
                give_back = LOST_ANSWER  # until the claim's answer is in
                record = spec.store.claim(spec.owner, spec.name, time.time() + spec.lease)
                give_back = None if record is None else outdated(spec, record)
                if give_back is not None:
                    retired, wait_for = True, 0.0
                    continue
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
