"""How long a store call waits for a database connection, by who asks.

Background work (solver workers; the supervisor's lease renewals, looks for stalled
claims and purges) waits the store's own timeout and retries (`app.store_retry`), riding
out a database that is away for a while. An HTTP request cannot: a container's health check
gives its command 5 s, and a client or load balancer holding a request for the store's
10 s sees a hung service rather than a 503. So each store call made for a request waits
at most REQUEST_WAIT, the health check at most CHECK_WAIT.

The request's bound is a context variable: `bounded()` sets it for one request (the
app's `app.store_wait.StoreWaitMiddleware`), and it follows the request into the threads
its store calls run in (`run_in_threadpool` runs them in a copy of the request's
context); threads started otherwise (the supervisor's, a worker's) never see it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

REQUEST_WAIT = 3.0
"""[s] the longest one store call made for an HTTP request waits for a connection: while
the database is away the request answers 503 within a container's 5 s health-check
timeout, with time left for the answer itself."""
CHECK_WAIT = 2.0
"""[s] the longest a health check (`/healthz`) waits for a connection (a container's
health check gives its command 5 s)."""

_BOUND: ContextVar[float | None] = ContextVar("undertow_store_wait", default=None)


@contextmanager
def bounded(seconds: float = REQUEST_WAIT) -> Iterator[None]:
    """Store calls in this context (and the threads it is copied to) wait at most
    `seconds` for a connection."""
    token = _BOUND.set(seconds)
    try:
        yield
    finally:
        _BOUND.reset(token)


def connection_wait(default: float) -> float:
    """[s] how long a store call in this context waits for a connection: `default` (the
    store's timeout), at most the bound `bounded` set."""
    bound = _BOUND.get()
    return default if bound is None else min(default, bound)
