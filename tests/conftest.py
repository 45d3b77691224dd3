"""Shared test helpers: seeded randomness, the seed paper's 4-link arm, an independent
point-mass reference of M and h (random robots: `testbed.robots`), and job stores of both
kinds (a throwaway PostgreSQL server per test process: `testbed.postgres`).

Plain functions (importable from a test module as `from conftest import ...`) with thin
fixtures around them. Every random draw goes through a `numpy.random.Generator` seeded
from the test's node id, so a failure reproduces whatever the test order or worker.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile
import time
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from app.store import JobStore, SqliteJobStore
from planner.examples import VERTICAL_SEED_ARM
from planner.model import Robot
from testbed import postgres as pg
from testbed.robots import random_robot

# One solver process per plan: the tests run two at a time already (pytest -n 2), and which
# process of a portfolio wins depends on timing; tests/test_portfolio.py sets its own.
os.environ.setdefault("UNDERTOW_SOLVER_PROCESSES", "1")
# No background compilations (solver.jit is on by default): each new structure would start
# a gcc process beside the tests; tests/test_compiled.py and the compiled-check test of
# tests/test_feedback.py turn them back on in a cache folder of their own. An empty cache
# folder: no test loads a library an earlier run left.
os.environ.setdefault("UNDERTOW_BUILDS", "off")
os.environ.setdefault("UNDERTOW_CACHE_DIR", tempfile.mkdtemp(prefix="undertow-kernels-"))
# Core tokens of this test process's own (planner.ocp.cores): the tests that fork a
# companion find a free core whatever else runs on the machine.
os.environ.setdefault("UNDERTOW_CORE_DIR", tempfile.mkdtemp(prefix="undertow-cores-"))


def seed_arm(gravity: float = 9.81, waves: bool = True,
             rotational: str = "cumulative") -> Robot:
    """The seed's 4-link arm, optionally without gravity or without its waves."""
    robot = Robot.model_validate({**VERTICAL_SEED_ARM, "gravity": gravity,
                                  "rotational_inertia": rotational})
    return robot if waves else robot.without_waves()


def point_mass_dynamics(robot: Robot, q, dq) -> tuple[np.ndarray, np.ndarray]:
    """M(q) and h(q, dq) by d'Alembert's principle, independent of the library.

    Tip k moves with dp_k/dt = sum_{i<=k} u_i dq_i, u_i = r_i' e_i + r_i e_i^perp, so
    Q_i = sum_k m_k u_i . a_k gives M_ij = mu_max(i,j) u_i . u_j and
    h_i = sum_j mu_max(i,j) u_i . u_j' dq_j^2 - g mu_i (u_i)_x, with mu_i the mass
    beyond joint i and u_j' = du_j/dq_j. Rotational inertia adds a constant to M.
    """
    q, dq = np.asarray(q, float), np.asarray(dq, float)
    n = robot.n
    r, r1, r2 = np.empty(n), np.empty(n), np.empty(n)
    for i, link in enumerate(robot.links):
        a, f, e = ((link.wave.amplitude, link.wave.frequency, link.wave.phase) if link.wave
                   else (0, 0, 0))
        r[i] = link.length + a * np.sin(f * q[i] + e)
        r1[i] = a * f * np.cos(f * q[i] + e)
        r2[i] = -a * f * f * np.sin(f * q[i] + e)
    e = np.stack([np.cos(q), np.sin(q)], axis=1)
    perp = np.stack([-np.sin(q), np.cos(q)], axis=1)
    u = r1[:, None] * e + r[:, None] * perp
    du = (r2 - r)[:, None] * e + 2 * r1[:, None] * perp
    mu = np.cumsum([link.mass for link in robot.links][::-1])[::-1]
    beyond = mu[np.maximum.outer(np.arange(n), np.arange(n))]
    M = beyond * (u @ u.T) + rotational_mass(robot)
    h = (beyond * (u @ du.T)) @ dq**2 - robot.gravity * mu * u[:, 0]
    return M, h


