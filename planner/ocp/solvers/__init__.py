"""The NLP's solvers by name (`solver.name` of a scene): one module each, behind `Solver`."""

from planner.ocp.solvers.fatrop import FATROP
from planner.ocp.solvers.ipopt import IPOPT
from planner.ocp.solvers.solver import Nlp, Solver

SOLVERS: dict[str, Solver] = {solver.name: solver for solver in (IPOPT, FATROP)}
"""Every solver by its name."""

__all__ = ["SOLVERS", "Nlp", "Solver"]
