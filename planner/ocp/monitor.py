"""Ipopt's iteration callback: reports progress and stops the solve on request or on limits."""

from __future__ import annotations

import time
from collections.abc import Callable

import casadi as ca
import numpy as np

from planner.ocp.result import Progress

Handler = Callable[[Progress], bool]


class IterationMonitor(ca.Callback):
    """Called by Ipopt once per iteration with the current iterate.

    Stops the solve (Ipopt's User_Requested_Stop) when the handler returns False, when
    the iteration limit is reached or when the wall-time limit [s] has passed; `reason`
    then says which.
    """

    def __init__(self, nx: int, ng: int, np_: int):
        ca.Callback.__init__(self)
        self.sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": np_, "lam_p": np_, "f": 1}
        self.reset(None, 0, np.inf, np.zeros(ng), np.zeros(ng))
        self.construct("iteration_monitor", {})

    def reset(self, handler: Handler | None, max_iter: int, max_wall_time: float,
              lbg: np.ndarray, ubg: np.ndarray) -> None:
        """Prepare for a new solve."""
        self.handler, self.max_iter, self.max_wall_time = handler, max_iter, max_wall_time
        self.lbg, self.ubg = lbg, ubg
        self.iteration, self.started, self.reason = -1, time.perf_counter(), ""
        self.last: Progress | None = None

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.sizes[ca.nlpsol_out(i)], 1)

    def eval(self, args):
        self.iteration += 1
        g = np.asarray(args[ca.nlpsol_out().index("g")]).ravel()
        violation = np.maximum(self.lbg - g, 0.0) + np.maximum(g - self.ubg, 0.0)
        elapsed = time.perf_counter() - self.started
        self.last = Progress(iteration=self.iteration,
                             objective=float(args[ca.nlpsol_out().index("f")]),
                             inf_pr=float(violation.max(initial=0.0)), inf_du=None,
                             elapsed=elapsed)
        if self.handler is not None and self.handler(self.last) is False:
            self.reason = "cancelled"
        elif self.iteration >= self.max_iter:
            self.reason = "max_iter"
        elif elapsed > self.max_wall_time:
            self.reason = "max_wall_time"
        return [1 if self.reason else 0]