def rotational_mass(robot: Robot) -> np.ndarray:
    """Constant rotational part of M: sum_{k>=max(i,j)} I_k (cumulative) or diag(I) (absolute)."""
    inertia = np.array([link.inertia for link in robot.links])
    if robot.rotational_inertia == "absolute":
        return np.diag(inertia)
    beyond = np.cumsum(inertia[::-1])[::-1]
    n = robot.n
    return beyond[np.maximum.outer(np.arange(n), np.arange(n))]


def wait_until(predicate: Callable[[], bool], timeout: float = 30.0) -> None:
    """Wait until `predicate()` holds; fail when `timeout` seconds pass first."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.02)


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded from the test's node id (stable across runs and workers)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


@pytest.fixture
def make_robot(rng) -> Callable[..., Robot]:
    """`make_robot(n, **options)`: `random_robot` drawing from the test's generator."""
    return lambda n, **options: random_robot(rng, n, **options)


@pytest.fixture
def seed_robot() -> Robot:
    """The seed's 4-link arm with its waves, under gravity."""
    return seed_arm()


@pytest.fixture(scope="session")
def postgres() -> Iterator[pg.PostgresServer]:
    """A throwaway PostgreSQL server for this test process (skips when none can start)."""
    reason = pg.missing()
    if reason is not None:
        pytest.skip(reason)
    with pg.PostgresServer() as server:
        yield server


@pytest.fixture
def postgres_url(postgres: pg.PostgresServer) -> str:
    """The URL of a new empty database of the throwaway server."""
    return postgres.create_database(pg.unique_name())


ENGINE_LEASE = 0.5
"""[s] The lease of the PostgreSQL stores of the tests: a claim left unrenewed that long
has run out (procrastinate's leases count from the last renewal, not from a time the
claim names)."""


def open_store(kind: str, request: pytest.FixtureRequest, tmp_path) -> JobStore:
    """A new empty store of `kind` ("sqlite": a file under `tmp_path`; "postgres": a new
    database, queued by procrastinate)."""
    if kind == "sqlite":
        return SqliteJobStore(tmp_path / "jobs" / "db.sqlite3")
    from app.store.postgres import PostgresJobStore

    return PostgresJobStore(request.getfixturevalue("postgres_url"), lease=ENGINE_LEASE)


ENGINE_STATUSES = {"queued": ("todo",), "running": ("doing",), "succeeded": ("succeeded",),
                   "failed": ("failed",), "cancelled": ("cancelled", "aborted")}
"""A job's status -> the statuses its engine job may have on PostgreSQL."""


def out_of_step(store: JobStore) -> list[tuple[str, str, str]]:
    """The jobs of a PostgreSQL store whose engine job's status is not one that their own
    status allows (`ENGINE_STATUSES`): (job id, status, engine status); [] elsewhere."""
    from app.store.postgres import PostgresJobStore

    if not isinstance(store, PostgresJobStore):
        return []
    rows = store._rows("SELECT j.id, j.status, q.status::text FROM jobs j JOIN undertow_queue m "
                       "ON m.job_id = j.id JOIN procrastinate_jobs q ON q.id = m.queue_id")
    return [row for row in rows if row[2] not in ENGINE_STATUSES[row[1]]]


@pytest.fixture(params=["sqlite", "postgres"])
def store(request: pytest.FixtureRequest, tmp_path) -> Iterator[JobStore]:
    """An empty job store, once of each kind; on PostgreSQL, each job's engine job is in
    step with it when the test ends (`out_of_step`)."""
    s = open_store(request.param, request, tmp_path)
    yield s
    try:
        assert out_of_step(s) == []
    finally:
        s.close()


# --------------------------------------------------------------------------- kinds of test
#
# Every test is marked with its kind from its file (no test file names its own kind):
# select with -m, e.g. `pytest -m unit` for the library alone, `-m "not database"`.
# The markers are registered in pyproject.toml (`--strict-markers`).

