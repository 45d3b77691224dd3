"""One claimed plan job run to its verdict, inside a solver worker (`app.worker`).

The worker writes everything about its job to the store itself: Ipopt's iterations
(throttled; a cancel flag or a lost claim stops the solve at the next iteration) and the
verdict. Each job gets its own progress reporter and its own scene; nothing of one job is
kept for the next. A job's wall-time budget, `solver.max_wall_time`, counts from the
claim, NLP build included: once it is spent, the next iteration stops the solve.

The store may fail for a while during a solve (a database restart): progress that cannot
be written is written later, and the verdict (and the reads before it) are retried with
backoff until the store answers (`app.store_retry`), so a row is never left running by a
worker that moved on.
"""

from __future__ import annotations

import dataclasses
import logging
import math
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
    reporter = _Reporter(store, job_id, start + budget, worker)
    try:
        arguments = persist(lambda: given(store, scene, admission), f"job {job_id}: warm start")
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
    reporter.flush()
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
