"""Every test file is marked with the kind its imports show (tests/conftest.py)."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import SERVICE

TESTS = Path(__file__).resolve().parent
SERVICE_MODULES = ("app", "service_fixtures", "testbed.service", "testbed.cluster",
                   "fastapi.testclient")


def reaches_the_service(path: Path) -> bool:
    """Whether a test file imports the service, its test client or a live server."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
            [node.module or ""] if isinstance(node, ast.ImportFrom) else []
        if any(n == m or n.startswith(m + ".") for n in names for m in SERVICE_MODULES):
            return True
    return False


RUN_IN_PROCESSES = frozenset({"test_benches.py"})
"""Files that reach the service only through child processes (the benchmarks start live
servers of their own), so that no import of theirs shows it."""


def test_the_service_files_are_exactly_those_that_reach_the_service():
    files = sorted(TESTS.glob("test_*.py"))
    reaching = {p.name for p in files if reaches_the_service(p)}
    assert reaching | RUN_IN_PROCESSES == set(SERVICE)
