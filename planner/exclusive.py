"""CasADi solvers shared between threads, called by one thread at a time.

An integrator or an nlpsol keeps the state of a call in the Function object itself: two
threads calling one cached instance at once corrupt it (four simulations of one arm at
once ended the process with a segmentation fault). Plain SX and MX functions are safe
to share and are not wrapped. The planner's own NLPs and re-integrations hold locks of
their own, as one solve or check spans several calls: `Problem.lock`
(`planner.ocp.solve.solve`) and the integrators' locks of `planner.ocp.flow.quiet`.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import casadi as ca

from planner import budget


class Exclusive:
    """A cached integrator or nlpsol behind a lock."""

    def __init__(self, function: ca.Function):
        self.function = function
        self._lock = threading.Lock()

    def __call__(self, deadline: float | None = None, what: str = "the computation",
                 **args: Any) -> tuple[dict[str, ca.DM], dict[str, Any]]:
        """The function's outputs for `args` and the stats of this call. Waits for another
        thread's call at most until `deadline`, and an Ipopt solve stops at it
        (`planner.budget.ipopt_stop`): either way BudgetExceeded("{what} ran past its
        deadline")."""
        wait = -1 if deadline is None else max(deadline - time.monotonic(), 0.0)
        if not self._lock.acquire(timeout=wait):
            raise budget.BudgetExceeded(f"{what} ran past its deadline")
        try:
            with budget.solving(deadline):
                out = self.function(**args)
            stats = self.function.stats()
        finally:
            self._lock.release()
        budget.check(deadline, what)  # a solve stopped at the deadline is no result
        return out, stats

    def size_out(self, name: str) -> tuple[int, int]:
        return self.function.size_out(name)
