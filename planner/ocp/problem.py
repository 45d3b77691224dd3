"""The NLP of a scene structure: variables, constraints, objective and parameters.

Only what the scene asks for is built (tracking cost, tip target, coupling margin, wave
co-design, each objective term). Every number (robot, duration, references, bounds,
weights) enters as a parameter or a bound, so one NLP serves every scene of its structure.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from planner.dynamics import derive, functions
from planner.model import Structure, wave_slots
from planner.ocp.layout import Layout
from planner.ocp.monitor import IterationMonitor
from planner.ocp.transcription import (
    Collocation,
    Discrete,
    HermiteSimpson,
    MultipleShooting,
    Trapezoidal,
)
from planner.scene import DurationRange, Scene


@dataclass(frozen=True)
class ProblemKey:
    """Everything that decides the NLP's symbolic form; numbers are not part of it."""

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
    tol: float
    jit: bool

    @classmethod
    def of(cls, scene: Scene) -> ProblemKey:
        task, tr = scene.task, scene.transcription
        robot = scene.robot
        wavy = None
        if task.co_design is not None:
            wavy = tuple(link.wavy or link.joint == "active" for link in robot.links)
        shooting = tr.method == "multiple-shooting"
        return cls(
            structure=Structure.of(robot, wavy),
            method=tr.method,
            intervals=tr.intervals,
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
            tol=scene.solver.tol,
            jit=scene.solver.jit,
        )

    def digest(self) -> str:
        """A stable hash of the key and of the code that builds its NLP: names the compiled
        NLP in the disk cache, so a library compiled by other code is never loaded."""
        return hashlib.sha256((repr(self) + formulation_hash()).encode()).hexdigest()[:20]


FORMULATION_SOURCES = ("dynamics.py", "model.py", "ocp/transcription.py", "ocp/problem.py")
"""The modules (under planner/) whose code decides an NLP's symbolic form."""


@lru_cache(maxsize=1)
def formulation_hash() -> str:
    """SHA-256 of the CasADi version and of `FORMULATION_SOURCES`."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256(ca.__version__.encode())
    for name in FORMULATION_SOURCES:
        digest.update((root / name).read_bytes())
    return digest.hexdigest()


@dataclass
class Problem:
    """A built NLP with the maps between its vectors and the scene's quantities."""

    key: ProblemKey
    layout: Layout
    transcription: object
    discrete: Discrete
    params: dict[str, slice]
    n_params: int
    lbg: np.ndarray
    ubg: np.ndarray
    solver: ca.Function
    monitor: IterationMonitor
    build_time: float
    accel: ca.Function = field(repr=False)

    def accelerations(self, x: np.ndarray, P: np.ndarray) -> dict[str, np.ndarray]:
        """Accelerations [rad/s^2] at the dynamics knots of a solution, by block name."""
        out = self.accel(x=x, P=P)
        return {name: np.array(value) for name, value in out.items()}


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


def _param_layout(key: ProblemKey, n_knots: int) -> tuple[dict[str, slice], int]:
    s = key.structure
    sizes = {"robot": s.n_params, "weights": 4}
    if not key.free_time:
        sizes["T"] = 1
    if key.weighted_tracking:
        sizes["ref"] = len(s.passive_idx) * n_knots
    if key.tip:
        sizes["tip"] = 2
    if key.margin:
        sizes["margin"] = 2  # the margin and the sign of det M_pa at the start
    out, k = {}, 0
    for name, size in sizes.items():
        out[name] = slice(k, k + size)
        k += size
    return out, k


def _transcription(key: ProblemKey, ode: ca.Function, p: ca.MX):
    N = key.intervals
    if key.method == "trapezoidal":
        return Trapezoidal(N)
    if key.method == "hermite-simpson":
        return HermiteSimpson(N)
    if key.method in ("legendre", "radau"):
        return Collocation(N, key.degree, key.method)
    return MultipleShooting(N, key.integrator, key.steps, ode, p)


