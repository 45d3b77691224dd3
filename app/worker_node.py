"""A stateless worker node (`undertow worker`): solver processes claiming the queued jobs
of every server sharing the job store, on any machine that reaches it, with no HTTP
server of its own.

Its supervisor (`app.supervisor`) is the one an API server runs, claiming anyone's jobs:
it renews its jobs' leases (reading their cancel flags, so a cancel sent to any API server
stops the solve), holds each job to its wall-time budget, and settles jobs of any worker
whose lease ran out. SIGTERM or Ctrl-C stops the node: idle processes leave, running
jobs are released at once (queued again, for another node). A node whose main process is
killed (SIGKILL, the OOM killer) has its solver processes requeue their jobs themselves
within a quarter of a second; a node killed whole (or its machine lost) leaves its jobs'
leases to run out, and whoever sees that first requeues them (infrastructure failures,
retried up to UNDERTOW_MAX_RETRIES times). A node refuses to start on a store it cannot
open (damaged, unreachable, or of a schema newer than it knows): one log line saying why,
and exit status REFUSED.
"""

from __future__ import annotations

import logging
import os
import signal
import threading

from prometheus_client import CollectorRegistry, Gauge, Histogram, start_http_server

from app.logging import configure
from app.metrics import _SOLVE_BUCKETS
from app.settings import PLAN_PROCESSES, Settings
from app.store import StoreUnavailable
from app.store.open import open_store
from app.supervisor import Supervisor
from app.worker import load_function
from app.worker_pipe import JobEnd

log = logging.getLogger("undertow.worker_node")

HEALTH_INTERVAL = 5.0  # [s] between two looks at the node's own health
REFUSED = 3
"""The exit status of a start refused for a reason the log's one line states (a store
that is damaged, unreachable or of a newer schema): an API server's (uvicorn's)."""


class NodeMetrics:
    """The node's Prometheus metrics: jobs it ended by status, their solve times, its busy
    and total solver processes, and whether it can run jobs (1) or not (0)."""

    def __init__(self, supervisor: Supervisor, processes: int):
        self.registry = CollectorRegistry()
        self.solves = Histogram("undertow_worker_solve_duration_seconds",
                                "Wall time of the plan solves this node ended, by status",
                                ["status"], buckets=_SOLVE_BUCKETS, registry=self.registry)
        Gauge("undertow_worker_processes", "Solver processes of this node",
              registry=self.registry).set(processes)
        Gauge("undertow_worker_busy_processes", "Solver processes of this node running a job",
              registry=self.registry).set_function(supervisor.busy)
        Gauge("undertow_worker_up", "1 while this node's solver processes and job store can "
              "be used", registry=self.registry).set_function(
            lambda: float(supervisor.problem is None))

    def done(self, end: JobEnd) -> None:
        self.solves.labels(end.status).observe(end.elapsed)


def _done(end: JobEnd) -> None:
    log.info("job %s %s in %.1f s", end.job_id, end.status, end.elapsed)


def run(settings: Settings, processes: int, stop: threading.Event | None = None,
        metrics: tuple[str, int] | None = None) -> int:
    """Run the node until SIGTERM, SIGINT or `stop`, serving Prometheus metrics at
    `metrics` (host, port) when given; the exit code (REFUSED, without a traceback, when
    the store cannot be opened)."""
    configure(settings.log_level)
    try:
        store = open_store(settings)
    except StoreUnavailable as exc:  # its message says what to do
        log.critical("%s", exc)
        return REFUSED
    name = f"{settings.instance}:worker:{os.getpid()}"
    os.environ[PLAN_PROCESSES] = str(settings.plan_processes())
    node_metrics: NodeMetrics | None = None

    def done(end: JobEnd) -> None:
        _done(end)
        if node_metrics is not None:
            node_metrics.done(end)

    supervisor = Supervisor(store, load_function(settings.solve_function), name, processes,
                            settings.worker_memory_mb, settings.wall_time_grace,
                            settings.log_level, on_done=done, lease=settings.lease,
                            any_owner=True, retention=settings.retention(),
                            drain=settings.drain)
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    if metrics is not None:
        node_metrics = NodeMetrics(supervisor, processes)
        start_http_server(metrics[1], metrics[0], registry=node_metrics.registry)
        log.info("worker node %s: metrics at http://%s:%d/metrics", name, *metrics)
    supervisor.start()
    supervisor.wake()
    log.info("worker node %s: %d solver processes on the job store", name, processes)
    reported = None
    while not stop.wait(HEALTH_INTERVAL):
        problem = supervisor.problem
        if problem != reported and problem is not None:
            log.error("worker node %s: %s", name, problem)
        reported = problem
    log.info("worker node %s stopping", name)
    supervisor.stop()
    store.close()
    return 0
