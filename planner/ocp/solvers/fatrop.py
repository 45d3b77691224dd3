"""fatrop: interior point that factors the KKT system stage by stage.

It needs stages that close their gaps explicitly (scenes check this: `planner.scene`),
differentiates the expanded NLP itself, and calls no iteration callback: its iteration
limit is fixed when it is built (`ProblemKey.max_iter`), and a solve reports no progress
and cannot be cancelled.
"""

from __future__ import annotations

from typing import Any

from planner.ocp.solvers.solver import Nlp

_STATUS = {"SOLVER_RET_SUCCESS": "Solve_Succeeded",
           "SOLVER_RET_LIMITED": "Maximum_Iterations_Exceeded",
           "SOLVER_RET_NAN": "Invalid_Number_Detected",
           "SOLVER_RET_INFEASIBLE": "Infeasible_Problem_Detected"}
"""fatrop's unified return statuses, named as Ipopt names the same outcome."""


class Fatrop:
    """fatrop with the NLP's stage structure declared."""

    name = "fatrop"
    monitored = False
    warm_options: dict[str, Any] | None = None
    idle_variable = False

    def options(self, nlp: Nlp) -> dict[str, Any]:
        """The stage structure (per stage: the node state, the other stage variables, the
        rows beyond the gap-closing ones), which rows are equalities, and the iteration
        limit and tolerance."""
        N = nlp.layout.intervals
        nx, nu = nlp.link, nlp.layout.stage_size - nlp.link
        return {"print_time": False, "expand": True, "structure_detection": "manual", "N": N,
                "nx": [nx] * (N + 1), "nu": [nu] * N + [0],
                "ng": [nlp.stage_rows - nx] * N + [nlp.lbg.size - N * nlp.stage_rows],
                "equality": [bool(e) for e in nlp.lbg == nlp.ubg],
                "fatrop": {"print_level": 0, "tol": nlp.tol, "max_iter": nlp.max_iter}}

    def status(self, stats: dict[str, Any]) -> str:
        unified = str(stats.get("unified_return_status", "unknown"))
        return _STATUS.get(unified, f"fatrop: {unified} (return flag "
                                    f"{stats.get('return_status', '?')})")


FATROP = Fatrop()
