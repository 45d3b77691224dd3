"""An idle solver worker's wait for work: its supervisor's pipe and the store's
announcements of queued jobs (`JobStore.listen`). On PostgreSQL the worker hears of a
queued job and claims it within milliseconds; of a job queued again after a pause (an
infrastructure failure's), it hears at once and looks again when the pause has passed
(`DUE_LOOKS` after it). On a store that announces nothing, or while its listening connection
is broken, it looks when its supervisor says WAKE or when the wait's timeout ends
(`app.worker.IDLE_POLL`)."""

from __future__ import annotations

import logging
import math
import time
from multiprocessing.connection import Connection, wait

from app.store import JobStore, Listener
from app.worker_pipe import stop_requested

log = logging.getLogger("undertow.worker")

LISTEN_RETRY = 5.0  # [s] between two tries to LISTEN again after the connection broke
DUE_LOOKS = (0.005, 0.05)
"""[s] when, after an announced pause has passed, the worker looks for the job: the job's
retry time is written from the clock of the process that queued it again and compared with
the database's when the worker claims, so a second look allows for those clocks differing
by up to 50 ms (the machines' clocks are kept synchronised: docs/deploy.md)."""


class IdleWait:
    """Waits on `channel` (the supervisor's pipe) and on `store`'s announcements (opened
    on first use, reopened `LISTEN_RETRY` s after a failure, polling meanwhile; never on
    a store that announces nothing), and until the end of the announced pauses. Its
    caller looks for a job whenever a wait ends without STOP."""

    def __init__(self, store: JobStore, channel: Connection):
        self.store, self.channel = store, channel
        self.listener: Listener | None = None
        self.retry_at = 0.0
        self.due: list[float] = []  # time.monotonic() when each paused job may be claimed

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

    def _until_due(self, timeout: float) -> float:
        """`timeout`, shortened to the end of the soonest announced pause (0 when one
        ended since the last wait)."""
        now = time.monotonic()
        return max(0.0, min([timeout, *(at - now for at in self.due)]))

    def stop_requested(self, timeout: float) -> bool:
        """Wait up to `timeout` s, and no longer than the soonest announced pause, for a
        message or an announcement; True on STOP or when the supervisor is gone."""
        self._open()
        timeout = self._until_due(timeout)
        if self.listener is None or timeout <= 0.0:
            stop = stop_requested(self.channel, timeout)
        else:
            try:
                announced = self.listener.fileno()
                if announced in wait([self.channel, announced], timeout):
                    now = time.monotonic()
                    self.due += [now + pause + after for pause in self.listener.drain()
                                 if pause > 0.0 for after in DUE_LOOKS]
            except Exception as exc:  # noqa: BLE001 - the listening connection broke
                log.warning("LISTEN connection lost (polling meanwhile): %s", exc)
                self._drop()
            stop = stop_requested(self.channel, 0.0)
        now = time.monotonic()  # the look that follows serves the pauses ended by now
        self.due = [at for at in self.due if at > now]
        return stop

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()
