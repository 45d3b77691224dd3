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
retried up to UNDERTOW_MAX_RETRIES times).
"""

from __future__ import annotations

import logging
import os
import signal
import threading

from app.logging import configure
from app.settings import Settings
from app.store.open import open_store
from app.supervisor import Supervisor
from app.worker import Outcome, load_function

log = logging.getLogger("undertow.worker_node")

HEALTH_INTERVAL = 5.0  # [s] between two looks at the node's own health


def _done(outcome: Outcome) -> None:
    log.info("job %s %s in %.1f s", outcome.job_id, outcome.status, outcome.elapsed)


def run(settings: Settings, processes: int, stop: threading.Event | None = None) -> int:
    """Run the node until SIGTERM, SIGINT or `stop`; the exit code."""
    configure(settings.log_level)
    store = open_store(settings)
    name = f"{settings.instance}:worker:{os.getpid()}"
    supervisor = Supervisor(store, load_function(settings.solve_function), name, processes,
                            settings.worker_memory_mb, settings.wall_time_grace,
                            settings.log_level, on_done=_done, lease=settings.lease,
                            any_owner=True)
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
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
