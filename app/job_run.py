"""One claimed plan job run to its verdict, inside a solver worker (`app.worker`).

The worker writes everything about its job to the store itself: Ipopt's iterations
(throttled; a cancel flag or a lost claim stops the solve at the next iteration) and the
verdict. Each job gets its own progress reporter and its own scene; nothing of one job is
kept for the next. A job's wall-time budget, `solver.max_wall_time`, counts from the
claim (less a wait for a store that is away before the solve), NLP build included: once it
is spent, the next iteration stops the solve.

The store may fail for a while during a solve (a database restart): progress is written by
a thread of its own, so the solve never waits for the store, and progress that cannot be
written is tried again later (`_Reporter`); the verdict (and the reads before it) are
retried with backoff until the store answers (`app.store_retry`), so a row is never left
running by a worker that moved on.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from app.admission import Admission, given
from app.store import CANCELLED_ON_REQUEST, JobStatus, JobStore, StoreUnavailable
from app.store_retry import persist
from app.worker_pipe import JobEnd
from planner.service import Plan, Progress, Scene, unverified_reason

log = logging.getLogger("undertow.worker")

SolveFunction = Callable[..., Plan]
"""solve(scene, progress=callback, issues=..., warm_start=...) -> Plan, never raising for a
solver failure; `issues` and `warm_start` as `planner.service.plan` takes them, each given
only when decided (`app.admission.given`)."""

PROGRESS_INTERVAL = 0.2  # [s] between two progress writes of one job

_current: tuple[JobStore, str, str | None] | None = None
"""The job this process is solving (store, job id, worker): `running`."""


def running() -> tuple[JobStore, str, str | None] | None:
    """The job this process is solving now (store, job id, worker), or None: what an
    orphaned worker gives back before it exits."""
    return _current


def out_of_memory(limit_mb: float | None) -> str:
    """The error of a job whose solve ran out of memory."""
    where = (f"the {limit_mb:g} MB a solver worker may use (UNDERTOW_WORKER_MEMORY_MB)"
             if limit_mb is not None else "the memory available")
    return (f"out of memory: the NLP needed more than {where}; use fewer intervals, a "
            "lower degree or fewer links")


def _finite(value: Any) -> Any:
    return value if not isinstance(value, float) or math.isfinite(value) else None


class _Reporter:
    """The progress callback of one job: throttled writes, cancel checks, the budget.

    The solver's iteration never waits on the store: the callback leaves the latest
    progress in a one-place mailbox and a writer thread writes it (at most every
    PROGRESS_INTERVAL), reading the cancel flag back; a write the store refuses (an
    outage) is counted in `unwritten` and the latest progress is tried again later. So a
    store that is away costs the solve nothing: its wall-time budget counts solving only,
    and an outage never ends a plan Maximum_WallTime_Exceeded."""

    def __init__(self, store: JobStore, job_id: str, deadline: float, worker: str | None):
        self.store, self.job_id, self.deadline, self.worker = store, job_id, deadline, worker
        self.go_on, self.expired = True, False
        self.unwritten = 0
        self._latest: dict[str, Any] | None = None
        self._lock, self._wake, self._closing = threading.Lock(), threading.Event(), \
            threading.Event()
        self._writer = threading.Thread(target=self._write_loop, daemon=True,
                                        name=f"progress-{job_id}")
        self._writer.start()

    def __call__(self, progress: Progress) -> bool:
        latest = {"phase": "solving",
                  **{k: _finite(v) for k, v in dataclasses.asdict(progress).items()}}
        with self._lock:
            self._latest = latest
        self._wake.set()
        if time.monotonic() > self.deadline:
            self.expired = True
        return self.go_on and not self.expired

    def close(self, wait: float = 2 * PROGRESS_INTERVAL) -> None:
        """Write the last progress if the store takes it within `wait` seconds [s], and
        stop the writer (a write still blocked on the store is left to finish by itself:
        the verdict does not wait for it). A writer pausing between two writes is woken
        at once: the verdict does not wait for the pause either."""
        self._closing.set()
        self._wake.set()
        self._writer.join(wait)
        if self.unwritten:
            log.warning("job %s: %d progress writes not made while the store was away",
                        self.job_id, self.unwritten)

    def _write_loop(self) -> None:
        last = -math.inf
        while not self._closing.is_set():
            self._wake.wait()
            pause = PROGRESS_INTERVAL - (time.monotonic() - last)
            if pause > 0:
                self._closing.wait(pause)
            self._wake.clear()
            last = self._write_latest(last)
        self._write_latest(last)  # progress that came during the last write, once

    def _write_latest(self, last: float) -> float:
        """Write the latest progress, if any came since the last write; when this write
        began (`last` without one)."""
        with self._lock:
            latest, self._latest = self._latest, None
        if latest is None:
            return last
        began = time.monotonic()
        self._write(latest)
        return began

    def _write(self, latest: dict[str, Any]) -> None:
        """Write one progress and read the cancel flag; refused, keep it for the next
        write unless newer progress came meanwhile."""
        try:
            self.go_on = self.store.report_progress(self.job_id, latest, self.worker)
        except StoreUnavailable as exc:
            self.unwritten += 1
            log.warning("job %s: progress not written (the next is tried later): %s",
                        self.job_id, exc)
        except Exception:  # a bug here must not stop the progress of the job
            self.unwritten += 1
            log.exception("job %s: progress not written", self.job_id)
        else:
            return
        with self._lock:
            if self._latest is None:
                self._latest = latest
        self._wake.set()


def _verdict(plan: Plan, cancel_requested: bool, expired: bool,
             budget: float) -> tuple[JobStatus, str | None]:
    """Final status and error of a returned plan, from the plan's own verdict
    (`plan.status`, `plan.message`): a verified plan succeeded, any other failed with its
    message ("unverified: ...", "infeasible: ...", ...), unless it was cancelled or ran past
    the job's budget. A plan without a verdict of its own (one made elsewhere than the
    planner) is judged by its solver report and verification."""
    if plan.status == "verified":
        return "succeeded", None
    if plan.status is None and plan.solver.success:
        reason = unverified_reason(plan.verification)
        return ("succeeded", None) if reason is None else ("failed", f"unverified: {reason}")
    if cancel_requested and plan.status != "unverified":
        return "cancelled", CANCELLED_ON_REQUEST
    if plan.status in ("unverified", "infeasible", "solver-failure") and plan.message:
        return "failed", plan.message
    if plan.infeasibility is not None:
        return "failed", f"infeasible: {plan.infeasibility.summary}"
    if expired:
        return "failed", (f"Maximum_WallTime_Exceeded: the job's wall-time budget of "
                          f"{budget:g} s (solver.max_wall_time, NLP build included) ran out")
    message = plan.solver.message
    return "failed", f"{plan.solver.status}: {message}" if message else plan.solver.status


def run_job(store: JobStore, job_id: str, scene: Scene, solve: SolveFunction,
            memory_mb: float | None = None, worker: str | None = None,
            admission: Admission | None = None) -> JobEnd:
    """Solve one job claimed by `worker`, as its `admission` decided (`app.admission`), and
    store its verdict (unless the job was taken from `worker` meanwhile: its lease ran out
    and another worker holds it)."""
    global _current
    start, budget = time.monotonic(), scene.solver.max_wall_time
    _current = (store, job_id, worker)
    reporter = None
    try:
        arguments = persist(lambda: given(store, scene, admission), f"job {job_id}: warm start")
        # the budget counts from here: a wait above for a store that is away is not solving
        reporter = _Reporter(store, job_id, time.monotonic() + budget, worker)
        plan = solve(scene, progress=reporter, **arguments)
    except MemoryError:
        return fail(store, job_id, out_of_memory(memory_mb), start, worker, exhausted=True)
    except Exception as exc:  # noqa: BLE001 - any error fails the job, the worker lives
        if "bad_alloc" in str(exc):  # C++ allocation failure, raised through CasADi
            return fail(store, job_id, out_of_memory(memory_mb), start, worker,
                        exhausted=True)
        return fail(store, job_id, f"solver error: {type(exc).__name__}: {exc}", start,
                    worker)
    finally:
        _current = None
        if reporter is not None:
            reporter.close()
    current = persist(lambda: store.get(job_id), f"job {job_id}: reading its cancel flag")
    status, error = _verdict(plan, bool(current and current.cancel_requested),
                             reporter.expired, budget)
    solution = plan.solution.model_dump(mode="json") if plan.solution is not None else None
    body = plan.model_dump(mode="json")
    persist(lambda: store.finish(job_id, status, body, error, solution, worker),
            f"job {job_id}: writing its verdict")
    return JobEnd(job_id, status, time.monotonic() - start)


def fail(store: JobStore, job_id: str, error: str, start: float, worker: str | None,
         exhausted: bool = False) -> JobEnd:
    """Store the job's failure with `error` (held by `worker`; `start`: the monotonic
    time its run began) and report it; `exhausted` when it ran out of memory."""
    persist(lambda: store.finish(job_id, "failed", None, error, worker=worker),
            f"job {job_id}: writing its verdict")
    return JobEnd(job_id, "failed", time.monotonic() - start, exhausted)
