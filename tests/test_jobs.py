"""The job runner on real worker processes, with a fake solve function (tests/fake_solvers)."""

from __future__ import annotations

import asyncio
import time

import pytest
from fake_solvers import fake_plan

from app.jobs import WORKER_DIED, JobRunner, Outcome, QueueFull
from app.store import FINAL, INTERRUPTED, SqliteJobStore

ROBOT = {"links": [{"length": 0.5, "mass": 1.0, "joint": "passive"},
                   {"length": 0.4, "mass": 0.5, "joint": "active"}]}


def scene(iterations: int = 3, tol: float = 1e-8) -> dict:
    """A scene the fake solver runs for `iterations` x 20 ms; `tol` picks the outcome."""
    return {"robot": ROBOT, "solver": {"max_iter": iterations, "tol": tol},
            "task": {"duration": 1.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                     "final": {"q": [1.0, None], "dq": [0.0, 0.0]}}}


def wait_final(store, job_id: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        record = store.get(job_id)
        if record.status in FINAL:
            return record
        time.sleep(0.02)
    raise AssertionError(f"job {job_id} still {store.get(job_id).status}")


def wait_until(predicate, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.02)


@pytest.fixture(scope="module")
def runner(tmp_path_factory):
    store = SqliteJobStore(tmp_path_factory.mktemp("jobs") / "db.sqlite3")
    done: list[Outcome] = []
    r = JobRunner(store, fake_plan, owner="test", workers=2, max_queued=2, on_done=done.append)
    r.done = done
    yield r
    r.shutdown()


def test_a_job_succeeds_with_its_plan_progress_and_metrics_hook(runner):
    runner.submit(scene(iterations=15), "ok")
    record = wait_final(runner.store, "ok")
    assert record.status == "succeeded" and record.error is None
    assert record.plan["solver"]["status"] == "Solve_Succeeded"
    assert record.progress["iteration"] == 14  # the last iteration is always written
    assert record.progress["inf_pr"] is None  # NaN from the solver is stored as null
    wait_until(lambda: any(o.job_id == "ok" for o in runner.done))
    outcome = next(o for o in runner.done if o.job_id == "ok")
    assert outcome.status == "succeeded" and 0.3 <= outcome.elapsed < 10


@pytest.mark.parametrize("tol, error", [
    (0.6, "Maximum_Iterations_Exceeded: Maximum_Iterations_Exceeded"),
    (0.3, "solver error: RuntimeError: the fake solver broke"),
    (0.2, ("unverified: re-integrated interval by interval, the delivered torque departs from "
           "the plan by 0.5 rad (tolerance 0.001 rad): the mesh refinement ran out of budget; "
           "raise transcription.refinement's max_intervals or max_passes, or solver.max_iter "
           "and max_wall_time"))])
def test_solver_failures_fail_the_job_with_the_reason(runner, tol, error):
    job_id = f"fail-{tol}"
    runner.submit(scene(tol=tol), job_id)
    record = wait_final(runner.store, job_id)
    assert (record.status, record.error) == ("failed", error)
    assert (record.plan is None) == (tol == 0.3)  # a returned plan is kept


def test_cancel_stops_a_running_solve_at_its_next_iteration(runner):
    runner.submit(scene(iterations=1000), "long")  # 20 s if not stopped
    wait_until(lambda: runner.store.get("long").progress is not None)
    asked = time.monotonic()
    runner.store.request_cancel("long")
    record = wait_final(runner.store, "long", timeout=5)
    assert time.monotonic() - asked < 2
    assert (record.status, record.plan["solver"]["status"]) == ("cancelled",
                                                                  "User_Requested_Stop")
    assert record.plan["solver"]["iterations"] < 200


def test_the_queue_refuses_jobs_beyond_capacity(runner):
    # earlier tests' jobs leave the queue only after their end is stored
    wait_until(lambda: runner.inflight == 0)
    ids = [f"cap{k}" for k in range(runner.capacity)]
    for job_id in ids:
        runner.submit(scene(iterations=25), job_id)
    with pytest.raises(QueueFull):
        runner.submit(scene(), "one-too-many")
    assert runner.store.get("one-too-many") is None
    assert {wait_final(runner.store, j).status for j in ids} == {"succeeded"}
    wait_until(lambda: runner.inflight == 0)


def test_wait_returns_when_the_job_ends(runner):
    async def go() -> float:
        runner.submit(scene(iterations=5), "waited")
        start = time.monotonic()
        await runner.wait("waited", timeout=20)
        return time.monotonic() - start

    assert asyncio.run(go()) < 5
    assert runner.store.get("waited").status == "succeeded"


def test_a_dead_worker_fails_its_job_and_the_runner_recovers(tmp_path):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    runner = JobRunner(store, fake_plan, owner="test", workers=1, max_queued=4)
    try:
        runner.submit(scene(tol=0.95), "crash")
        runner.submit(scene(), "after")
        crash = wait_final(store, "crash")
        assert (crash.status, crash.error) == ("failed", WORKER_DIED)
        assert wait_final(store, "after").status == "succeeded"
    finally:
        runner.shutdown()


def test_start_interrupts_running_jobs_and_requeues_queued_ones(tmp_path):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    store.create("was-running", scene(), "test")
    store.claim("was-running")
    store.create("was-queued", scene(), "test")
    store.create("elsewhere", scene(), "other")
    store.claim("elsewhere")
    runner = JobRunner(store, fake_plan, owner="test", workers=1, max_queued=1)
    try:
        assert runner.start() == ["was-running"]
        assert store.get("was-running").error == INTERRUPTED
        assert wait_final(store, "was-queued").status == "succeeded"
        assert store.get("elsewhere").status == "running"
    finally:
        runner.shutdown()
