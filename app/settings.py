"""Service settings, read from UNDERTOW_* environment variables (pydantic-settings)."""

from __future__ import annotations

import os
import socket
from functools import lru_cache

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.procmem import MB
from app.store.base import Retention
from planner.model import MAX_LINKS

PLAN_PROCESSES = "UNDERTOW_SOLVER_PROCESSES"
"""The environment variable the planner reads for the processes one plan may use; the
service sets it for its workers from `Settings.plan_processes`."""
REMOVED_QUEUE = "UNDERTOW_QUEUE"
"""The variable that chose between procrastinate and undertow's own PostgreSQL queue; the
own queue was removed, and the variable with it (`get_settings`)."""


class Settings(BaseSettings):
    """Every knob of the service; each field is the env var UNDERTOW_<NAME>."""

    model_config = SettingsConfigDict(env_prefix="UNDERTOW_", frozen=True)

    db_url: str | None = Field(default=None, description=(
        "PostgreSQL job store, postgresql://user:password@host:port/database; shared by "
        "servers and workers on any machine (unset: the SQLite file at UNDERTOW_DB_PATH)"))
    db_path: str = Field(default="var/undertow-jobs.sqlite3",
                         description="SQLite job store file (relative to the working directory)")
    instance: str = Field(default_factory=socket.gethostname,
                          description="name of this server; jobs its own workers leave "
                                      "running are requeued when a server of that "
                                      "name starts. One live server of a name per store: "
                                      "a second one refuses to start")
    workers: int = Field(default=2, ge=0, le=64, description=(
        "solver worker processes of this server (0: an API-only server, whose jobs "
        "`undertow worker` processes run)"))
    solver_processes: int | None = Field(default=None, ge=1, le=8, description=(
        "processes one plan may use (a plan's continuation start runs in a second one "
        "beside its other starts, on a core no other plan holds; docs/planner.md, \"Both "
        "cores\"); unset: the machine's cores"))
    lease: float = Field(default=60.0, ge=1.0, le=3600.0, description=(
        "seconds a worker's claim on a job holds without renewal (renewed every 0.25 s); a "
        "job whose worker stays silent that long has had an infrastructure failure and is "
        "requeued (UNDERTOW_MAX_RETRIES)"))
    drain: float = Field(default=0.0, ge=0.0, le=3600.0, description=(
        "seconds a stopping server or worker node (SIGTERM, Ctrl-C) lets its running solves "
        "end, claiming nothing new, before it releases those still running to other nodes "
        "(0: at once); keep it below the stop's grace period (`docker stop -t`)"))
    max_retries: int = Field(default=3, ge=0, le=100, description=(
        "requeues a job gets after infrastructure failures (its worker process or node "
        "died, its lease ran out, its server stopped under it); one more failure ends it "
        "failed as a dead letter. Solver failures are never retried by themselves"))
    retry_backoff: float = Field(default=1.0, ge=0.0, le=3600.0, description=(
        "seconds before a requeued job may be claimed again after its first infrastructure "
        "failure; doubled after each further one"))
    retry_max_backoff: float = Field(default=60.0, ge=0.0, le=86400.0, description=(
        "longest pause before a requeued job may be claimed again [s]"))
    worker_memory_mb: int = Field(default=4096, ge=64, description=(
        "memory a solver worker may take beyond its start-up size [MB]: plans estimated "
        "above it are refused (422), a solve that needs more fails"))
    wall_time_grace: float = Field(default=30.0, gt=0.0, description=(
        "seconds a job may run past its wall-time budget (NLP build included) before its "
        "worker process is stopped; keep it above 5 s, the margin within which a plan "
        "returns past its budget (docs/planner.md, \"Limits and failures\")"))
    solve_function: str = Field(default="planner.service:plan",
                                description="module:function that plans a scene")
    api_key: str | None = Field(default=None, description="required X-API-Key when set")
    max_body_bytes: int = Field(default=1_000_000, ge=1024, description="request body limit")
    max_links: int = Field(default=MAX_LINKS, ge=1, le=MAX_LINKS)
    max_nodes: int = Field(default=2000, ge=2, description="collocation nodes of one plan")
    max_horizon: float = Field(default=60.0, gt=0.0, description="longest plan duration [s]")
    max_wall_time: float = Field(default=60.0, gt=0.0, description="cap on one solve [s]")
    max_queued: int = Field(default=32, ge=0, description="plans waiting for a worker")
    retention_days: float = Field(default=30.0, gt=0.0, description=(
        "days a finished job (its plan, its history) is kept after it ended"))
    retention_count: int = Field(default=100_000, ge=1, description=(
        "finished jobs kept at most: older ones beyond this count are deleted"))
    retention_mb: float = Field(default=1024.0, gt=0.0, description=(
        "what the store may hold of finished jobs (their scenes, progress, compressed plans "
        "and NLP solutions) [MB]: the oldest beyond are deleted"))
    integrity_interval: float = Field(default=300.0, ge=1.0, description=(
        "seconds between two full integrity checks (PRAGMA integrity_check) of the SQLite "
        "store by each server and worker node; a quick check runs besides whenever the file "
        "changed since the last one passed, before a job is accepted"))
    max_batch_members: int = Field(default=200, ge=1, le=1000, description=(
        "plans one batch (POST /v1/batches) may create; a batch may take the server this "
        "many plans beyond UNDERTOW_MAX_QUEUED"))
    max_wait: float = Field(default=30.0, ge=0.0, description="cap on POST /v1/plans?wait= [s]")
    max_points: int = Field(default=20_000, ge=2, description="states, configurations, grid "
                            "points, samples or time steps one request may ask for")
    max_wave_starts: int = Field(default=8, ge=1, description="NLP starts of one wave design")
    max_wave_frequency: int = Field(default=6, ge=1, description="largest frequency_max of one "
                                    "wave design (the screening grows as its power)")
    compute_threads: int = Field(default=4, ge=1, description="concurrent synchronous computations")
    sync_memory_mb: int = Field(default=1024, ge=64, description=(
        "memory the synchronous computations running at once may take together, by their "
        "up-front estimates [MB]: one estimated above it is refused (422), one that does "
        "not fit beside those running waits up to UNDERTOW_COMPUTE_WAIT, then 503"))
    quick_threads: int = Field(default=1, ge=1, description="threads kept for quick requests: "
                               "dynamics or coupling at no more than quick_points points")
    quick_points: int = Field(default=64, ge=0, description="points (states, configurations, "
                              "grid points) of a quick request")
    compute_wait: float = Field(default=5.0, ge=0.0, description="longest wait for a compute "
                                "thread [s]; then 503 with Retry-After")
    sync_wall_time: float = Field(default=20.0, gt=0.0, description="wall-time budget of one "
                                  "synchronous computation, its wait for a thread included [s]")
    max_sessions: int = Field(default=4, ge=0, le=256, description=(
        "replanning sessions a server keeps at once (0: none); one more is a 503 until one "
        "closes or expires"))
    session_idle: float = Field(default=60.0, gt=0.0, le=86400.0, description=(
        "seconds a replanning session is kept without a request; then it is freed"))
    max_wave_screening: int = Field(default=500_000, ge=1, description="configurations the "
                                    "screening of one wave design may evaluate")
    read_timeout: float = Field(default=10.0, gt=0.0, description="time a client has to send "
                                "a request's head, and again its body [s]")
    retry_after: int = Field(default=5, ge=1, description="Retry-After [s] when the queue is full")
    log_level: str = Field(default="INFO")


    def retention(self) -> Retention:
        """How long finished jobs are kept (UNDERTOW_RETENTION_DAYS, _COUNT, _MB)."""
        return Retention(86400.0 * self.retention_days, self.retention_count,
                         int(self.retention_mb * MB))

    def plan_processes(self) -> int:
        """Processes one plan may use (UNDERTOW_SOLVER_PROCESSES, else the machine's
        cores: a plan forks its companion only onto a core that no other plan holds)."""
        if self.solver_processes is not None:
            return self.solver_processes
        return max(1, len(os.sched_getaffinity(0)))

    @field_validator("db_url")
    @classmethod
    def _postgres_url(cls, url: str | None) -> str | None:
        if url is not None and not url.startswith(("postgresql://", "postgres://")):
            raise ValueError("expected postgresql://user:password@host:port/database")
        return url or None


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The settings of this process (read once from the environment). A set
    UNDERTOW_QUEUE stops the start (ValueError) instead of being ignored: a deployment
    that chose the removed own queue learns that procrastinate now queues its jobs."""
    if any(name.upper() == REMOVED_QUEUE for name in os.environ):
        raise ValueError(
            f"{REMOVED_QUEUE} is set but no longer read: a PostgreSQL store's jobs are always "
            "queued by procrastinate, since undertow's own PostgreSQL queue was removed "
            "(docs/deploy.md, \"Queue engine\"); unset it")
    return Settings()
