"""The NLP of a scene structure: variables, constraints, objective and parameters.

Only what the scene asks for is built (each term of `planner.ocp.terms` it switches on).
Every number (robot, duration, mesh widths and quadrature weights, references, bounds,
weights) enters as a parameter or a bound, so one NLP serves every scene of its structure
and every mesh with its number of intervals. The NLP is written stage by stage
(`planner.ocp.transcription`) and assembled with per-stage derivatives
(`planner.ocp.assembly`), so building one for another number of intervals is cheap.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Generic, overload

import casadi as ca
import numpy as np

from planner.compiled import library, source_digest
from planner.dynamics import functions
from planner.model import Structure, wave_slots
from planner.ocp import methods
from planner.ocp.assembly import Derivatives, Kernels, assemble, derivatives
from planner.ocp.layout import Layout, Part, split
from planner.ocp.monitor import IterationMonitor
from planner.ocp.terms import TERMS, Boundaries, Stage, Term
from planner.ocp.transcription import AnyTranscription, Model, StagePiece, Transcription
from planner.scene import Bounds, DurationRange, Scene
from planner.symbolic import Sym


@dataclass(frozen=True)
class ProblemKey:
    """Everything that decides the NLP's symbolic form; numbers are not part of it.

    torque_limit, position_bounds, velocity_bounds (the joints bounded below and above): the
    bounds that need rows beyond their variables' bounds to hold on whole intervals
    (`Transcription.hulls`); a bound whose polynomials the variables bound alone is not
    part of the key."""

    structure: Structure
    method: str
    intervals: int
    degree: int
    integrator: str
    steps: int
    form: str
    free_time: bool
    weighted_tracking: bool
    tip: bool
    margin: bool
    codesign: bool
    effort: bool
    time: bool
    smoothness: bool
    torque_limit: bool
    position_bounds: tuple[tuple[int, ...], tuple[int, ...]]
    velocity_bounds: tuple[tuple[int, ...], tuple[int, ...]]
    tol: float
    jit: bool
    solver: str = "ipopt"
    max_iter: int = 0  # fatrop's, fixed when its solver is built (0 for Ipopt)
    relaxed: bool = False
    """Virtual torques on the passive joints too (the relaxed dynamics of a continuation,
    `planner.ocp.continuation`): the torque vector holds the active joints' torques, then
    the passive joints' virtual ones; implicit form only."""

    @classmethod
    def of(cls, scene: Scene, intervals: int | None = None) -> ProblemKey:
        """The key of a scene's NLP on `intervals` intervals (default: the scene's)."""
        task, tr = scene.task, scene.transcription
        robot = scene.robot
        wavy = None
        if task.co_design is not None:
            wavy = tuple(link.wavy or link.joint == "active" for link in robot.links)
        shooting = tr.method == "multiple-shooting"
        key = cls(
            structure=Structure.of(robot, wavy),
            method=tr.method,
            intervals=tr.intervals if intervals is None else intervals,
            degree=tr.degree if tr.method in ("legendre", "radau") else 0,
            integrator=tr.integrator if shooting else "",
            steps=tr.steps if shooting and tr.integrator == "rk4" else 0,
            form="explicit" if shooting else tr.form,
            free_time=isinstance(task.duration, DurationRange),
            weighted_tracking=task.tracking is not None and task.tracking.mode == "weighted",
            tip=task.tip_target is not None,
            margin=task.coupling_margin is not None,
            codesign=task.co_design is not None,
            effort=task.objective.effort > 0,
            time=task.objective.time > 0,
            smoothness=task.objective.smoothness > 0,
            torque_limit=task.torque_limit is not None,
            position_bounds=_bounded(task.position_bounds),
            velocity_bounds=_bounded(task.velocity_bounds),
            tol=scene.solver.tol,
            jit=scene.solver.jit,
            solver=scene.solver.name,
            max_iter=scene.solver.max_iter if scene.solver.name == "fatrop" else 0,
        )
        hulls = _hulls(key.method, key.degree, key.integrator, key.steps, key.form)
        return replace(key, torque_limit=key.torque_limit and "tau" in hulls,
                       position_bounds=key.position_bounds if "q" in hulls else ((), ()),
                       velocity_bounds=key.velocity_bounds if "dq" in hulls else ((), ()))

    def transcription(self) -> AnyTranscription:
        """The transcription method of this key."""
        return methods.create(self.method, self.intervals, self.degree, self.integrator,
                              self.steps, self.form == "implicit")

    def terms(self) -> list[Term]:
        """The objective and constraint terms this key asks for."""
        return [term for term in TERMS if term.wanted(self)]

    def torque_count(self) -> int:
        """Rows of the torque variables: the active joints (and the passive ones, relaxed)."""
        return self.structure.n if self.relaxed else len(self.structure.active_idx)

    def fingerprint(self) -> str:
        """A stable hash of the whole key (its number of intervals too) and of the code that
        builds its NLP: two problems with the same fingerprint have the same variables and
        constraints."""
        return hashlib.sha256((repr(self) + formulation_hash()).encode()).hexdigest()[:20]

    def digest(self) -> str:
        """A stable hash of the key (but its number of intervals) and of the code that builds
        its NLP: names compiled stages in the disk cache, so code compiled from other
        sources is never loaded."""
        text = repr(replace(self, intervals=0)) + formulation_hash()
        return hashlib.sha256(text.encode()).hexdigest()[:20]