def _margin_function(s: Structure) -> ca.Function:
    """Leading principal minors of G / margin^2 - I, G the smaller Gram matrix of M_pa.

    All minors > 0 <=> G - margin^2 I is positive definite <=> sigma_min(M_pa) > margin.
    A square block also keeps the sign its determinant has at the start:
    sign * det(M_pa) / margin^p - 1 >= 0, necessary for the margin (|det| >= margin^p) and
    what stops a path from jumping through det = 0 between two knots. A 1 x 1 block needs
    that row alone (sign * M_pa / margin >= 1 is the margin): its minor M_pa^2 / margin^2 - 1
    would be active at the same points with a parallel gradient, which breaks the linear
    independence of the active constraints' gradients that Ipopt's steps rely on.
    """
    sym = derive(s)
    margin, sign = ca.SX.sym("margin"), ca.SX.sym("sign")
    mpa = sym.mass[s.passive_idx, s.active_idx]
    gram = ca.mtimes(mpa, mpa.T) if mpa.size1() <= mpa.size2() else ca.mtimes(mpa.T, mpa)
    shifted = gram / margin**2 - ca.SX.eye(gram.size1())
    square = mpa.size1() == mpa.size2()
    orders = [] if square and mpa.size1() == 1 else range(1, gram.size1() + 1)
    rows = [ca.det(shifted[:k, :k]) for k in orders]
    if square:
        rows.append(sign * ca.det(mpa) / margin ** mpa.size1() - 1)
    return ca.Function("margin", [sym.q, sym.p, margin, sign], [ca.vertcat(*rows)])


def _robot_parameters(key: ProblemKey, lay: Layout, P: ca.MX, params: dict) -> ca.MX:
    """The dynamics' parameter vector: the scene's numbers, with co-designed waves as variables."""
    entries = ca.vertsplit(P[params["robot"]])
    if key.codesign:
        s = key.structure
        waves = lay.add("wave", 2, len(s.active_idx))  # rows: amplitude, phase
        slots = wave_slots(s)
        for col, joint in enumerate(s.active_idx):
            entries[slots[joint]] = waves[0, col]
            entries[slots[joint] + 2] = waves[1, col]
    return ca.vertcat(*entries)


