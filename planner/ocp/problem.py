"""The NLP of a scene structure with its solver, built once per key and cached.

Only what the scene asks for is built (each term of `planner.ocp.terms` it switches on).
Every number (robot, duration, mesh widths and quadrature weights, references, bounds,
weights) enters as a parameter or a bound, so one NLP serves every scene of its structure
(`planner.ocp.key`) and every mesh with its number of intervals. The NLP is written stage
by stage (`planner.ocp.stages`) and assembled with per-stage derivatives
(`planner.ocp.assembly`), so building one for another number of intervals is cheap; the
solver is the key's (`planner.ocp.solvers`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from planner.ocp.assembly import assemble
from planner.ocp.boundary import boundary_cost
from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout
from planner.ocp.monitor import IterationMonitor
from planner.ocp.parameters import Parameters
from planner.ocp.solvers import SOLVERS, Nlp
from planner.ocp.stage_function import RowGroups
from planner.ocp.stages import compiled_ready, stages
from planner.ocp.terms import terms_of
from planner.ocp.transcription import AnyTranscription

__all__ = ["Problem", "ProblemKey", "build", "cached_problem", "problem", "stages"]


@dataclass
class Problem:
    """A built NLP with the maps between its vectors and the scene's quantities. Its
    solvers and iteration monitor keep the state of a solve in themselves, and the cached
    problem is shared by every thread of the process: `lock` is held for a solve's whole
    call (`planner.ocp.solve.solve`)."""

    key: ProblemKey
    layout: Layout
    transcription: AnyTranscription
    params: Parameters
    lbg: np.ndarray
    ubg: np.ndarray
    solver: ca.Function
    monitor: IterationMonitor
    build_time: float
    structured: bool
    oracle: dict = field(repr=False)
    options: dict = field(repr=False)
    compiled: bool = False  # its derivative kernels run compiled (planner.compiled)
    _warm: ca.Function | None = field(repr=False, default=None)
    lock: threading.Lock = field(repr=False, compare=False, default_factory=threading.Lock)

    @property
    def n_params(self) -> int:
        return self.params.n_common + self.params.n_local * (self.key.intervals + 1)

    def warm_solver(self) -> ca.Function:
        """The same NLP with its solver set to start from given primal and dual values
        (`Solver.warm_options`); it reuses the derivatives of `solver`, so building it is
        cheap."""
        if self._warm is None:
            kind = SOLVERS[self.key.solver]
            assert kind.warm_options is not None  # asked for only of a solver that has them
            derivatives = {"hess_lag": self.solver.get_function("nlp_hess_l"),
                           "jac_g": self.solver.get_function("nlp_jac_g"),
                           "grad_f": self.solver.get_function("nlp_grad_f")}
            opts = {**self.options, **derivatives,
                    kind.name: {**self.options[kind.name], **kind.warm_options}}
            self._warm = ca.nlpsol("plan_warm", kind.name, self.oracle, opts)
        return self._warm


def build(key: ProblemKey, compiled: bool = False) -> Problem:
    """Build the NLP of a key and its solver (compiled: with compiled kernels)."""
    start = time.perf_counter()
    parts = stages(key.stage_key(), compiled)
    tr = key.transcription()
    layout = Layout(*parts.parts, key.global_variables(), key.intervals)
    assembly = assemble(parts.kernels, parts.derivatives, parts.link, layout,
                        parts.params.n_common, parts.params.n_local,
                        boundary_cost(key, layout, parts.params, terms_of(key)))
    lbg, ubg = _row_bounds(parts.bounds[0], key.intervals, parts.bounds[1], layout.copy_rows)
    n_params = parts.params.n_common + parts.params.n_local * (key.intervals + 1)
    monitor = IterationMonitor(layout.size, lbg.size, n_params)
    kind = SOLVERS[key.solver]
    opts = kind.options(Nlp(assembly, layout, parts.link,
                            sum(count for _, _, count in parts.bounds[0]), lbg, ubg, key.tol,
                            key.max_iter, monitor, tr.symbolic is ca.SX))
    solver = ca.nlpsol("plan", kind.name, assembly.nlp, opts)
    return Problem(key, layout, tr, parts.params, lbg, ubg, solver, monitor,
                   time.perf_counter() - start, assembly.structured, assembly.nlp, opts,
                   compiled)


def _row_bounds(stage: RowGroups, N: int, terminal: RowGroups,
                copies: int) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper bounds of all rows: N stages', the terminal's, then the `copies`
    rows that keep the globals' copies equal (zero)."""
    def expand(groups: RowGroups, side: int) -> np.ndarray:
        return np.concatenate([np.full(size, g[side]) for *g, size in groups] or [np.zeros(0)])

    lower, upper = (np.concatenate([np.tile(expand(stage, side), N), expand(terminal, side),
                                    np.zeros(copies)]) for side in (0, 1))
    return lower, upper


def problem(key: ProblemKey, wait: bool = False) -> Problem:
    """The NLP of a structure, built once and reused (cache keyed by `ProblemKey`). A key
    with `jit` gets compiled kernels once they are on disk; the first requests of its
    structure run interpreted while they are built in the background, unless wait."""
    return cached_problem(key, compiled_ready(key.stage_key(), wait))


@lru_cache(maxsize=256)
def cached_problem(key: ProblemKey, compiled: bool) -> Problem:
    """`build` of a key, cached. A plan meets two or three keys (its meshes): a service's
    or a suite's mix of scenes meets more than a few dozen, which, planned in turn,
    would evict one another from a small cache and be rebuilt every time round."""
    return build(key, compiled)
