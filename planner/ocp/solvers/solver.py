"""What a solver of the NLP is (`Solver`), and what it reads of a built NLP (`Nlp`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import casadi as ca
import numpy as np

from planner.ocp.assembly import Assembly
from planner.ocp.layout import Layout


@dataclass(frozen=True)
class Nlp:
    """A built NLP as its solver's options read it.

    assembly: the NLP and, when structured, its derivative functions; layout: its
    variables (N stages, the terminal, the globals); link: the leading entries of a stage
    that its predecessor reads (the node state); stage_rows: the rows of one stage, its
    `link` gap-closing rows first; lbg, ubg: the bounds of all rows (stages, then the
    terminal's); tol, max_iter: the key's (max_iter 0 unless the solver calls no iteration
    callback); monitor: the iteration callback; expandable: the stages are SX (no call
    that SX cannot hold, such as an integrator)."""

    assembly: Assembly
    layout: Layout
    link: int
    stage_rows: int
    lbg: np.ndarray
    ubg: np.ndarray
    tol: float
    max_iter: int
    monitor: ca.Callback
    expandable: bool


class Solver(Protocol):
    """An nlpsol plugin as the planner uses it.

    name: the plugin's (and `solver.name` of a scene); monitored: it calls the iteration
    callback at every iteration, so that the monitor reports progress and stops a solve at
    the plan's limits (otherwise its iteration limit is fixed when it is built, and a solve
    runs to its end); warm_options: its own options (nested under its name in nlpsol's)
    of a solve that starts from given primal and dual values, None when it takes none;
    idle_variable: its NLP carries one variable that no row or cost reads
    (`ProblemKey.idle`)."""

    @property
    def name(self) -> str: ...

    @property
    def monitored(self) -> bool: ...

    @property
    def warm_options(self) -> dict[str, Any] | None: ...

    @property
    def idle_variable(self) -> bool: ...

    def options(self, nlp: Nlp) -> dict[str, Any]:
        """The nlpsol options of a solver of `nlp`."""
        ...

    def status(self, stats: dict[str, Any]) -> str:
        """The outcome in a solve's statistics, named as Ipopt names it."""
        ...
