"""The job runner on real worker processes, with a fake solve function (testbed/fake_solvers.py)."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import pytest
from conftest import wait_until

from app import jobs
from app.job_run import out_of_memory
from app.jobs import JobRunner, QueueFull
from app.store import BUILDING, FINAL, RetryPolicy, SqliteJobStore, StoreUnavailable
from app.supervisor import CANCELLED_STOPPED, TICK, died, over_budget
from app.worker_pipe import JobEnd
from testbed.fake_solvers import fake_plan

ROBOT = {"links": [{"length": 0.5, "mass": 1.0, "joint": "passive"},
                   {"length": 0.4, "mass": 0.5, "joint": "active"}]}


def scene(iterations: int = 3, tol: float = 1e-8, duration: float = 1.0,
          wall_time: float = 60.0) -> dict:
    """A scene the fake solver runs for `iterations` x 20 ms; `tol` picks the outcome
    (testbed/fake_solvers.py), `duration` is a fake build's time."""
    return {"robot": ROBOT,
            "solver": {"max_iter": iterations, "tol": tol, "max_wall_time": wall_time},
            "task": {"duration": duration, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                     "final": {"q": [1.0, None], "dq": [0.0, 0.0]}}}


def wait_final(store, job_id: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        record = store.get(job_id)
        if record.status in FINAL:
            return record
        time.sleep(0.02)
    raise AssertionError(f"job {job_id} still {store.get(job_id).status}")


def unfinished(store) -> int:
    counts = store.count_by_status()
    return counts["queued"] + counts["running"]


def solving(store, job_id: str) -> bool:
    """Whether the job's solver has reported an iteration."""
    progress = store.get(job_id).progress
    return progress is not None and progress["phase"] == "solving"


@pytest.fixture(scope="module")
def runner(tmp_path_factory):
    store = SqliteJobStore(tmp_path_factory.mktemp("jobs") / "db.sqlite3",
                           policy=RetryPolicy(max_retries=1, backoff=0.1))
    done: list[JobEnd] = []
    r = JobRunner(store, fake_plan, owner="test", workers=2, max_queued=2, on_done=done.append)
    r.start()
    r.done = done
    yield r
    r.shutdown()


@pytest.fixture
def make_runner(tmp_path):
    """`make_runner(**options)`: a started runner of its own (shut down after the test)."""
    made = []

    def make(store=None, **options) -> JobRunner:
        store = store or SqliteJobStore(tmp_path / "db.sqlite3")
        made.append(JobRunner(store, fake_plan, **{"owner": "test", "workers": 1,
                                                   "max_queued": 4, **options}))
        made[-1].start()
        return made[-1]

    yield make
    for r in made:
        r.shutdown()


def test_a_job_succeeds_with_its_plan_progress_and_metrics_hook(runner):
    runner.submit(scene(iterations=15), "ok")
    record = wait_final(runner.store, "ok")
    assert record.status == "succeeded" and record.error is None
    assert record.plan["solver"]["status"] == "Solve_Succeeded"
    assert record.progress["iteration"] == 14  # the last iteration is always written
    assert record.progress["phase"] == "solving"
    assert record.progress["inf_pr"] is None  # NaN from the solver is stored as null
    assert record.worker.startswith("test/")
    wait_until(lambda: any(o.job_id == "ok" for o in runner.done))
    end = next(o for o in runner.done if o.job_id == "ok")
    assert end.status == "succeeded" and 0.3 <= end.elapsed < 10


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
    wait_until(lambda: solving(runner.store, "long"))
    asked = time.monotonic()
    runner.store.request_cancel("long")
    record = wait_final(runner.store, "long", timeout=5)
    assert time.monotonic() - asked < 2
    assert (record.status, record.plan["solver"]["status"]) == ("cancelled",
                                                                  "User_Requested_Stop")
    assert record.plan["solver"]["iterations"] < 200


def test_a_cancel_during_the_build_stops_the_worker(runner):
    runner.submit(scene(tol=0.85, duration=60.0), "building")  # a 60 s build
    wait_until(lambda: runner.store.get("building").status == "running")
    assert runner.store.get("building").progress == BUILDING  # never null once running
    runner.store.request_cancel("building")
    record = wait_final(runner.store, "building", timeout=15)
    assert (record.status, record.error, record.plan) == ("cancelled", CANCELLED_STOPPED, None)
    runner.submit(scene(), "after-cancel")  # the worker was replaced
    assert wait_final(runner.store, "after-cancel").status == "succeeded"


def test_the_budget_counts_the_build_and_stops_the_solver(runner):
    # a 1 s build, then 20 s of iterations: the 1.5 s budget ends during the iterations
    runner.submit(scene(iterations=1000, tol=0.85, duration=1.0, wall_time=1.5), "budget")
    record = wait_final(runner.store, "budget", timeout=15)
    assert (record.status, record.error) == (
        "failed", ("Maximum_WallTime_Exceeded: the job's wall-time budget of 1.5 s "
                   "(solver.max_wall_time, NLP build included) ran out"))
    assert record.plan["solver"]["status"] == "User_Requested_Stop"
    assert record.plan["solver"]["iterations"] < 100


def fill(runner: JobRunner, prefix: str, iterations: int) -> list[str]:
    """Submit as many jobs as the runner holds; one more is refused and not stored."""
    # earlier tests' jobs must have ended: the capacity counts the store's unfinished jobs
    wait_until(lambda: unfinished(runner.store) == 0)
    ids = [f"{prefix}{k}" for k in range(runner.capacity)]
    for job_id in ids:
        runner.submit(scene(iterations=iterations), job_id)
    with pytest.raises(QueueFull):
        runner.submit(scene(), f"{prefix}-refused")
    assert runner.store.get(f"{prefix}-refused") is None
    return ids


def test_the_queue_refuses_jobs_beyond_capacity(runner):
    ids = fill(runner, "cap", iterations=25)
    assert {wait_final(runner.store, j).status for j in ids} == {"succeeded"}


def test_cancelled_queued_jobs_free_their_places(runner):
    ids = fill(runner, "place", iterations=1000)
    wait_until(lambda: runner.store.count_by_status()["running"] == 2)  # both workers busy
    queued = [j for j in ids if runner.store.get(j).status == "queued"]
    assert len(queued) >= 2
    for job_id in queued:
        assert runner.store.request_cancel(job_id).status == "cancelled"
    runner.submit(scene(), "taken")  # a cancelled job no longer holds a place
    for job_id in ids:
        runner.store.request_cancel(job_id)
    assert wait_final(runner.store, "taken").status == "succeeded"


def test_wait_returns_when_the_job_ends(runner):
    async def go() -> float:
        runner.submit(scene(iterations=5), "waited")
        start = time.monotonic()
        await runner.wait("waited", timeout=20)
        return time.monotonic() - start

    assert asyncio.run(go()) < 5
    assert runner.store.get("waited").status == "succeeded"


def test_a_job_its_own_worker_ends_wakes_its_waiter_without_the_store_poll(
        runner, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(jobs, "WAIT_POLL", 60.0)  # only the worker's outcome can end it soon

    async def go() -> float:
        runner.submit(scene(iterations=5), "woken")
        start = time.monotonic()
        await runner.wait("woken", timeout=30)
        return time.monotonic() - start

    assert asyncio.run(go()) < 20
    assert runner.store.get("woken").status == "succeeded" and runner._waiters == {}


def test_a_dead_worker_requeues_only_its_job_until_it_is_a_dead_letter(runner):
    runner.submit(scene(iterations=100), "neighbour")  # 2 s on the other worker
    wait_until(lambda: solving(runner.store, "neighbour"))
    runner.submit(scene(tol=0.95), "crash")  # kills every worker that takes it
    crash = wait_final(runner.store, "crash")
    assert (crash.status, crash.dead_letter, crash.infra_failures) == ("failed", True, 2)
    assert crash.error == (f"dead letter: {died(3)}; it failed for infrastructure reasons "
                           "2 times (UNDERTOW_MAX_RETRIES=1)")
    assert died(3) == "the worker process died during the solve (exit status 3; out of memory?)"
    assert [e["event"] for e in crash.history] == ["claimed", "infrastructure-failure"] * 2
    assert wait_final(runner.store, "neighbour").status == "succeeded"
    runner.submit(scene(), "after-crash")
    assert wait_final(runner.store, "after-crash").status == "succeeded"


def test_a_killed_worker_requeues_its_job_with_the_signal_in_its_history(runner):
    runner.submit(scene(iterations=100), "killed")
    wait_until(lambda: solving(runner.store, "killed"))
    worker = next(w for w in runner.supervisor._slots if w is not None and w.job == "killed")
    os.kill(worker.process.pid, signal.SIGKILL)
    record = wait_final(runner.store, "killed")
    assert (record.status, record.infra_failures, record.attempts) == ("succeeded", 1, 2)
    assert record.history[1]["reason"] == ("the worker process died during the solve "
                                           "(killed by signal SIGKILL; out of memory?)")


def test_a_job_past_its_budget_and_grace_has_its_worker_stopped(make_runner):
    runner = make_runner(grace=1.0)
    runner.submit(scene(tol=0.85, duration=60.0, wall_time=1.0), "stuck")  # 60 s "build"
    record = wait_final(runner.store, "stuck", timeout=20)
    assert (record.status, record.error, record.plan) == ("failed", over_budget(1.0, 1.0), None)
    assert record.error == ("the job ran past its wall-time budget of 1 s (solver.max_wall_time, "
                            "NLP build included) plus 1 s grace (UNDERTOW_WALL_TIME_GRACE); "
                            "its worker process was stopped")
    runner.submit(scene(), "next")
    assert wait_final(runner.store, "next").status == "succeeded"


def test_a_worker_over_its_memory_limit_fails_its_job_and_is_replaced(make_runner):
    runner = make_runner(memory_mb=300)
    runner.submit(scene(iterations=200, tol=0.92), "fits")  # 200 MB
    runner.submit(scene(iterations=1000, tol=0.92), "greedy")  # 1000 MB
    runner.submit(scene(), "after")
    assert wait_final(runner.store, "fits").status == "succeeded"
    greedy = wait_final(runner.store, "greedy")
    assert (greedy.status, greedy.error) == ("failed", out_of_memory(300))
    assert greedy.error.startswith("out of memory: the NLP needed more than the 300 MB a "
                                   "solver worker may use (UNDERTOW_WORKER_MEMORY_MB)")
    after = wait_final(runner.store, "after")
    assert after.status == "succeeded" and after.worker != greedy.worker


def test_nothing_of_one_job_leaks_into_the_next(make_runner):
    runner = make_runner()  # one worker: every job runs in the same process
    runner.submit(scene(iterations=1000, tol=0.85, duration=0.2, wall_time=0.5), "expired")
    runner.submit(scene(tol=0.75), "refused")  # no iteration, no progress
    runner.submit(scene(iterations=7), "plain")
    expired, refused, plain = (wait_final(runner.store, j) for j in ("expired", "refused",
                                                                        "plain"))
    assert expired.worker == refused.worker == plain.worker
    assert expired.error.startswith("Maximum_WallTime_Exceeded: the job's wall-time budget")
    assert (refused.status, refused.error) == (
        "failed", "Invalid_Problem_Definition: Invalid_Problem_Definition")
    assert refused.progress == BUILDING
    assert (refused.plan["solver"]["status"], refused.plan["solver"]["iterations"]) == (
        "Invalid_Problem_Definition", 0)
    assert (plain.status, plain.error, plain.progress["iteration"]) == ("succeeded", None, 6)
    assert plain.plan["solver"]["iterations"] == 7


def test_shutdown_keeps_queued_jobs_queued_and_releases_running_ones(make_runner, tmp_path):
    runner = make_runner()
    runner.submit(scene(iterations=1000), "running")
    runner.submit(scene(), "queued-1")
    runner.submit(scene(), "queued-2")
    wait_until(lambda: solving(runner.store, "running"))
    runner.shutdown()
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    running = store.get("running")
    assert (running.status, running.error, running.attempts, running.infra_failures) == (
        "queued", None, 0, 0)  # released: not a failure
    assert running.history[-1]["event"] == "released"
    for job_id in ("queued-1", "queued-2"):
        record = store.get(job_id)
        assert (record.status, record.started, record.worker) == ("queued", None, None)
    make_runner(store)
    assert {wait_final(store, j).status for j in ("queued-1", "queued-2")} == {"succeeded"}
    store.request_cancel("running")


def test_start_requeues_running_jobs_and_runs_queued_ones(tmp_path):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    store.create("was-running", scene(), "test")
    store.claim("test", "test/0/old", time.time() + 60)  # a worker of this server
    store.create("was-queued", scene(), "test")
    store.create("elsewhere", scene(), "other")
    store.claim("other", "other/0/x", time.time() + 60)
    runner = JobRunner(store, fake_plan, owner="test", workers=1, max_queued=1)
    try:
        assert runner.start() == ["was-running"]
        assert wait_final(store, "was-queued").status == "succeeded"
        again = wait_final(store, "was-running")
        assert (again.status, again.infra_failures) == ("succeeded", 1)
        assert store.get("elsewhere").status == "running"
    finally:
        runner.shutdown()


def test_a_deleted_store_is_reported_and_refuses_new_jobs(make_runner):
    runner = make_runner()
    assert runner.problem() is None
    os.unlink(runner.store.path)
    assert "was deleted or replaced while the service ran" in runner.problem()
    with pytest.raises(StoreUnavailable, match="was deleted or replaced"):
        runner.submit(scene(), "lost")


def test_workers_start_with_the_first_job(make_runner):
    runner = make_runner()
    time.sleep(3 * TICK)  # rounds of the supervisor with nothing to do
    assert runner.supervisor._slots == [None]
    runner.submit(scene(), "first")
    assert wait_final(runner.store, "first").status == "succeeded"


def test_one_worker_killed_while_starting_is_replaced_without_alarm(make_runner):
    runner = make_runner()
    runner.submit(scene(), "after")
    wait_until(lambda: runner.supervisor._slots[0] is not None)
    os.kill(runner.supervisor._slots[0].process.pid, signal.SIGKILL)  # before it is ready
    wait_until(lambda: runner.supervisor._failed_starts == 1)
    assert runner.problem() is None  # one lost start is not a broken worker setup
    assert wait_final(runner.store, "after").status == "succeeded"
