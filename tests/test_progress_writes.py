"""A job's progress is written beside its solve (`app.job_run._Reporter`): a store that is
away costs the solver's iterations nothing, refused writes are counted, and the latest
progress is written once the store is back."""

from __future__ import annotations

import threading
import time

import pytest

from app import job_run
from app.job_run import _Reporter
from app.store import StoreUnavailable
from planner.service import Progress

HANG = 0.3
"""[s] how long a progress write blocks before the store that is away refuses it."""


class AwayStore:
    """A store whose progress writes block for HANG seconds and fail while it is away."""

    def __init__(self) -> None:
        self.back = threading.Event()
        self.written: list[dict] = []

    def report_progress(self, job_id: str, progress: dict, worker: str | None = None) -> bool:
        if not self.back.wait(HANG):
            raise StoreUnavailable("the database is away")
        self.written.append(progress)
        return True


def _progress(k: int) -> Progress:
    return Progress(iteration=k, objective=1.0, inf_pr=0.1, inf_du=0.1, elapsed=0.0)


def test_iterations_never_wait_on_a_store_that_is_away():
    store = AwayStore()
    reporter = _Reporter(store, "job", time.monotonic() + 3600, "worker")
    waited, calls = 0.0, 40
    for k in range(calls):  # some 1.2 s of solving: four writes or so refused meanwhile
        started = time.monotonic()
        assert reporter(_progress(k)) is True
        waited += time.monotonic() - started
        time.sleep(0.03)
    assert waited < HANG, f"the iterations waited {waited:.2f} s on the store"
    assert reporter.unwritten >= 1 and store.written == []
    store.back.set()
    reporter.close(wait=5 * HANG)
    assert store.written and store.written[-1]["iteration"] == calls - 1


def test_a_cancel_read_back_stops_the_solve_at_a_later_iteration():
    class Cancelled(AwayStore):
        def report_progress(self, job_id, progress, worker=None) -> bool:
            self.written.append(progress)
            return False  # the job's cancel flag is set

    store = Cancelled()
    reporter = _Reporter(store, "job", time.monotonic() + 3600, "worker")
    answers = []
    for k in range(50):
        answers.append(reporter(_progress(k)))
        if not answers[-1]:
            break
        time.sleep(0.02)
    reporter.close()
    assert answers[0] is True and answers[-1] is False


def test_closing_wakes_a_writer_that_waits_between_writes(monkeypatch: pytest.MonkeyPatch):
    """The verdict follows the solve at once: closing does not wait out the pause between
    two progress writes (an hour here), and the latest progress is still written."""
    monkeypatch.setattr(job_run, "PROGRESS_INTERVAL", 3600.0)
    store = AwayStore()
    store.back.set()
    reporter = _Reporter(store, "job", time.monotonic() + 3600, "worker")
    reporter(_progress(0))
    wait_until_written = time.monotonic() + 30
    while not store.written and time.monotonic() < wait_until_written:
        time.sleep(0.01)
    reporter(_progress(1))  # the writer now pauses before writing it
    time.sleep(0.2)  # (to be in that pause when it closes; it passes either way)
    reporter.close(wait=30)
    assert not reporter._writer.is_alive()
    assert [p["iteration"] for p in store.written] == [0, 1]


def test_progress_that_comes_during_the_last_write_is_written_when_closing():
    class Slow(AwayStore):
        """A store whose first write waits until `release`."""

        def __init__(self) -> None:
            super().__init__()
            self.entered, self.release = threading.Event(), threading.Event()

        def report_progress(self, job_id, progress, worker=None) -> bool:
            self.entered.set()
            assert self.release.wait(30)
            self.written.append(progress)
            return True

    store = Slow()
    reporter = _Reporter(store, "job", time.monotonic() + 3600, "worker")
    reporter(_progress(0))
    assert store.entered.wait(30)  # the writer is writing 0
    reporter(_progress(1))
    closing = threading.Thread(target=reporter.close, kwargs={"wait": 30})
    closing.start()
    assert reporter._closing.wait(30)
    store.release.set()
    closing.join(60)
    assert [p["iteration"] for p in store.written] == [0, 1]