def _bounded(bounds: Bounds | None) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The joints with a (finite) lower bound and those with an upper bound."""
    if bounds is None:
        return (), ()
    def finite(values: list[float | None]) -> tuple[int, ...]:
        return tuple(j for j, v in enumerate(values) if v is not None and math.isfinite(v))
    return finite(bounds.lower), finite(bounds.upper)


@lru_cache(maxsize=64)
def _hulls(method: str, degree: int, integrator: str, steps: int, form: str) -> tuple[str, ...]:
    """`Transcription.hulls` of a key's method."""
    return methods.create(method, 1, degree, integrator, steps, form == "implicit").hulls


FORMULATION_SOURCES = ("dynamics.py", "model.py", "rk4.py", "ocp/transcription.py",
                       "ocp/interpolant.py", "ocp/methods", "ocp/terms.py", "ocp/assembly.py",
                       "ocp/layout.py", "ocp/problem.py")
"""The modules and packages (under planner/) whose code decides an NLP's symbolic form."""


@lru_cache(maxsize=1)
def formulation_hash() -> str:
    """A hash of the CasADi version and of `FORMULATION_SOURCES`."""
    root = Path(__file__).resolve().parents[1]
    sources = [source for name in FORMULATION_SOURCES for source in
               (sorted((root / name).glob("*.py")) if (root / name).is_dir() else [root / name])]
    return source_digest(sources=sources)


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


@dataclass(frozen=True)
class Parameters:
    """Where the NLP's numbers go: `common` entries by name, then per stage `local` entries
    by name (one column per stage, the terminal's last)."""

    common: dict[str, slice]
    local: dict[str, slice]

    @property
    def n_common(self) -> int:
        return max((s.stop for s in self.common.values()), default=0)

    @property
    def n_local(self) -> int:
        return max((s.stop for s in self.local.values()), default=0)


@dataclass
class Problem:
    """A built NLP with the maps between its vectors and the scene's quantities."""

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

    @property
    def n_params(self) -> int:
        return self.params.n_common + self.params.n_local * (self.key.intervals + 1)

    def warm_solver(self) -> ca.Function:
        """The same NLP with Ipopt set to start from given primal and dual values
        (`WARM_OPTIONS`); it reuses the derivatives of `solver`, so building it is cheap."""
        if self._warm is None:
            derivatives = {"hess_lag": self.solver.get_function("nlp_hess_l"),
                           "jac_g": self.solver.get_function("nlp_jac_g"),
                           "grad_f": self.solver.get_function("nlp_grad_f")}
            opts = {**self.options, **derivatives,
                    "ipopt": {**self.options["ipopt"], **WARM_OPTIONS}}
            self._warm = ca.nlpsol("plan_warm", "ipopt", self.oracle, opts)
        return self._warm


