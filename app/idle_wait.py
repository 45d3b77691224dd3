"""An idle solver worker's wait for work: its supervisor's pipe and the store's
announcements of queued jobs (`JobStore.listen`). On PostgreSQL the worker hears of a
queued job and claims it within milliseconds; on a store that announces nothing, or while
its listening connection is broken, it looks when its supervisor says WAKE or when the
wait's timeout ends (`app.worker.IDLE_POLL`)."""

from __future__ import annotations

import logging
import math
import time
from multiprocessing.connection import Connection, wait

from app.store import JobStore, Listener
from app.worker_pipe import stop_requested

log = logging.getLogger("undertow.worker")

LISTEN_RETRY = 5.0  # [s] between two tries to LISTEN again after the connection broke


class IdleWait:
    """Waits on `channel` (the supervisor's pipe) and on `store`'s announcements (opened
    on first use, reopened `LISTEN_RETRY` s after a failure, polling meanwhile; never on
    a store that announces nothing)."""

    def __init__(self, store: JobStore, channel: Connection):
        self.store, self.channel = store, channel
        self.listener: Listener | None = None
        self.retry_at = 0.0

    def _open(self) -> None:
        if self.listener is not None or time.monotonic() < self.retry_at:
            return
        try:
            self.listener = self.store.listen()
        except Exception as exc:  # noqa: BLE001 - any failure: poll, try again later
            log.warning("LISTEN failed (polling meanwhile): %s", exc)
            self.retry_at = time.monotonic() + LISTEN_RETRY
            return
        if self.listener is None:  # the store announces nothing: poll for good
            self.retry_at = math.inf

    def _drop(self) -> None:
        if self.listener is not None:
            self.listener.close()
        self.listener, self.retry_at = None, time.monotonic() + LISTEN_RETRY

    def stop_requested(self, timeout: float) -> bool:
        """Wait up to `timeout` s for a message or an announcement; True on STOP or when
        the supervisor is gone."""
        self._open()
        if self.listener is None or timeout <= 0.0:
            return stop_requested(self.channel, timeout)
        try:
            announced = self.listener.fileno()
            if announced in wait([self.channel, announced], timeout):
                self.listener.drain()
        except Exception as exc:  # noqa: BLE001 - the listening connection broke
            log.warning("LISTEN connection lost (polling meanwhile): %s", exc)
            self._drop()
        return stop_requested(self.channel, 0.0)

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()
