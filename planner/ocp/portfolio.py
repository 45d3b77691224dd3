"""A plan's companion: one start solved in a second process, beside the plan's own starts.

A plan may use `solver_processes()` processes (`UNDERTOW_SOLVER_PROCESSES`; by default 2
where the machine has two cores or more). With two, the process that plans forks a
companion that solves the continuation start (`planner.ocp.continuation`) while it goes
through its own starts; the first verified plan wins and the other process stops. The
companion is forked, so it needs no start-up and shares the NLPs already built; it stops
by itself when the process that forked it is gone (on Linux the kernel kills it then),
is paused while the plan's own checks run, and is killed when the plan ends (and reaped
by a thread, so that the plan does not wait for its memory to be released).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import pickle
import select
import signal
import threading
import time
from collections.abc import Callable

from planner.ocp.monitor import Handler, reports
from planner.ocp.result import Plan, Progress

ENVIRONMENT = "UNDERTOW_SOLVER_PROCESSES"
LOWEST = 19
"""The niceness of a deferred companion (`Companion.defer`) once its pause is over, or
where it cannot be paused."""
PAUSE = 0.5
"""[s] The longest a deferred companion is paused. A plan's checks take tens of
milliseconds; where they take longer (a hard plan, whose own checks may yet fail and leave
the companion's plan to be taken), the companion goes on beside them at the lowest
priority."""


def solver_processes() -> int:
    """Processes one plan may use: `UNDERTOW_SOLVER_PROCESSES`, else min(2, cores)."""
    value = os.environ.get(ENVIRONMENT, "").strip()
    if value:
        return max(1, int(value))
    return min(2, os.cpu_count() or 1)


def orphan_guard() -> Handler:
    """A progress handler for the companion: it stops the solve once the process that
    forked it is gone (and reports nowhere: the plan's own process reports)."""
    parent = os.getppid()

    def handler(_: Progress) -> bool:
        return os.getppid() == parent

    return handler


def _prctl() -> Callable[..., int] | None:
    """Linux's prctl(2), None where the C library has none."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_PRCTL = _prctl()
PAUSABLE = _PRCTL is not None
"""Whether a companion can be paused (`Companion.defer`): only where it dies with the
process that forked it (prctl's PR_SET_PDEATHSIG), so that a paused one never outlives
a plan's process killed meanwhile."""
_PR_SET_PDEATHSIG = 1


def _die_with(parent: int) -> None:
    """Have the kernel kill this process once the thread that forked it ends; exit at
    once where it cannot, or where `parent` is gone already."""
    if _PRCTL is None or _PRCTL(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0 \
            or os.getppid() != parent:
        os._exit(1)


class Companion:
    """A forked process running `run` (which returns a Plan); its plan comes back through
    a pipe."""

    def __init__(self, run: Callable[[Handler], Plan]):
        read, write = os.pipe()
        armed, arming = os.pipe()  # a byte once it dies with this process
        parent = os.getpid()
        pid = os.fork()
        if pid == 0:  # the companion
            os.close(read)
            os.close(armed)
            if PAUSABLE:
                _die_with(parent)
                os.write(arming, b"!")
            os.close(arming)
            _serve(run, write)
        os.close(write)
        os.close(arming)
        self.pid, self._fd, self._armed = pid, read, armed
        self.plan: Plan | None = None
        self.finished = False
        self.paused = self._dying = False
        self._pause: threading.Timer | None = None

    def ready(self, timeout: float = 0.0) -> bool:
        """Whether its plan has come (waiting up to `timeout` [s] for it); reads it."""
        if not self.finished and select.select([self._fd], [], [], max(timeout, 0.0))[0]:
            self._read()
        return self.finished

    def verified(self) -> bool:
        """Whether its plan has come and is verified."""
        return self.ready() and self.plan is not None and _verified(self.plan)

    def wait(self, deadline: float) -> Plan | None:
        """Its plan, waiting for it until `deadline` (time.perf_counter() seconds); a
        paused companion goes on first."""
        self._go_on()
        self.ready(deadline - time.perf_counter())
        return self.plan

    def defer(self) -> None:
        """Once the plan's own solve has settled, its checks need the cores far more than
        a companion whose plan is then rarely taken: let it run only on time other work
        leaves over (the lowest priority, nice 19) and, where it is `PAUSABLE`, pause it
        (SIGSTOP) for at most PAUSE seconds or until `wait`, so that the checks have both
        cores."""
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.setpriority(os.PRIO_PROCESS, self.pid, LOWEST)
        if PAUSABLE and not self.paused and self._dies_with_us():
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGSTOP)
                self.paused = True
                self._pause = threading.Timer(PAUSE, self._go_on)
                self._pause.daemon = True
                self._pause.start()

    def _go_on(self) -> None:
        """End the companion's pause (SIGCONT), if it is paused."""
        if self.paused:
            self.paused = False
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGCONT)

    def _dies_with_us(self) -> bool:
        """Whether the companion has said that it dies with this process (it does so at
        once after the fork; not waited for)."""
        if not self._dying and select.select([self._armed], [], [], 0.0)[0]:
            self._dying = os.read(self._armed, 1) == b"!"
        return self._dying

    def stop(self) -> None:
        """End the companion (if still running) and release its pipe. A deferred companion
        gets its priority back first where the process may raise it: a killed process
        still needs the core to release its memory, which at the lowest priority on a
        busy machine would take long. That release is not waited for: a thread of its
        own reaps the companion."""
        if self._pause is not None:
            self._pause.cancel()
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.setpriority(os.PRIO_PROCESS, self.pid, os.getpriority(os.PRIO_PROCESS, 0))
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)
        threading.Thread(target=_reap, args=(self.pid,), name=f"reap-{self.pid}",
                         daemon=True).start()
        for fd in (self._fd, self._armed):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _read(self) -> None:
        chunks = []
        while chunk := os.read(self._fd, 1 << 20):
            chunks.append(chunk)
        self.finished = True
        with contextlib.suppress(pickle.UnpicklingError, EOFError, ValueError):
            self.plan = pickle.loads(b"".join(chunks))


def _reap(pid: int) -> None:
    """Wait for the child `pid` to end, so that it leaves no zombie."""
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)