def _parameters(key: ProblemKey, tr: AnyTranscription, terms: list[Term]) -> Parameters:
    common = {"robot": key.structure.n_params}
    if not key.free_time:
        common["T"] = 1
    local = {"width": 1, "weights": len(tr.knot_positions), "boundary": 1}
    for term in terms:
        common[term.name] = term.common_size(key)
        if term.local_size(key, tr):
            local[term.name] = term.local_size(key, tr)
    return Parameters(_slices(common), _slices(local))


def _slices(sizes: dict[str, int]) -> dict[str, slice]:
    out, k = {}, 0
    for name, size in sizes.items():
        out[name] = slice(k, k + size)
        k += size
    return out


def _globals(key: ProblemKey) -> tuple[tuple[str, int], ...]:
    out = (("T", 1),) if key.free_time else ()
    return out + ((("wave", 2 * len(key.structure.active_idx)),) if key.codesign else ())


def _offsets(named: tuple[tuple[str, int], ...]) -> dict[str, slice]:
    return _slices(dict(named))


class _Symbols(Generic[Sym]):
    """The symbolic inputs of a stage function (in the transcription's Sym) and what terms
    read from them."""

    def __init__(self, key: ProblemKey, tr: Transcription[Sym], layout: Layout, params: Parameters,
                 width: int, terminal: bool):
        sym, s = tr.symbolic, key.structure
        self.w: Sym = sym.sym("w", width)
        self.nxt: Sym = sym.sym("nxt", 0 if terminal else sum(
            p.size for p in layout.stage if p.name in tr.link))
        self.glob: Sym = sym.sym("glob", layout.globals_size)
        self.common: Sym = sym.sym("common", params.n_common)
        self.local: Sym = sym.sym("local", params.n_local)
        globs = _offsets(layout.globals)
        self.T: Sym = self.glob[globs["T"]] if key.free_time else self.common[params.common["T"]]
        entries = ca.vertsplit(self.common[params.common["robot"]])
        if key.codesign:
            waves = self.glob[globs["wave"]]
            for col, joint in enumerate(s.active_idx):
                entries[wave_slots(s)[joint]] = waves[2 * col]
                entries[wave_slots(s)[joint] + 2] = waves[2 * col + 1]
        self.p: Sym = ca.vertcat(*entries)
        self.params = params

    def inputs(self, terminal: bool) -> list[Sym]:
        return [self.w, self.glob, self.common, self.local] if terminal else \
            [self.w, self.nxt, self.glob, self.common, self.local]

    def common_of(self, name: str) -> Sym:
        return self.common[self.params.common[name]]

    def local_of(self, name: str) -> Sym:
        return self.local[self.params.local[name]]


RowGroups = list[tuple[float, float, int]]
"""Constraint rows in groups: lower bound, upper bound, count."""


@overload
def _stage_function(key: ProblemKey, tr: Transcription[ca.SX], layout: Layout,
                    params: Parameters, terms: list[Term],
                    terminal: bool) -> tuple[ca.Function, RowGroups, tuple[str, ...]]: ...


@overload
def _stage_function(key: ProblemKey, tr: Transcription[ca.MX], layout: Layout,
                    params: Parameters, terms: list[Term],
                    terminal: bool) -> tuple[ca.Function, RowGroups, tuple[str, ...]]: ...