def build(key: ProblemKey) -> Problem:
    """Build the NLP of a structure and its Ipopt solver."""
    start = time.perf_counter()
    s = key.structure
    f = functions(s)
    n, na = s.n, len(s.active_idx)
    lay = Layout()
    if key.free_time:
        T = lay.add("T", 1)
    params, n_params = _param_layout(key, _knot_count(key))
    P = ca.MX.sym("P", n_params)
    p = _robot_parameters(key, lay, P, params)
    if not key.free_time:
        T = P[params["T"]]
    h = T / key.intervals

    constraints: list[tuple[ca.MX, float, float]] = []
    accelerations: dict[str, ca.MX] = {}

    def dyn(name: str, q: ca.MX, dq: ca.MX, tau: ca.MX) -> ca.MX:
        K = q.size2()
        if key.form == "explicit":
            ddq = f["fd"].map(K)(q, dq, tau, p)
        else:
            ddq = lay.add(name, n, K)
            constraints.append((f["residual"].map(K)(q, dq, ddq, tau, p), 0.0, 0.0))
        accelerations[name] = ddq
        return ddq

    transcription = _transcription(key, f["ode"], p)
    disc = transcription.build(lay, n, na, h, dyn)
    if not accelerations:  # shooting: accelerations at the nodes, torque held from the left
        tau_nodes = ca.horzcat(disc.knot_tau, disc.knot_tau[:, -1])
        accelerations["ddq"] = f["fd"].map(key.intervals + 1)(disc.q, disc.dq, tau_nodes, p)
    constraints += [(d, 0.0, 0.0) for d in disc.defects]

    weights = P[params["weights"]]
    cost = 0
    K = disc.knot_times.size
    w = ca.DM(disc.weights).T
    if key.effort:
        cost += weights[0] * T * ca.mtimes(w, ca.sum1(disc.knot_tau**2).T)
    if key.time:
        cost += weights[1] * T
    if key.smoothness and disc.step_times.size:
        dt = ca.DM(disc.step_times).T * T
        cost += weights[2] * ca.sum2(ca.sum1(disc.tau_steps**2) / dt)
    if key.weighted_tracking:
        ref = ca.reshape(P[params["ref"]], len(s.passive_idx), K)
        err = disc.knot_q[s.passive_idx, :] - ref
        cost += weights[3] * T * ca.mtimes(w, ca.sum1(err**2).T)
    if key.tip:
        tip = f["tips"](disc.q[:, -1], p)[:, -1]
        constraints.append((tip - P[params["tip"]], 0.0, 0.0))
    if key.margin:
        margin, sign = P[params["margin"]][0], P[params["margin"]][1]
        minors = _margin_function(s).map(disc.path_q.size2())(disc.path_q, p, margin, sign)
        constraints.append((minors, 0.0, np.inf))

    g = ca.vertcat(*(ca.vec(c) for c, _, _ in constraints))
    lbg = np.concatenate([np.full(c.numel(), lo) for c, lo, _ in constraints])
    ubg = np.concatenate([np.full(c.numel(), hi) for c, _, hi in constraints])
    monitor = IterationMonitor(lay.size, g.numel(), n_params)
    opts = {
        "print_time": False,
        "iteration_callback": monitor,
        "ipopt": {"print_level": 0, "sb": "yes", "tol": key.tol, "max_iter": 100000,
                  **IPOPT_OPTIONS},
    }
    if key.integrator == "cvodes":
        opts["ipopt"]["hessian_approximation"] = "limited-memory"
    nlp = {"x": lay.vector(), "p": P, "f": cost, "g": g}
    if key.jit and key.integrator != "cvodes":
        solver = ca.nlpsol("plan", "ipopt", compiled_nlp(key, nlp, opts), opts)
    else:
        expand = key.method != "multiple-shooting"
        solver = ca.nlpsol("plan", "ipopt", nlp, {**opts, "expand": expand})
    accel = ca.Function("accelerations", [lay.vector(), P], list(accelerations.values()),
                        ["x", "P"], list(accelerations))
    return Problem(key, lay, transcription, disc, params, n_params, lbg, ubg, solver, monitor,
                   time.perf_counter() - start, accel)


_CODEGEN = threading.Lock()  # code generation writes into the working directory


def cache_dir() -> str:
    """Where compiled NLPs are kept: $UNDERTOW_CACHE_DIR, else ~/.cache/undertow."""
    default = os.path.join(os.path.expanduser("~"), ".cache", "undertow")
    return os.environ.get("UNDERTOW_CACHE_DIR", default)


def compiled_nlp(key: ProblemKey, nlp: dict, opts: dict) -> str:
    """Path of the NLP's functions compiled to a shared library, built on first use.

    The graph is generated unexpanded, so each per-knot function (and its derivatives)
    becomes one loop in C: a few MB of code that gcc compiles in seconds, where the
    expanded graph would be tens of MB. The file is named by the key's hash and written
    atomically, so processes sharing the cache never see a partial library.
    """
    folder = cache_dir()
    os.makedirs(folder, exist_ok=True)
    library = os.path.join(folder, f"nlp_{key.digest()}.so")
    if os.path.exists(library):
        return library
    generator = ca.nlpsol("plan", "ipopt", nlp, {**opts, "expand": False})
    with _CODEGEN, tempfile.TemporaryDirectory(dir=folder) as work, contextlib.chdir(work):
        source = generator.generate_dependencies("nlp.c", {"with_header": False})
        subprocess.run(["gcc", "-O1", "-fPIC", "-shared", source, "-o", "nlp.so"],
                       check=True, capture_output=True)
        os.replace("nlp.so", library)
    return library


def _knot_count(key: ProblemKey) -> int:
    """Number of dynamics knots of a transcription (fixes the size of the reference block)."""
    N = key.intervals
    return {"trapezoidal": N + 1, "hermite-simpson": 2 * N + 1, "legendre": N * key.degree,
            "radau": N * key.degree}.get(key.method, N)


@lru_cache(maxsize=32)
def problem(key: ProblemKey) -> Problem:
    """The NLP of a structure, built once and reused (cache keyed by `ProblemKey`)."""
    return build(key)