SERVICE = frozenset({
    "test_admission.py", "test_api_budget.py", "test_api_compute.py", "test_api_plans.py",
    "test_api_service.py", "test_api_sessions.py", "test_progress_writes.py",
    "test_api_warm_start.py", "test_bad_input.py", "test_batches.py", "test_benches.py",
    "test_capacity.py", "test_derived_status.py",
    "test_cli.py", "test_continuation.py", "test_delivered_torque.py", "test_distributed.py",
    "test_dockerfile.py", "test_e2e_server.py", "test_engine_nodes.py", "test_errors.py",
    "test_examples.py",
    "test_infeasible.py",
    "test_job_faults.py", "test_jobs.py", "test_json_text.py", "test_limits.py",
    "test_message_versions.py", "test_node_faults.py",
    "test_migrations.py", "test_openapi.py", "test_stored_plan.py", "test_sync_memory.py",
    "test_openapi_client.py", "test_plan_budget.py", "test_plots.py", "test_queue_engine.py",
    "test_readme.py", "test_rolling_upgrade.py",
    "test_sampling.py", "test_scene_validation.py", "test_schemathesis.py", "test_server.py",
    "test_service_interface.py", "test_startup_objects.py", "test_store.py",
    "test_store_drills.py",
    "test_store_integrity.py", "test_store_waits.py", "test_stop_status.py", "test_stress.py",
    "test_sync_deadlines.py", "test_viewer.py"})
"""Files that exercise the service (app/): its app in-process, live servers and worker
processes, the command line, the job store, the API documents, the benchmarks. Any other
file is `unit`: the library alone, in the test's own process."""
DATABASE = frozenset({"test_distributed.py", "test_node_faults.py", "test_queue_engine.py",
                      "test_rolling_upgrade.py"})
"""Files every test of which needs PostgreSQL; elsewhere a test that takes the `postgres`
or `postgres_url` fixture, or the `store` fixture's PostgreSQL case, is marked too, and so
is a test of tests/test_benches.py that runs a benchmark needing it (`bench.smoke`)."""
BROWSER = frozenset({"test_viewer.py"})
"""Files that drive the viewer in a browser."""
CHROMIUM = Path("/usr/bin/chromium")  # tests/test_viewer.py's browser


def kinds(item: pytest.Item) -> set[str]:
    """The kinds (markers) of a collected test, from its file and its fixtures."""
    name = item.path.name
    found = {"service"} if name in SERVICE else {"unit"}
    if name in BROWSER:
        found.add("browser")
    callspec = getattr(item, "callspec", None)
    fixtures = set(getattr(item, "fixturenames", ()))
    if name in DATABASE or fixtures & {"postgres", "postgres_url"} or (
            callspec is not None and callspec.params.get("store") == "postgres"):
        found.add("database")
    if name == "test_benches.py" and callspec is not None and "name" in callspec.params:
        from bench.smoke import SMALL

        if "postgres" in SMALL[callspec.params["name"]].needs:
            found.add("database")
    return found


def browser_missing() -> str | None:
    """Why the viewer tests cannot run here, or None."""
    if not CHROMIUM.exists():
        return (f"browser tests skipped: no browser at {CHROMIUM}; `make browser` installs "
                "Debian's chromium (needs root and apt-get)")
    if importlib.util.find_spec("playwright") is None:
        return "browser tests skipped: the playwright package is not installed"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test with its kinds; skip the browser tests up front, saying why, when
    there is no browser (before their module starts a live server for nothing)."""
    no_browser = browser_missing()
    for item in items:
        for kind in sorted(kinds(item)):
            item.add_marker(getattr(pytest.mark, kind))
        if no_browser is not None and "browser" in kinds(item):
            item.add_marker(pytest.mark.skip(reason=no_browser))


def pytest_report_header(config: pytest.Config) -> list[str]:
    """What this machine cannot run, said before the run rather than only in the summary."""
    reasons = [why for why in (browser_missing(), pg.missing()) if why is not None]
    if pg.missing() is not None:
        reasons[-1] = f"database tests skipped: {reasons[-1]}"
    return reasons or ["every kind of test can run here (unit, service, database, browser)"]
