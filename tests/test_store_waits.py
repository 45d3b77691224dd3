"""The bound on a request's store waits (`app.store.waits`): it holds in the request's
context and in the threads the request runs its store calls in (`run_in_threadpool`),
never in threads started otherwise (the supervisor's, a worker's), which keep the store's
own timeout to ride out an outage. The bound measured on a stopped database is
tests/test_node_faults.py's."""

from __future__ import annotations

import threading

import anyio
from starlette.concurrency import run_in_threadpool

from app.store.waits import CHECK_WAIT, REQUEST_WAIT, bounded, connection_wait

TIMEOUT = 10.0  # [s] a store's own timeout (PostgresJobStore's default)


def test_a_request_waits_at_most_the_bound_and_background_work_its_timeout():
    assert CHECK_WAIT <= REQUEST_WAIT <= 3.0  # within a container's 5 s health check
    assert connection_wait(TIMEOUT) == TIMEOUT
    background: list[float] = []
    with bounded():
        assert connection_wait(TIMEOUT) == REQUEST_WAIT
        assert connection_wait(1.0) == 1.0  # a shorter timeout stays
        thread = threading.Thread(target=lambda: background.append(connection_wait(TIMEOUT)))
        thread.start()
        thread.join()
    assert background == [TIMEOUT]  # a thread started during a request is not bound
    assert connection_wait(TIMEOUT) == TIMEOUT  # after the request


def test_the_bound_follows_a_request_into_its_worker_threads():
    async def request() -> tuple[float, float]:
        with bounded():
            inside = await run_in_threadpool(connection_wait, TIMEOUT)
        return inside, await run_in_threadpool(connection_wait, TIMEOUT)

    assert anyio.run(request) == (REQUEST_WAIT, TIMEOUT)
