"""Schemathesis fuzzes the committed OpenAPI document against a live server.

Checks: all of schemathesis' checks (no 5xx; responses match their documented schema,
status code, content type and headers; invalid data, a missing or wrong API key and
unsupported methods are refused; Allow headers are right; ...) but one:
`positive_data_acceptance`, which expects every schema-valid body to be accepted, while
the service also refuses bodies by rules a JSON schema cannot state (one entry per joint,
one torque row per time) and by the server's limits (docs/api.md, "Fuzzing"). The server
has an API key, which the run sends. Bounded: a few examples per operation, a fixed seed,
tight server limits so that any plan or wave design it manages to submit is small. The
default run leaves out the two
operations that start solver work (plan submission, wave design); the slow run fuzzes
every operation. The documented request examples are posted by tests/test_e2e_server.py
and tests/test_api_compute.py instead.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from service_fixtures import ROOT

from testbed.service import LiveServer

pytest.importorskip("schemathesis", reason="schemathesis is a test dependency")

KEY = "fuzz-key"
LIMITS = {"UNDERTOW_MAX_NODES": "200", "UNDERTOW_MAX_WALL_TIME": "2", "UNDERTOW_WORKERS": "1",
          "UNDERTOW_MAX_QUEUED": "0", "UNDERTOW_MAX_POINTS": "200", "UNDERTOW_MAX_HORIZON": "10",
          "UNDERTOW_MAX_WAIT": "2", "UNDERTOW_MAX_WAVE_STARTS": "2",
          "UNDERTOW_MAX_WAVE_FREQUENCY": "3"}
SOLVER_WORK = ["--exclude-operation-id", "create_plan", "--exclude-operation-id", "wave_design"]


def fuzz(tmp_path, extra: list[str]) -> None:
    with LiveServer(tmp_path / "jobs.sqlite3", UNDERTOW_API_KEY=KEY, **LIMITS) as live:
        run = subprocess.run(
            [sys.executable, "-m", "schemathesis.cli", "run",
             str(ROOT / "openapi" / "openapi.json"), "--url", live.url, "--checks", "all",
             "--exclude-checks", "positive_data_acceptance", "--header", f"X-API-Key: {KEY}",
             "--max-examples", "5", "--seed", "1", "--phases", "coverage,fuzzing,stateful",
             "--workers", "1", "--request-timeout", "60", "--generation-database", "none",
             "--no-color", *extra],
            check=False, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    assert " passed" in run.stdout


def test_fuzzing_finds_no_server_error_and_no_schema_violation(tmp_path):
    fuzz(tmp_path, SOLVER_WORK)


@pytest.mark.slow
def test_fuzzing_every_operation_including_solver_work(tmp_path):
    fuzz(tmp_path, [])
