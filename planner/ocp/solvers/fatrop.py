"""fatrop: interior point that factors the KKT system stage by stage.

It needs stages that close their gaps explicitly (scenes check this: `planner.scene`) and
calls no iteration callback: its iteration limit is fixed when it is built
(`ProblemKey.max_iter`), and a solve reports no progress and cannot be cancelled. Where
the NLP's derivatives are assembled from per-stage kernels (`planner.ocp.assembly`),
fatrop evaluates those, compiled where the stages are; otherwise it differentiates the
expanded NLP itself.
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from planner.ocp.solvers.solver import Nlp

_STATUS = {"SOLVER_RET_SUCCESS": "Solve_Succeeded",
           "SOLVER_RET_LIMITED": "Maximum_Iterations_Exceeded",
           "SOLVER_RET_NAN": "Invalid_Number_Detected",
           "SOLVER_RET_INFEASIBLE": "Infeasible_Problem_Detected"}
"""fatrop's unified return statuses, named as Ipopt names the same outcome."""


def oracle_functions(derivatives: dict[str, ca.Function]) -> dict[str, ca.Function]:
    """The functions CasADi's fatrop interface asks of its NLP, by the names it asks them
    under, from the assembled ones (`Assembly.derivatives`: grad_f, jac_g, hess_lag):
    the objective's gradient, the rows and their Jacobian, the Lagrangian's gradient and
    whole (symmetric) Hessian, and the objective, rows and Lagrangian gradient the solve's
    multipliers are read from. The Lagrangian is lam_f f + lam_g' g; the gradient in the
    parameters is not asked for (calc_lam_p off) and is zero."""
    grad_f, jac_g, hess = derivatives["grad_f"], derivatives["jac_g"], derivatives["hess_lag"]
    x = ca.MX.sym("x", grad_f.sparsity_in(0))
    p = ca.MX.sym("p", grad_f.sparsity_in(1))
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", jac_g.sparsity_out(0))
    f, gradient = grad_f(x, p)
    g, jac = jac_g(x, p)
    lagrangian_gradient = lam_f * gradient + ca.mtimes(jac.T, lam_g)
    return {
        "nlp_grad_f": ca.Function("nlp_grad_f", [x, p], [gradient], ["x", "p"], ["grad_f_x"]),
        "nlp_jac_g": ca.Function("nlp_jac_g", [x, p], [g, jac], ["x", "p"], ["g", "jac_g_x"]),
        "nlp_hess_l": ca.Function(
            "nlp_hess_l", [x, p, lam_f, lam_g],
            [lagrangian_gradient, ca.triu2symm(hess(x, p, lam_f, lam_g))],
            ["x", "p", "lam_f", "lam_g"], ["grad_gamma_x", "hess_gamma_x_x"]),
        "nlp_grad": ca.Function(
            "nlp_grad", [x, p, lam_f, lam_g],
            [f, g, lagrangian_gradient, ca.MX.zeros(p.sparsity())],
            ["x", "p", "lam_f", "lam_g"], ["f", "g", "grad_gamma_x", "grad_gamma_p"]),
    }


class Fatrop:
    """fatrop with the NLP's stage structure declared."""

    name = "fatrop"
    monitored = False
    warm_options: dict[str, Any] | None = None
    idle_variable = False

    def options(self, nlp: Nlp) -> dict[str, Any]:
        """The stage structure (per stage: the node state, the other stage variables, the
        rows beyond the gap-closing ones), which rows are equalities, the iteration limit
        and tolerance, and the assembled derivatives where the NLP has them (CasADi's
        function cache, which the interface reads before it derives a function itself)."""
        N = nlp.layout.intervals
        nx, nu = nlp.link, nlp.layout.stage_size - nlp.link
        opts: dict[str, Any] = {
            "print_time": False, "structure_detection": "manual", "N": N,
            "nx": [nx] * (N + 1), "nu": [nu] * N + [0],
            "ng": [nlp.stage_rows - nx] * N + [nlp.lbg.size - N * nlp.stage_rows],
            "equality": [bool(e) for e in nlp.lbg == nlp.ubg],
            "fatrop": {"print_level": 0, "tol": nlp.tol, "max_iter": nlp.max_iter}}
        if nlp.assembly.structured:
            opts.update({"cache": oracle_functions(nlp.assembly.derivatives),
                         "calc_lam_p": False})
        else:
            opts["expand"] = True
        return opts

    def status(self, stats: dict[str, Any]) -> str:
        unified = str(stats.get("unified_return_status", "unknown"))
        return _STATUS.get(unified, f"fatrop: {unified} (return flag "
                                    f"{stats.get('return_status', '?')})")


FATROP = Fatrop()
