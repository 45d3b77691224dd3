"""A solve function whose module cannot be imported in worker processes started while
UNDERTOW_TEST_BREAK_WORKERS is set: workers that fail at start-up."""

from __future__ import annotations

import os

if os.environ.get("UNDERTOW_TEST_BREAK_WORKERS"):
    raise ImportError("this worker was started to fail (UNDERTOW_TEST_BREAK_WORKERS)")


def broken_plan(scene, progress=None):
    """Never runs: no worker gets this far."""
    raise AssertionError("unreachable")
