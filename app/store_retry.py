"""Store actions that outlast a store failing for a while (a database restart): retried
with backoff until the store answers again, or until the caller gives up."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import TypeVar

from app.store import StoreUnavailable

log = logging.getLogger("undertow.worker")

STORE_RETRY = 0.05  # [s] first pause before retrying a store that failed; doubled each time
STORE_RETRY_MAX = 2.0  # [s] longest pause between two tries
T = TypeVar("T")


def persist(action: Callable[[], T], what: str, give_up: float = math.inf) -> T:
    """`action()`, retried with backoff while the store is unavailable, for up to
    `give_up` seconds (then its StoreUnavailable is raised)."""
    pause, deadline, warned = STORE_RETRY, time.monotonic() + give_up, False
    while True:
        try:
            return action()
        except StoreUnavailable as exc:
            if time.monotonic() + pause > deadline:
                raise
            if not warned:
                log.warning("%s: the store failed, retrying: %s", what, exc)
                warned = True
            time.sleep(pause)
            pause = min(STORE_RETRY_MAX, 2 * pause)