def _stage_function(key: ProblemKey, tr: Transcription[Sym], layout: Layout, params: Parameters,
                    terms: list[Term], terminal: bool
                    ) -> tuple[ca.Function, RowGroups, tuple[str, ...]]:
    """A stage's (or the terminal's) rows and cost, the bounds of its row groups and what
    each group is (`ROW_KINDS`, for the evidence of an infeasible task), written in the
    transcription's symbolic type (one overload each, so that a transcription of either
    type can be passed)."""
    s = key.structure
    parts = layout.terminal if terminal else layout.stage
    sym = _Symbols(key, tr, layout, params, sum(p.size for p in parts), terminal)
    f = functions(s)
    model = Model(s.n, key.torque_count(), key.form == "implicit", f["fd"], f["ode"], sym.p)
    w = split(parts, sym.w)
    width = sym.local_of("width")
    h = sym.T * width
    if terminal:
        piece = tr.terminal(w, model)
    else:
        link = tuple(p for p in layout.stage if p.name in tr.link)
        piece = tr.stage(w, split(link, sym.nxt), h, model)
    m = piece.knot_q.size2()
    weights = sym.T * sym.local_of("weights")[:m].T if m else tr.symbolic(1, 0)
    rows: list[tuple] = [(piece.defects, 0.0, 0.0)] if piece.defects.numel() else []
    kinds = ["dynamics"] * len(rows)
    if model.implicit and m:
        rows.append((ca.vec(_residual(key, f["residual"].map(m), piece, sym.p)), 0.0, 0.0))
        kinds.append("dynamics")
    context = Stage(key, s, piece, weights, h, sym.T, sym.p, sym.common_of, sym.local_of, terminal)
    cost = tr.symbolic(0)
    for term in terms:
        piece_cost, term_rows = term.cost(context), term.rows(context)
        if piece_cost is not None:
            cost += piece_cost
        if term_rows is not None:
            rows.append(term_rows)
            kinds.append(ROW_KINDS.get(term.name, term.name))
    if piece.gaps is not None and piece.gaps.numel():
        rows.insert(0, (piece.gaps, 0.0, 0.0))
        kinds.insert(0, "continuity")
    g = ca.vertcat(*(r for r, _, _ in rows)) if rows else tr.symbolic(0, 1)
    bounds = [(lo, hi, r.numel()) for r, lo, hi in rows]
    name = "terminal" if terminal else "stage"
    return ca.Function(name, sym.inputs(terminal), [g, cost]), bounds, tuple(kinds)


ROW_KINDS = {"tip": "tip target", "margin": "coupling margin", "torque_limit": "torque limit",
             "position_bounds": "position bound", "velocity_bounds": "velocity bound"}
"""What a term's constraint rows are, by its name; the transcription's own rows are
"dynamics" (collocation defects and M ddq + h - B tau) and "continuity" (the gaps between
stages). The task's initial and final states are bounds of variables, not rows."""


def _residual(key: ProblemKey, residual: ca.Function, piece: StagePiece[Sym], p: Sym) -> Sym:
    """M ddq + h - B tau at a stage's knots (n x m); relaxed, less the passive joints'
    virtual torques (the rows of the torque vector after the active ones)."""
    s = key.structure
    tau = piece.knot_tau
    if not key.relaxed:
        return residual(piece.knot_q, piece.knot_dq, piece.knot_ddq, tau, p)
    na = len(s.active_idx)
    scatter = np.zeros((s.n, len(s.passive_idx)))
    scatter[s.passive_idx, range(len(s.passive_idx))] = 1.0
    return residual(piece.knot_q, piece.knot_dq, piece.knot_ddq, tau[:na, :], p) \
        - ca.mtimes(ca.DM(scatter), tau[na:, :])


