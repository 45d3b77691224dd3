"""Ipopt: interior point with MUMPS, the planner's default solver."""

from __future__ import annotations

from typing import Any

from planner.ocp.solvers.solver import Nlp

INERTIA_OPTIONS = {"perturb_dec_fact": 0.5, "perturb_inc_fact": 4.0,
                   "first_hessian_perturbation": 1e-8}
"""How Ipopt would perturb the Hessian when the KKT matrix has the wrong inertia, with the
idle variable (`Ipopt.idle_variable`; docs/benchmarks.md, "Ipopt settings: inertia
corrections", 17 hard-suite tasks): measured, not the planner's setting (docs/planner.md
says why). An iteration first factors with the last perturbation times perturb_dec_fact,
then raises it by perturb_inc_fact until the inertia is right; a solve's first
perturbation is first_hessian_perturbation. Ipopt's 1/3, 8 and 1e-4: 1.52 factorizations
per iteration. 1/2 and 4: fewer iterations that raise it, 1.44. A first perturbation of
1e-8 (1e-4 is large beside these Hessians' curvature, and shortens the first steps of
every solve): 1.53 in 0.89 of the iterations of Ipopt's own inertia correction, 0.68 of
its factorizations, the fewest of any way measured. A decrease of 0.6 makes 1.36 but lets
the perturbation linger: 1.18 times the iterations."""

IPOPT_OPTIONS = {"linear_solver": "mumps", "mumps_pivot_order": 0, "mumps_scaling": 0,
                 "mumps_mem_percent": 200, "mumps_pivtol": 1e-8, "mu_strategy": "adaptive"}
"""Ipopt settings every NLP is built with (docs/benchmarks.md, "Ipopt settings"). MUMPS orders
the KKT matrix by approximate minimum degree (0): on the banded collocation matrices Ipopt's
own work per iteration is lower than with its automatic choice on five of the six reference
scenes. MUMPS scales nothing (0): Ipopt's own work per iteration as low or lower on every
reference scene, the same optimum on all but the horizontal seed arm at N = 50 (another
verified one there). MUMPS's workspace is its own estimate plus 200 %, not Ipopt's plus
1000 %: on the seed arm at N = 100 that larger workspace is above the size up to which the
C heap reuses freed memory, so that each factorization mapped it anew and faulted in its
pages afresh, a fifth of an iteration's CPU time in the kernel
(docs/benchmarks.md, "Cost of an iteration on the seed arm"); Ipopt enlarges a workspace
that MUMPS finds too small and factors again. The adaptive barrier update stays, with its
quality-function oracle: the monotone update and the probing oracle saved iterations on
some scenes but ended in worse optima or the iteration limit on the horizontal seed arm.
MUMPS accepts a pivot down to 1e-8 of its column's largest entry (Ipopt's 1e-6): where the
multipliers of a co-design's coupling margin grow huge, the unscaled KKT matrix has
columns of very different sizes, MUMPS delayed pivot after pivot, its factors outgrew the
workspace again and again, and each enlargement made every later factorization of the
solve map and fault in its pages anew: single iterations of tens of seconds, past the
plan's wall time. Ipopt still raises the tolerance where a
solution is inaccurate (mumps_pivtolmax)."""

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
    idle_variable = False
    """With the idle variable Ipopt finds the Hessian singular (its row and column are
    empty) in its first iterations, concludes that it is structurally so, and from then
    on perturbs it in every iteration, starting from the last perturbation
    (INERTIA_OPTIONS), instead of first factoring it unperturbed: about 1.5 KKT
    factorizations per iteration instead of 2 on hard tasks, but other paths on two-link
    arms that converge slower or not at all, so it is off (docs/planner.md)."""

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
        else:  # nothing differentiates the oracle, whose stages may be compiled kernels
            opts.update({"calc_lam_p": False, "no_nlp_grad": True})
        return opts

    def status(self, stats: dict[str, Any]) -> str:
        return str(stats.get("return_status", "Error"))


IPOPT = Ipopt()