def _verified(plan: Plan) -> bool:
    return bool(plan.solver.success and plan.verification.verified)


def _serve(run: Callable[[Handler], Plan], fd: int) -> None:
    """The companion's life: plan, send the plan (nothing when planning raised), exit."""
    code, data = 0, b""
    try:
        data = pickle.dumps(run(orphan_guard()))
    except Exception:  # noqa: BLE001 - whatever failed, the plan's own process goes on
        code = 1
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
    finally:
        os._exit(code)


class Watch:
    """The plan's own progress handler beside a companion: it passes reports on, and also
    stops the solve once the companion has a verified plan; `cancelled`: the caller's
    handler stopped it."""

    def __init__(self, companion: Companion, progress: Handler | None):
        self.companion, self.progress, self.cancelled = companion, progress, False

    @property
    def reports(self) -> bool:
        """Whether its reports reach anyone (`planner.ocp.monitor.reports`)."""
        return reports(self.progress)

    def __call__(self, report: Progress) -> bool:
        if self.progress is not None and self.progress(report) is False:
            self.cancelled = True
            return False
        return not self.companion.verified()


def better(own: Plan, other: Plan) -> bool:
    """Whether `own` is at least as good as `other`: verified, then converged, then the
    smaller largest interval error."""
    def rank(p: Plan) -> tuple[bool, bool, float]:
        error = p.verification.local_error
        return (not p.verification.verified, not p.solver.success,
                math.inf if error is None else error)

    return rank(own) <= rank(other)