def torques(layout: Layout) -> tuple[list[np.ndarray], list[float], list[np.ndarray], list[float]]:
    """The torque columns of a stage and of the terminal in time order, with their positions
    (local indices into the stage's / the terminal's variables)."""
    def columns(parts: tuple[Part, ...]) -> tuple[list[np.ndarray], list[float]]:
        found, start = [], 0
        for part in parts:
            if part.kind == "tau":
                for j, at in enumerate(part.positions):
                    found.append((at, start + j * part.rows + np.arange(part.rows)))
            start += part.size
        found.sort(key=lambda item: item[0])
        return [idx for _, idx in found], [at for at, _ in found]

    stage, stage_at = columns(layout.stage)
    terminal, terminal_at = columns(layout.terminal)
    return stage, stage_at, terminal, terminal_at


def _boundary(key: ProblemKey, layout: Layout, params: Parameters, terms: list[Term]):
    """The cost of terms that couple neighbouring stages, as a function of (X, common, local)."""
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
        T = X[layout.size - layout.globals_size] if key.free_time else common[params.common["T"]]
        b = Boundaries(ca.reshape(X[np.concatenate(before).tolist()], -1, len(before)),
                       ca.reshape(X[np.concatenate(after).tolist()], -1, len(after)),
                       T * local[params.local["boundary"], :len(before)],
                       lambda name: common[params.common[name]])
        costs = (term.boundary_cost(b) for term in coupling)
        return sum((c for c in costs if c is not None), ca.MX(0))

    return cost


@dataclass(frozen=True)
class Stages:
    """What a key's NLP is made of, whatever its number of intervals: the stage and terminal
    functions with their derivative kernels, the variable parts, the parameters, and the
    bounds of the rows of a stage and of the terminal."""

    transcription: AnyTranscription
    kernels: Kernels
    derivatives: Derivatives | None
    parts: tuple[tuple[Part, ...], tuple[Part, ...]]
    params: Parameters
    bounds: tuple[list[tuple[float, float, int]], list[tuple[float, float, int]]]
    kinds: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())
    """What each row group of a stage and of the terminal is (`ROW_KINDS`)."""


@lru_cache(maxsize=32)
def stages(key: ProblemKey, compiled: bool = False) -> Stages:
    """The stages of a key (its `intervals` ignored; cached); compiled: with the derivative
    kernels of `compiled_kernels`, which the caller found on disk."""
    if compiled:
        plain = stages(key)
        loaded = None if plain.derivatives is None else compiled_kernels(key, plain.derivatives)
        return plain if loaded is None else replace(plain, derivatives=loaded)
    s = key.structure
    tr, terms = key.transcription(), key.terms()
    parts = tr.parts(s.n, key.torque_count())
    layout = Layout(*parts, _globals(key), 1)
    params = _parameters(key, tr, terms)
    stage, stage_bounds, stage_kinds = _stage_function(key, tr, layout, params, terms, False)
    terminal, terminal_bounds, terminal_kinds = _stage_function(key, tr, layout, params, terms,
                                                                True)
    kernels = Kernels(stage, terminal, sum(p.size for p in layout.stage if p.name in tr.link))
    return Stages(tr, kernels, derivatives(kernels), parts, params,
                  (stage_bounds, terminal_bounds), (stage_kinds, terminal_kinds))


def compiled_kernels(key: ProblemKey, derivatives: Derivatives,
                     wait: bool = False) -> Derivatives | None:
    """The derivative kernels (what an iteration spends its time in) compiled to C
    (`planner.compiled`), named by the stage key's digest: every number of intervals of the
    key, every process and every later run share the library. None while the library is
    being built in the background (unless wait). The stage functions themselves stay
    symbolic: nlpsol differentiates them for what it computes once per solve."""
    loaded = library(f"stages_{key.digest()}", derivatives.functions(), background=not wait)
    return None if loaded is None else derivatives.replaced(loaded)


def _compiled_ready(key: ProblemKey, wait: bool) -> bool:
    """Whether a key's NLP can have compiled kernels now: it asks for them (`solver.jit`)
    and they are on disk, or are built here (wait). If they are not, their build starts in
    the background."""
    if not key.jit:
        return False
    plain = stages(key)
    return plain.derivatives is not None and \
        compiled_kernels(key, plain.derivatives, wait) is not None


