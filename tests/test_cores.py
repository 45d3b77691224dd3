"""The machine's cores as tokens: a plan forks its companion only onto a core no other plan
holds, and a dead holder never keeps one."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import wait_until

from planner.examples import example
from planner.ocp import cores, portfolio
from planner.ocp.planner import plan
from planner.scene import Scene


@pytest.fixture()
def pool(tmp_path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(cores.DIRECTORY, str(tmp_path))
    return tmp_path


def test_each_core_is_taken_once_and_given_back(pool):
    first, second = cores.take(2), cores.take(2)
    assert first is not None and second is not None and first.index != second.index
    assert cores.take(2) is None  # every core held, even by this same process
    cores.release(first, None)
    again = cores.take(2)
    assert again is not None and again.index == first.index
    cores.release(again, second)


def test_a_holder_that_dies_gives_its_core_back(pool):
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # takes both cores, says so, and is killed holding them
        held = [cores.take(2), cores.take(2)]
        os.write(write, b"1" if all(held) else b"0")
        os.pause()
    assert os.read(read, 1) == b"1"
    assert cores.take(2) is None
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    token = cores.take(2)
    assert token is not None
    cores.release(token)


def _started(flag: Path) -> None:
    """A companion's run: say it has started, then wait to be killed."""
    flag.touch()
    os.pause()


def test_a_forked_child_does_not_keep_its_parents_core(pool):
    """A killed companion still releasing its memory must not hold the plan's cores: the
    next plan takes them at once."""
    token = cores.take(1)
    assert token is not None
    flag = pool / "started"
    companion = portfolio.Companion(lambda guard: _started(flag))  # alive throughout
    try:
        wait_until(flag.exists)  # the companion has run its fork hook
        cores.release(token)
        again = cores.take(1)
        assert again is not None
        cores.release(again)
    finally:
        companion.stop()


def test_a_plan_runs_alone_when_no_core_is_free(pool, monkeypatch):
    monkeypatch.setenv(portfolio.ENVIRONMENT, "2")
    monkeypatch.setattr(cores, "available", lambda: 2)
    held = [cores.take(), cores.take()]
    forks = []
    monkeypatch.setattr(portfolio, "Companion", lambda *a: forks.append(a))
    result = plan(Scene.model_validate(example("two-link-plan").request))  # passive joint
    assert forks == [] and result.verification.verified
    cores.release(*held)
    assert cores.take() is not None  # the plan gave back nothing it did not take
