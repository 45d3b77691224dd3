"""The cost of terms that couple neighbouring stages (`Term.boundary_cost`): the torques
on both sides of every stage boundary, in time order, and the time between them."""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout, torques
from planner.ocp.parameters import Parameters
from planner.ocp.terms import Boundaries, Term

BoundaryCost = Callable[[ca.MX, ca.MX, ca.MX], ca.MX]
"""cost(X, common, local): X the NLP's variables, common (n_common,) and local
(n_local x N + 1) its parameters."""


def boundary_cost(key: ProblemKey, layout: Layout, params: Parameters,
                  terms: list[Term]) -> BoundaryCost | None:
    """The cost of the terms that couple neighbouring stages (None: no term does, or there
    is no boundary with torques on both sides)."""
    coupling = [t for t in terms if type(t).boundary_cost is not Term.boundary_cost]
    stage, _, terminal, _ = torques(layout)
    if not coupling or not stage:
        return None
    N, nw = layout.intervals, layout.stage_size
    before = [k * nw + stage[-1] for k in range(N)]
    after = [(k + 1) * nw + stage[0] for k in range(N - 1)]
    if terminal:
        after.append(N * nw + terminal[0])
    else:
        before.pop()
    if not before:
        return None

    def cost(X: ca.MX, common: ca.MX, local: ca.MX) -> ca.MX:
        T = X[int(layout.first("T")[0])] if key.free_time else common[params.common["T"]]
        b = Boundaries(ca.reshape(X[np.concatenate(before).tolist()], -1, len(before)),
                       ca.reshape(X[np.concatenate(after).tolist()], -1, len(after)),
                       T * local[params.local["boundary"], :len(before)],
                       lambda name: common[params.common[name]])
        costs = (term.boundary_cost(b) for term in coupling)
        return sum((c for c in costs if c is not None), ca.MX(0))

    return cost
