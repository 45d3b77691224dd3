"""The README's examples run as written: its Python block, and its request within the
server's limits."""

from __future__ import annotations

import re

from service_fixtures import ROOT

from app.settings import Settings

README = (ROOT / "README.md").read_text()


def test_the_python_example_runs():
    (block,) = re.findall(r"```python\n(.*?)```", README, re.DOTALL)
    exec(compile(block, "README.md", "exec"), {})


def test_the_plan_request_waits_no_longer_than_the_server_allows():
    waits = [float(w) for w in re.findall(r"[?&]wait=([\d.]+)", README)]
    assert waits and max(waits) <= Settings().max_wait
