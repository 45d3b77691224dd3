"""One solve of an NLP instance by its solver (`planner.ocp.solvers`), within the plan's
iteration and wall-time budget."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from planner.ocp.instance import Instance
from planner.ocp.monitor import STALL_WINDOW, Handler
from planner.ocp.solvers import SOLVERS

_STOP_STATUS = {"cancelled": "User_Requested_Stop", "max_iter": "Maximum_Iterations_Exceeded",
                "max_wall_time": "Maximum_WallTime_Exceeded", "stalled": "Stalled"}
"""Why the iteration monitor stopped a solve, as a status."""
BUSY = ("the wall-time limit was reached while another solve of the same problem held its "
        "solver in this process")
"""The message of a solve that could not have its problem's solver in time."""
_MESSAGES = {"User_Requested_Stop": "the solve was cancelled",
             "Maximum_Iterations_Exceeded": "the iteration limit was reached",
             "Maximum_WallTime_Exceeded": "the wall-time limit was reached",
             "Infeasible_Problem_Detected": "the task is infeasible (constraints cannot all hold)",
             "Local_Infeasibility": "the solve converged to a point of locally least "
                                    "constraint violation (constraints cannot all hold)",
             "Restoration_Failed": "the restoration phase failed to reduce the constraint "
                                   "violation",
             "Stalled": f"the solve stalled: no progress towards feasibility over "
                        f"{STALL_WINDOW} iterations"}


INFEASIBLE = frozenset({"Infeasible_Problem_Detected", "Local_Infeasibility",
                        "Restoration_Failed"})
"""Statuses by which a solve says that its constraints cannot all hold (from where it went)."""


CHECKS_TIME = 0.2
"""[s] The fixed part of what a plan's checks after its last solve cost (`checks_time`)."""
CHECKS_PER_NODE = 1e-3
"""[s] Their cost per interval and joint: the interval errors, the open-loop replay and
`verify` with its feedback took 0.36 to 1.2 ms per interval and joint on 2 to 6 links with
50 to 400 intervals; this bounds them with room for a far-from-converged iterate."""
CHECKS_FACTOR = 6.0
"""The final checks cost up to this times what the latest solve's own checks took (its
plan's interval errors and, with a coupling margin, their proof, `Budget.measured`): they
integrate the plan's whole horizon three more times (the open-loop replay and the two
closed-loop ones of `verify`), linearise it and sample it densely."""
RESERVE_SHARE = 0.25
"""The most of a plan's wall time kept for its checks: a short budget still solves."""
MARGIN = 5.0
"""[s] A plan returns within solver.max_wall_time plus this (docs/planner.md, "Limits and
failures"): the checks' cost beyond their reserve, one Ipopt iteration, an NLP build."""


@dataclass(frozen=True)
class Clock:
    """A moment of the plan: time.perf_counter() and time.process_time() [s]."""

    wall: float
    cpu: float

    @classmethod
    def now(cls) -> Clock:
        return cls(time.perf_counter(), time.process_time())


def checks_time(intervals: int, joints: int) -> float:
    """[s] What the checks after the last solve of a plan on `intervals` intervals of an
    arm of `joints` joints are expected to cost at most (CHECKS_TIME, CHECKS_PER_NODE)."""
    return CHECKS_TIME + CHECKS_PER_NODE * intervals * joints


@dataclass
class Budget:
    """What a plan may spend: `max_iter` Ipopt iterations per solve, wall time up to
    `deadline` (time.perf_counter() seconds) in all; `used` counts its iterations so far.
    The solves stop `reserve` seconds before the deadline, so that the checks of the last
    one (interval errors, replays, `verify`) end by it (`keep_for_checks`)."""

    started: float
    deadline: float
    max_iter: int
    used: int = 0
    reserve: float = 0.0
    measured: float = 0.0
    """[s] What the interval errors (and margin proof) of the latest solve's plan took."""
    cap: float = math.inf
    """When the solves of a `capped_time` block stop (time.perf_counter() seconds)."""
    solved: Clock | None = None
    """When the latest solve ended (None before the first): the plan's checks follow it."""

    @classmethod
    def of(cls, max_iter: int, max_wall_time: float) -> Budget:
        now = time.perf_counter()
        return cls(now, now + max_wall_time, max_iter)

    @property
    def solves_until(self) -> float:
        """When the solves stop (time.perf_counter() seconds)."""
        return min(self.deadline - self.reserve, self.cap)

    @property
    def spent(self) -> bool:
        """No further solve may start: the time left is kept for the checks."""
        return time.perf_counter() >= self.solves_until

    @contextlib.contextmanager
    def capped(self, max_iter: int) -> Iterator[None]:
        """Within: at most `max_iter` iterations per solve."""
        full = self.max_iter
        self.max_iter = min(full, max_iter)
        try:
            yield
        finally:
            self.max_iter = full

    @contextlib.contextmanager
    def capped_time(self, share: float) -> Iterator[None]:
        """Within: the solves stop `share` of the plan's wall time from now at the latest."""
        outer = self.cap
        self.cap = min(outer, time.perf_counter() + share * (self.deadline - self.started))
        try:
            yield
        finally:
            self.cap = outer

    def keep_for_checks(self, intervals: int, joints: int) -> None:
        """Keep the checks' expected cost before the deadline: on a mesh of `intervals`
        (`checks_time`), or CHECKS_FACTOR times what the latest solve's checks took if
        more; at most RESERVE_SHARE of the plan's wall time."""
        expected = max(checks_time(intervals, joints), CHECKS_FACTOR * self.measured)
        self.reserve = min(expected, RESERVE_SHARE * (self.deadline - self.started))


