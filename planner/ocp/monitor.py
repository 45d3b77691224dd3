"""Ipopt's iteration callback: reports progress, keeps the last iterate, stops on request
or on the plan's limits."""

from __future__ import annotations

import time
from collections.abc import Callable

import casadi as ca
import numpy as np

from planner.budget import IterationCallback
from planner.ocp.result import Progress

Handler = Callable[[Progress], bool]


def reports(handler: Handler | None) -> bool:
    """Whether a handler passes its reports on to anyone: not when there is none, nor when
    its `reports` attribute says it only watches (its reports then carry no dual
    infeasibility, which costs a read of the solver's whole statistics per iteration)."""
    return handler is not None and getattr(handler, "reports", True)


STALL_WINDOW = 100
"""Iterations over which a solve that may stall must make progress towards feasibility."""
STALL_FLOOR = 1e-3
"""Constraint violation below which a solve is never stopped as stalled."""


class IterationMonitor(IterationCallback):
    """Called by Ipopt once per iteration (iteration 0 is the starting point).

    Iterations are numbered across the solves of one plan: a solve starts at `first`, the
    plan's iterations so far. The monitor stops the solve (Ipopt's User_Requested_Stop)
    when the handler returns False, when the solve has made `max_iter` iterations, when
    the deadline (time.perf_counter() seconds) has passed or, if it may stall, when it
    stalls (`stalled`); `reason` says which.
    """

    def __init__(self, nx: int, ng: int, np_: int):
        self.reset(None, 0, 0, np.inf, np.zeros(ng), np.zeros(ng), None, 0, time.perf_counter())
        super().__init__("iteration_monitor", nx, ng, np_)

    def reset(self, handler: Handler | None, first: int, max_iter: int, deadline: float,
              lbg: np.ndarray, ubg: np.ndarray, solver: ca.Function | None, mesh_pass: int,
              started: float, stall: bool = False) -> None:
        """Prepare for a solve by `solver` (whose statistics give the dual infeasibility);
        stall: the solve may be stopped when it stalls."""
        self.handler, self.first, self.max_iter, self.deadline = handler, first, max_iter, deadline
        self.lbg, self.ubg, self.solver, self.mesh_pass = lbg, ubg, solver, mesh_pass
        self.started, self.calls, self.reason = started, 0, ""
        self.last_x: np.ndarray | None = None
        self.last_f = np.nan
        self.stall = stall
        self.violations: list[float] = []

    @property
    def iteration(self) -> int:
        """The plan's iteration count at the latest call."""
        return self.first + self.calls - 1

    def _dual_infeasibility(self) -> float | None:
        if self.solver is None:
            return None
        values = self.solver.stats().get("iterations", {}).get("inf_du", [])
        return float(values[-1]) if values else None

    def stalled(self) -> bool:
        """Whether the constraint violation, above STALL_FLOOR, has not fallen below half
        its smallest earlier value over the last STALL_WINDOW iterations."""
        v = self.violations
        return len(v) > STALL_WINDOW and v[-1] > STALL_FLOOR \
            and min(v[-STALL_WINDOW:]) > 0.5 * min(v[:-STALL_WINDOW])

    def stop(self, values: dict[str, np.ndarray]) -> bool:
        self.calls += 1
        self.last_x = values["x"].copy()
        self.last_f = float(values["f"][0])
        if self.handler is not None or self.stall:
            g = values.get("g", np.zeros(0))
            violation = np.maximum(self.lbg - g, 0.0) + np.maximum(g - self.ubg, 0.0)
            self.violations.append(float(violation.max(initial=0.0)))
        if self.handler is not None:
            progress = Progress(iteration=self.iteration, objective=self.last_f,
                                inf_pr=self.violations[-1],
                                inf_du=self._dual_infeasibility()
                                if reports(self.handler) else None,
                                elapsed=time.perf_counter() - self.started,
                                mesh_pass=self.mesh_pass)
            if self.handler(progress) is False:
                self.reason = "cancelled"
        if not self.reason and self.calls - 1 >= self.max_iter:
            self.reason = "max_iter"
        elif not self.reason and time.perf_counter() > self.deadline:
            self.reason = "max_wall_time"
        elif not self.reason and self.stall and self.stalled():
            self.reason = "stalled"
        return bool(self.reason)
