"""Schemathesis fuzzes the committed OpenAPI document against a live server.

Checks: no 5xx, every response matches its documented schema, status code and content
type. Bounded: a few examples per operation, a fixed seed, tight server limits so that
any plan it manages to submit is small.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from service_fixtures import ROOT, LiveServer

pytest.importorskip("schemathesis", reason="schemathesis is a test dependency")

CHECKS = ("not_a_server_error,response_schema_conformance,"
          "status_code_conformance,content_type_conformance")


def test_fuzzing_finds_no_server_error_and_no_schema_violation(tmp_path):
    limits = {"UNDERTOW_MAX_NODES": "200", "UNDERTOW_MAX_WALL_TIME": "2",
              "UNDERTOW_MAX_QUEUED": "2", "UNDERTOW_MAX_POINTS": "200",
              "UNDERTOW_MAX_HORIZON": "10", "UNDERTOW_MAX_WAIT": "2"}
    with LiveServer(tmp_path / "jobs.sqlite3", **limits) as live:
        run = subprocess.run(
            [sys.executable, "-m", "schemathesis.cli", "run",
             str(ROOT / "openapi" / "openapi.json"), "--url", live.url, "--checks", CHECKS,
             "--max-examples", "5", "--seed", "1", "--workers", "1", "--request-timeout", "30",
             "--generation-database", "none", "--no-color"],
            check=False, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and "failed" not in run.stdout.split("SUMMARY")[-1]
