"""Prometheus metrics: requests by route and status, latencies, solve durations, jobs by state,
the memory the synchronous computations hold.

Each app has its own registry. Worker processes report nothing themselves: the parent
observes solve durations when a job ends, and reads jobs by state from the store when
scraped (so the gauge is right across restarts and across instances sharing a store).
"""

from __future__ import annotations

import time

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.store import JobStore
from app.sync_memory import MemoryBudget
from app.worker_pipe import JobEnd

_LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)
_SOLVE_BUCKETS = (0.1, 0.25, 0.5, 1, 2, 5, 10, 20, 30, 60, 120, 300, 600)


class _JobsByState(Collector):
    def __init__(self, store: JobStore):
        self.store = store

    def collect(self):
        family = GaugeMetricFamily("undertow_jobs", "Plan jobs in the store by state",
                                   labels=["state"])
        for state, count in self.store.count_by_status().items():
            family.add_metric([state], count)
        yield family

    def describe(self):
        return []


class Metrics:
    """The metrics of one app."""

    def __init__(self):
        self.registry = CollectorRegistry()
        self.requests = Counter("undertow_http_requests", "HTTP requests",
                                ["method", "route", "status"], registry=self.registry)
        self.latency = Histogram("undertow_http_request_duration_seconds",
                                 "HTTP request latency", ["method", "route"],
                                 buckets=_LATENCY_BUCKETS, registry=self.registry)
        self.solves = Histogram("undertow_solve_duration_seconds",
                                "Wall time of plan solves by final status", ["status"],
                                buckets=_SOLVE_BUCKETS, registry=self.registry)
        self.sync_memory = Gauge("undertow_sync_memory_reserved_megabytes",
                                 "Memory the synchronous computations running now have "
                                 "reserved of UNDERTOW_SYNC_MEMORY_MB", registry=self.registry)
        self._jobs: _JobsByState | None = None

    def watch(self, store: JobStore) -> None:
        """Report the jobs of `store` by state (replacing a store watched before)."""
        if self._jobs is not None:
            self.registry.unregister(self._jobs)
        self._jobs = _JobsByState(store)
        self.registry.register(self._jobs)

    def watch_memory(self, budget: MemoryBudget) -> None:
        """Report what `budget` holds at scrape time."""
        self.sync_memory.set_function(lambda: budget.used)

    def job_done(self, end: JobEnd) -> None:
        """Record a finished job (called in the server process)."""
        self.solves.labels(end.status).observe(end.elapsed)


class MetricsMiddleware:
    """Count requests and time them, labelled by route template (not raw path)."""

    def __init__(self, app: ASGIApp, metrics: Metrics):
        self.app, self.metrics = app, metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start, status = time.perf_counter(), 500

        async def record_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, record_status)
        finally:
            # answered without an API route: the API description and static files by
            # their path (a fixed set), anything refused before routing as unmatched
            route = getattr(scope.get("route"), "path", None) or (
                scope["path"] if status < 400 else "unmatched")
            method = scope["method"]
            self.metrics.requests.labels(method, route, str(status)).inc()
            self.metrics.latency.labels(method, route).observe(time.perf_counter() - start)
