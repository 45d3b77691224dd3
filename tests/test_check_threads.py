"""The process's checking threads (`planner.ocp.check_threads`): kept across a process's
plans, and started anew in a forked child, which a plan's companion is."""

from __future__ import annotations

import os
import threading

from planner.ocp.check_threads import pool


def _checking_threads() -> set[int]:
    return {t.ident for t in threading.enumerate() if t.name.startswith("checks")}


def test_the_threads_are_kept_for_the_next_plan():
    """One pool for the process: later plans' checks run on the threads of the first, and
    start none (planted: a pool per call starts threads for every plan)."""
    pool().submit(int).result(10)
    before = _checking_threads()
    for _ in range(5):
        pool().submit(int).result(10)
    assert before and _checking_threads() == before


def test_a_forked_child_runs_its_checks_on_threads_of_its_own():
    """The parent's threads are not in a forked child: were its pool copied, work submitted
    there would wait for threads that do not exist (planted: the pool kept across the fork
    leaves the child's work waiting)."""
    pool().submit(int).result(10)  # the parent's threads are up
    parents = _checking_threads()
    pid = os.fork()
    if pid == 0:  # the child: run one piece of work, say whether it ran on a thread
        try:
            ran = pool().submit(threading.get_ident).result(10)
            os._exit(0 if ran != threading.get_ident() else 2)
        finally:  # a wait that timed out
            os._exit(1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert pool().submit(threading.get_ident).result(10) in parents  # any of them
