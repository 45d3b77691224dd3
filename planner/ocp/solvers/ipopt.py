"""Ipopt: interior point with MUMPS, the planner's default solver."""

from __future__ import annotations

from typing import Any

from planner.ocp.solvers.solver import Nlp

IPOPT_OPTIONS = {"linear_solver": "mumps", "mumps_pivot_order": 0, "mumps_scaling": 0,
                 "mu_strategy": "adaptive"}
"""Ipopt settings every NLP is built with (docs/benchmarks.md, "Ipopt settings"). MUMPS orders
the KKT matrix by approximate minimum degree (0): on the banded collocation matrices Ipopt's
own work per iteration is lower than with its automatic choice on five of the six reference
scenes. MUMPS scales nothing (0): Ipopt's own work per iteration as low or lower on every
reference scene, the same optimum on all but the horizontal seed arm at N = 50 (another
verified one there). The adaptive barrier update stays, with its
quality-function oracle: the monotone update and the probing oracle saved iterations on
some scenes but ended in worse optima or the iteration limit on the horizontal seed arm."""

WARM_OPTIONS = {"warm_start_init_point": "yes", "mu_init": 1e-6,
                "warm_start_bound_push": 1e-9, "warm_start_bound_frac": 1e-9,
                "warm_start_slack_bound_push": 1e-9, "warm_start_slack_bound_frac": 1e-9,
                "warm_start_mult_bound_push": 1e-9}
"""Ipopt settings of a solve that starts from an earlier solution's primal and dual values:
a small barrier parameter and no push away from the bounds, so that the solve stays at the
optimum it starts near."""

MAX_ITER = 100000
"""Ipopt's own iteration limit: the iteration monitor stops a solve at the plan's."""


class Ipopt:
    """Ipopt with the assembled derivatives: exact Hessians where the stages are SX,
    limited-memory ones where they call an integrator (MX); nlpsol expands an NLP whose
    derivatives are not assembled."""

    name = "ipopt"
    monitored = True
    warm_options: dict[str, Any] | None = WARM_OPTIONS

    def options(self, nlp: Nlp) -> dict[str, Any]:
        opts: dict[str, Any] = {
            "print_time": False,
            "iteration_callback": nlp.monitor,
            "ipopt": {"print_level": 0, "sb": "yes", "tol": nlp.tol, "max_iter": MAX_ITER,
                      **IPOPT_OPTIONS},
            **nlp.assembly.derivatives,
        }
        if not nlp.expandable:
            opts["ipopt"]["hessian_approximation"] = "limited-memory"
        elif not nlp.assembly.structured:
            opts["expand"] = True
        return opts

    def status(self, stats: dict[str, Any]) -> str:
        return str(stats.get("return_status", "Error"))


IPOPT = Ipopt()