def _stage_key(key: ProblemKey) -> ProblemKey:
    """The key without its number of intervals: what the stages depend on."""
    return replace(key, intervals=0)


def build(key: ProblemKey, compiled: bool = False) -> Problem:
    """Build the NLP of a key and its Ipopt solver (compiled: with compiled kernels)."""
    start = time.perf_counter()
    parts = stages(_stage_key(key), compiled)
    tr = key.transcription()
    layout = Layout(*parts.parts, _globals(key), key.intervals)
    terms = key.terms()
    assembly = assemble(parts.kernels, parts.derivatives, layout, parts.params.n_common,
                        parts.params.n_local, _boundary(key, layout, parts.params, terms))
    lbg, ubg = _row_bounds(parts.bounds[0], key.intervals, parts.bounds[1])
    n_params = parts.params.n_common + parts.params.n_local * (key.intervals + 1)
    monitor = IterationMonitor(layout.size, lbg.size, n_params)
    opts = {
        "print_time": False,
        "iteration_callback": monitor,
        "ipopt": {"print_level": 0, "sb": "yes", "tol": key.tol, "max_iter": 100000,
                  **IPOPT_OPTIONS},
        **assembly.derivatives,
    }
    if key.solver == "fatrop":
        opts = _fatrop_options(key, parts, lbg, ubg)
    elif tr.symbolic is ca.MX:
        opts["ipopt"]["hessian_approximation"] = "limited-memory"
    elif not assembly.structured:
        opts["expand"] = True
    solver = ca.nlpsol("plan", key.solver, assembly.nlp, opts)
    return Problem(key, layout, tr, parts.params, lbg, ubg, solver, monitor,
                   time.perf_counter() - start, assembly.structured, assembly.nlp, opts,
                   compiled)


def _fatrop_options(key: ProblemKey, parts: Stages, lbg: np.ndarray, ubg: np.ndarray) -> dict:
    """fatrop's options: the stage structure (per stage: the node state, the other stage
    variables, the rows beyond the gap-closing ones), which rows are equalities, and its
    iteration limit and tolerance. fatrop differentiates the expanded NLP itself."""
    N = key.intervals
    stage, terminal = parts.parts
    nx = sum(p.size for p in stage if p.name in parts.transcription.link)
    nu = sum(p.size for p in stage) - nx
    rows = sum(count for _, _, count in parts.bounds[0])
    return {"print_time": False, "expand": True, "structure_detection": "manual", "N": N,
            "nx": [nx] * (N + 1), "nu": [nu] * N + [0],
            "ng": [rows - nx] * N + [sum(count for _, _, count in parts.bounds[1])],
            "equality": [bool(e) for e in lbg == ubg],
            "fatrop": {"print_level": 0, "tol": key.tol, "max_iter": key.max_iter}}


def _row_bounds(stage: list[tuple[float, float, int]], N: int,
                terminal: list[tuple[float, float, int]]) -> tuple[np.ndarray, np.ndarray]:
    def expand(groups: list[tuple[float, float, int]], side: int) -> np.ndarray:
        return np.concatenate([np.full(size, g[side]) for *g, size in groups] or [np.zeros(0)])

    return (np.concatenate([np.tile(expand(stage, 0), N), expand(terminal, 0)]),
            np.concatenate([np.tile(expand(stage, 1), N), expand(terminal, 1)]))


def problem(key: ProblemKey, wait: bool = False) -> Problem:
    """The NLP of a structure, built once and reused (cache keyed by `ProblemKey`). A key
    with `jit` gets compiled kernels once they are on disk; the first requests of its
    structure run interpreted while they are built in the background, unless wait."""
    return cached_problem(key, _compiled_ready(_stage_key(key), wait))


@lru_cache(maxsize=32)
def cached_problem(key: ProblemKey, compiled: bool) -> Problem:
    """`build` of a key, cached."""
    return build(key, compiled)