@dataclass(frozen=True)
class Solution:
    """The returned iterate of one solve (the last one Ipopt reached when it failed) and
    Ipopt's verdict; lam_x, lam_g its multipliers (None when Ipopt gave none)."""

    x: np.ndarray
    lam_x: np.ndarray | None
    lam_g: np.ndarray | None
    objective: float
    status: str
    success: bool
    message: str
    iterations: int
    time: float
    g: np.ndarray | None = None
    """The constraint rows at x (None where the solver gave none)."""


def message(status: str, success: bool) -> str:
    """A sentence for Ipopt's return status."""
    if success:
        return "optimal solution found"
    return _MESSAGES.get(status, f"the solver stopped: {status}")


def solve(inst: Instance, x0: np.ndarray, budget: Budget, handler: Handler | None,
          mesh_pass: int, multipliers: tuple[np.ndarray, np.ndarray] | None = None,
          stall: bool = False) -> Solution:
    """Solve from x0 (with multipliers (lam_x, lam_g): the warm-start solver); adds its
    iterations to `budget.used`; stall: stop it (status "Stalled") when it stalls
    (`planner.ocp.monitor`). Never raises for a solver failure. The problem's solvers
    serve one thread at a time (`Problem.lock`): a solve whose problem another thread
    holds (two replanning sessions of one structure in a server) waits for it, and one
    that cannot have it before its solves must end (`budget.solves_until`) ends
    Maximum_WallTime_Exceeded without iterating."""
    prob = inst.problem
    started = time.perf_counter()
    wait = min(max(budget.solves_until - started, 0.0), threading.TIMEOUT_MAX)
    if not prob.lock.acquire(timeout=wait):
        budget.solved = Clock.now()
        return Solution(np.asarray(x0, float), None, None, math.nan,
                        "Maximum_WallTime_Exceeded", False, BUSY, 0,
                        time.perf_counter() - started)
    try:
        return _solve_held(inst, x0, budget, handler, mesh_pass, multipliers, stall)
    finally:
        prob.lock.release()


def _solve_held(inst: Instance, x0: np.ndarray, budget: Budget, handler: Handler | None,
                mesh_pass: int, multipliers: tuple[np.ndarray, np.ndarray] | None,
                stall: bool) -> Solution:
    """`solve`, with the problem's lock held."""
    prob = inst.problem
    solver = prob.solver if multipliers is None else prob.warm_solver()
    monitor = prob.monitor
    budget.keep_for_checks(inst.mesh.intervals, prob.key.structure.n)
    monitor.reset(handler, budget.used, budget.max_iter, budget.solves_until, prob.lbg, prob.ubg,
                  solver if handler is not None else None, mesh_pass, budget.started, stall)
    args = {"x0": x0, "lbx": inst.lbx, "ubx": inst.ubx, "lbg": prob.lbg, "ubg": prob.ubg,
            "p": inst.P}
    if multipliers is not None:
        args["lam_x0"], args["lam_g0"] = multipliers
    started = time.perf_counter()
    try:
        out = solver(**args)
    except RuntimeError as exc:  # an evaluation error: the last iterate Ipopt reached
        out, error = None, str(exc).strip().splitlines()[-1]
    elapsed = time.perf_counter() - started
    budget.solved = Clock.now()
    kind = SOLVERS[prob.key.solver]
    monitored = kind.monitored  # else its statistics count its iterations
    stats = solver.stats() if out is not None or not monitored else {}
    iterations = max(monitor.calls - 1, 0) if monitored else int(stats.get("iter_count", 0))
    budget.used += iterations
    if out is None:
        x = monitor.last_x if monitor.last_x is not None else np.asarray(x0, float)
        return Solution(x, None, None, monitor.last_f, "Error", False, error, iterations,
                        elapsed)
    status = _STOP_STATUS.get(monitor.reason) or kind.status(stats)
    success = bool(stats.get("success", False)) and not monitor.reason
    objective = float(out["f"])
    return Solution(np.array(out["x"]).ravel(), np.array(out["lam_x"]).ravel(),
                    np.array(out["lam_g"]).ravel(),
                    objective if math.isfinite(objective) else math.nan, status, success,
                    message(status, success), iterations, elapsed,
                    np.array(out["g"]).ravel())
