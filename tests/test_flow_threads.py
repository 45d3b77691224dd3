"""Re-integrations from several threads at once, as a server's replanning sessions make
them: each answers what it answers alone, a failure keeps its own dump of CasADi's inputs,
and the process's streams are its own afterwards (`planner.ocp.flow.quiet`)."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
from test_diverging import ROBOT, inputs

from planner.captured import captured
from planner.model import Structure
from planner.ocp.flow import flow, lock_of


def _in_threads(work, count: int = 3) -> None:
    threads = [threading.Thread(target=work) for _ in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)


def test_one_interval_flows_in_three_threads_at_once_answer_as_alone():
    """The unmapped integrator (one interval, a replay's fallback) keeps a call's state
    in itself: three threads calling it at once without `quiet`'s lock end the process."""
    f = flow(Structure.of(ROBOT), 0, 4, 1)
    alone = f(*inputs(1, 0.1, 0.2))
    answers: list[np.ndarray] = []

    def integrate() -> None:
        answers.extend(f(*inputs(1, 0.1, 0.2)) for _ in range(100))
    _in_threads(integrate)
    assert len(answers) == 300
    assert all(np.array_equal(a, alone) for a in answers)


def test_flows_diverging_in_three_threads_at_once_keep_their_dumps_and_the_streams(capfd):
    """As a server's replanning sessions re-integrate in threads of their own: each failure
    keeps its own dump, nothing is printed, and sys.stdout and sys.stderr are the
    process's own afterwards."""
    before = sys.stdout, sys.stderr
    f = flow(Structure.of(ROBOT), 0, 4, 3)
    notes: list[list[str]] = []

    def diverge() -> None:
        for _ in range(5):
            try:
                f(*inputs(3, 1e150, 1e200))
            except RuntimeError as exc:
                notes.append([n for e in (exc, exc.__context__) if e is not None
                              for n in getattr(e, "__notes__", [])])
    _in_threads(diverge)
    assert (sys.stdout, sys.stderr) == before
    assert capfd.readouterr() == ("", "")
    assert len(notes) == 15 and all(any("Input 0 (x0)" in n for n in ns) for ns in notes)


def test_a_capture_keeps_its_own_thread_s_output_and_lets_the_others_through(capsys):
    """While one thread captures, another prints as it would without the capture, and the
    streams are the process's own once the capture ends (`planner.captured`)."""
    before = sys.stdout, sys.stderr
    inside, printed = threading.Event(), threading.Event()
    kept: list[str] = []

    def capture() -> None:
        with captured() as (out, err):
            print("from the capturing thread")
            print("and to its stderr", file=sys.stderr)
            inside.set()
            printed.wait(10)
        kept.extend([out.getvalue(), err.getvalue()])

    thread = threading.Thread(target=capture)
    thread.start()
    inside.wait(10)
    print("from another thread meanwhile")
    printed.set()
    thread.join(10)
    assert kept == ["from the capturing thread\n", "and to its stderr\n"]
    assert capsys.readouterr() == ("from another thread meanwhile\n", "")
    assert (sys.stdout, sys.stderr) == before


def test_integrations_of_different_integrators_do_not_wait_for_each_other():
    """One lock per integrator (`lock_of`): a call of one integrator goes on while another
    integrator's lock is held, and the same integrator's waits."""
    s = Structure.of(ROBOT)
    one, other = flow(s, 0, 4, 1), flow(s, 0, 4, 1, tol=1e-8)
    assert lock_of(one.adams) is lock_of(one.adams) is not lock_of(other.adams)
    with lock_of(one.adams):
        done = threading.Event()

        def integrate() -> None:
            other(*inputs(1, 0.1, 0.2))
            done.set()
        threading.Thread(target=integrate).start()
        assert done.wait(30)


def test_a_forked_child_integrates_while_another_thread_of_its_parent_holds_the_integrator():
    """A plan's companion is forked while a server's other threads may be integrating: the
    locks and the capture another thread held at the fork are not held in the child, whose
    streams are the process's own."""
    f = flow(Structure.of(ROBOT), 0, 4, 1)
    held, release = threading.Event(), threading.Event()
    streams = sys.stdout, sys.stderr

    def hold() -> None:
        with lock_of(f.adams), captured():
            held.set()
            release.wait(30)
    thread = threading.Thread(target=hold)
    thread.start()
    held.wait(10)
    try:
        child = os.fork()
        if child == 0:
            code = 1
            try:
                f(*inputs(1, 0.1, 0.2))
                code = 0 if (sys.stdout, sys.stderr) == streams else 2
            finally:
                os._exit(code)
        deadline = time.monotonic() + 30
        while (done := os.waitpid(child, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        if done[0] == 0:
            os.kill(child, signal.SIGKILL)
            os.waitpid(child, 0)
        assert done[0] == child and os.waitstatus_to_exitcode(done[1]) == 0
    finally:
        release.set()
        thread.join(10)
