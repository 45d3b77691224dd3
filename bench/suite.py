"""The task suite (testbed.suites.ordinary): how often a plan verifies, and how long a
verified plan takes, against the same planner with mesh refinement off, without retries,
with fatrop instead of Ipopt or with Ipopt's idle variable (`planner.ocp.solvers.ipopt`:
one more NLP variable that no row reads, and INERTIA_OPTIONS), and its peers on the same
50 intervals: a plain CasADi Opti script (bench/peers/opti.py, Legendre degree 3),
rockit (bench/peers/rockit.py: direct collocation with Ipopt, multiple shooting with
fatrop) and opty (bench/peers/opty.py, midpoint, in its own virtualenv `.venv-opty`).

Every planner configuration runs in a process of its own, its tasks one after the other as
a service worker would (NLPs built once per structure and number of intervals stay cached);
a peer runs each task in a process of its own (the Opti script and rockit build their
problem per task anyway; opty derives and compiles it). A plan counts as verified
when its solver succeeded and every interval, re-integrated from the plan's own state with
the torque its transcription delivers, lands on the plan within
solver.resimulation_tolerance (1e-3 rad); every peer's plans are checked by the same code.
Before a planner configuration's first task is timed, every task is planned once and the
compiled kernels its plan met are built (`planner.prebuild`: the builds its companion asked
for too), as a service has them once it has planned the task; their build time is
printed, not counted. (A plan of one iteration a task, as the service prebuilds its
examples, misses the kernels of the companion's continuation, which then ran interpreted.)
The configuration "structures never met" builds only what a service builds when it starts
(the built-in examples' kernels), in a cache folder of its own, so that each task's
structure is new to it unless an earlier task or an example had it, as on a service that
meets tasks it has never seen.
Every configuration has the same cap on a task, WALL_TIME: the planner stops itself there,
a peer's Ipopt gets it as max_wall_time (opty: everything from derivation on), a peer's
plan that arrives later does not count, and a peer's process still running a grace period
past the cap is stopped (fatrop has no wall-time option): its row is unverified, "stopped
at the cap", with the cap as its time. Time to a verified
plan is the wall time of the whole plan (build, every solve, mesh pass and retry, error
estimates and verification), counted only for verified plans. A peer whose package is
missing is skipped, with the reason printed and written.

    python -m bench suite [--count 48] [--seed 20261123] [--configs undertow,...] [--merge]
    python -m bench suite --suite hard [--seed 20261125] [--categories seed-g0-cross,...]

`--seed` other than the suite's own writes its own section and CSV (suite-seed-N.csv):
tasks the planner was not tuned on.

`--suite hard` runs `testbed.suites.hard` (its own seed, and the two of
`testbed.suites.hard.HELD_OUT`) and reports per task what the solves cost as Ipopt counts
it: iterations, restoration-phase iterations, KKT factorizations, CPU time (this process
and its children) and wall time; and per configuration the share verified and the median,
90th percentile and maximum time to a verified plan. It writes hard-suite.csv (or
hard-suite-seed-N.csv) and its own section. Ipopt gives restoration iterations and
factorizations only in its log: the planner runs with Ipopt's print level at LOG_LEVEL,
its output (file descriptor 1) taken to a temporary file per task and counted. Peers run
only the tasks they can state (fixed duration, state to state, effort objective: the
crossings, swings and 5- to 8-link arms). `--cap` lowers every configuration's cap on a
task (a quick check of the plumbing; a scene's own settings otherwise).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator

import numpy as np
from pydantic import ValidationError

from bench import harness
from bench.examples import BEFORE
from bench.scenes import fixed_duration
from planner.ocp.solvers.ipopt import INERTIA_OPTIONS
from planner.scene import DurationRange, Scene
from testbed.suites import hard as hard_suite
from testbed.suites.ordinary import COUNT, SEED, tasks

NEVER_MET = "structures never met"
CONFIGS = {
    "undertow": "default settings",
    "refinement off": "transcription.refinement.enabled false",
    "retries off": "solver.retries 0",
    "fatrop": "solver.name fatrop",
    "idle variable": "an idle NLP variable, perturb_dec_fact 1/2, perturb_inc_fact 4, "
                     "first_hessian_perturbation 1e-8",
    "one BLAS thread": "OPENBLAS_NUM_THREADS 1: the solver's OpenBLAS on one thread (the "
                       "planner's: OpenBLAS' own count, a thread per core)",
    NEVER_MET: "default settings in a cache folder of its own that holds only "
               "the built-in examples' compiled kernels, as a service has them when it "
               "starts: a structure's first plans run interpreted while its kernels are "
               "built in the background",
    "before": f"the planner of {BEFORE}, before plans were refined and checked interval by "
              "interval (verified: the whole-horizon replay within 1e-3 rad)",
    "Opti script": "plain CasADi Opti, Legendre 3, 50 intervals, Ipopt defaults",
    "rockit": "rockit DirectCollocation, Legendre 3, 50 intervals, piecewise-constant "
              "torque, Ipopt defaults",
    "rockit fatrop": "rockit MultipleShooting, one RK4 step on each of 50 intervals, "
                     "piecewise-constant torque, CasADi's fatrop",
    "opty": "opty midpoint, 50 intervals, torque linear between nodes, Ipopt (L-BFGS)",
}
ROCKIT = {"rockit": ("collocation", "ipopt"), "rockit fatrop": ("multiple shooting", "fatrop")}
PEERS = ("Opti script", *ROCKIT)  # run in this project's environment
OPTY_METHOD = "midpoint"
OPTY_GRACE = 30.0  # [s] past WALL_TIME before an opty process is stopped (its cap is its own)
PEER_GRACE = 10.0  # [s] past WALL_TIME before an Opti script or rockit task's process is
# stopped: its start and imports (a few seconds), and the check of a plan that came at the cap
WALL_TIME = 60.0  # [s] every configuration's cap on one task (the planner's default)
BUILD_WAIT = 3600.0
"""[s] How long a planner configuration waits for the compiled kernels it builds ahead: a
suite of new structures (the hard suite's 5- to 8-link arms, after a change to the stages'
sources) makes dozens of libraries, built one after the other; past it the tasks start and
the rest build beside them."""
DOC = harness.DOCS / "benchmarks.md"
SECTION = "Task suite: verified plans and time to a verified plan"
HARD_SECTION = "Hard suite: iterations, factorizations and time to a verified plan"
SUITES = ("default", "hard")
LOG_LEVEL = 6
"""Ipopt's print level on the hard suite: its iteration table (restoration iterations marked
"r") and, per search direction, "Number of trial factorizations performed" (level 6,
J_DETAILED); about 4 kB a iteration, a few per cent of a solve's time."""
_ITERATION = re.compile(r"^\s*(\d+)(r?)\s+[-+]?\d\.\d+e[-+]\d+\s", re.MULTILINE)
_TRIALS = re.compile(r"^Number of trial factorizations performed:\s*(\d+)", re.MULTILINE)
_ESTIMATES = re.compile(r"^Least square estimates", re.MULTILINE)


def set_cap(cap: float) -> None:
    """Every configuration's cap on one task [s] (WALL_TIME), in this process."""
    global WALL_TIME
    WALL_TIME = cap


def suite_tasks(suite: str, count: int, seed: int,
                categories: tuple[str, ...] = ()) -> list[tuple[str, Scene]]:
    """The tasks of the default suite or the hard one (only `categories` of it, if given)."""
    if suite == "hard":
        extra = [c for c in categories if c in hard_suite.EXTRA_CATEGORIES]
        out = [] if extra and len(extra) == len(categories) else hard_suite.hard_tasks(count, seed)
        out = [t for t in out if not categories or hard_suite.category(t[0]) in categories]
        return out + [t for c in extra for t in hard_suite.category_tasks(c, seed=seed)]
    return tasks(count, seed)


def supported(scene: Scene) -> bool:
    """Whether the peers can state the task: a fixed duration, from a state to a state,
    the effort objective alone, no bounds but a torque limit, no co-design or tracking."""
    task = scene.task
    return (not isinstance(task.duration, DurationRange)
            and all(v is not None for v in [*task.final.q, *task.final.dq])
            and task.tip_target is None and task.co_design is None and task.tracking is None
            and task.position_bounds is None and task.velocity_bounds is None
            and task.objective.time == 0.0 and task.objective.smoothness == 0.0)


@contextlib.contextmanager
def solver_log() -> Iterator[Callable[[], str]]:
    """What is written to file descriptor 1 within (Ipopt's log, C stdio flushed), as a
    function that returns it once the block has ended."""
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    saved = os.dup(1)
    text = ""
    with tempfile.TemporaryFile(mode="w+", errors="replace") as log:
        os.dup2(log.fileno(), 1)
        try:
            yield lambda: text
        finally:
            sys.stdout.flush()
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
            log.seek(0)
            text = log.read()


def log_counts(text: str, iterations: int) -> dict:
    """Restoration iterations, KKT factorizations and iterations in Ipopt's log at
    LOG_LEVEL: iteration rows marked "r"; the trial factorizations of every search direction
    plus one for each least-squares multiplier estimate; iteration rows numbered above 0.
    The log holds the companion process's solves too (`planner.ocp.portfolio`), whose
    iterations a plan counts only when the companion's plan is chosen: factorizations per
    iteration divide by the log's own iterations. NaN when the log holds no iteration row
    while the plan made iterations (a solver that writes none: fatrop)."""
    rows = _ITERATION.findall(text)
    if not rows and iterations > 0:
        return {"restoration": math.nan, "factorizations": math.nan,
                "logged_iterations": math.nan}
    return {"restoration": sum(1 for _, r in rows if r),
            "factorizations": sum(int(k) for k in _TRIALS.findall(text))
            + len(_ESTIMATES.findall(text)),
            "logged_iterations": sum(1 for k, _ in rows if int(k) > 0)}


def per_iteration(rows: list[dict]) -> float:
    """KKT factorizations per Ipopt iteration over rows: their sums, both counted in the
    logs (NaN without any; a row from before the log's iterations were counted has none)."""
    pairs = [(float(r["factorizations"]), float(r["logged_iterations"])) for r in rows
             if r.get("logged_iterations") not in (None, "")]
    pairs = [(f, k) for f, k in pairs if math.isfinite(f) and math.isfinite(k) and k > 0]
    total = sum(k for _, k in pairs)
    return sum(f for f, _ in pairs) / total if total else math.nan


IPOPT_INERTIA = {"perturb_dec_fact": 1 / 3, "perturb_inc_fact": 8.0,
                 "first_hessian_perturbation": 1e-4}
"""Ipopt's own settings of its inertia correction (the planner's, which leaves the idle
variable out: `planner.ocp.solvers.ipopt`)."""


def _ipopt(config: str, hard: bool) -> tuple[dict, bool | None]:
    """The Ipopt options and idle variable (None: the planner's) of a planner configuration."""
    options = {"print_level": LOG_LEVEL} if hard else {}
    if config == "idle variable":
        return {**options, **INERTIA_OPTIONS}, True
    return options, None


def _settings(config: str) -> dict:
    """Scene changes of a planner configuration."""
    changes: dict[str, dict] = {
        "refinement off": {"transcription": {"refinement": {"enabled": False}}},
        "retries off": {"solver": {"retries": 0}},
        "fatrop": {"solver": {"name": "fatrop"}}}
    return changes.get(config, {})


def _merged(scene: dict, changes: dict) -> dict:
    out = dict(scene)
    for key, value in changes.items():
        out[key] = _merged(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


UNCERTAINTY = {"mass": 0.1}
"""The model error every planner task is verified under (reported, not required): every
link's mass 10 % off, both ways (docs/planner.md, "Robustness to model error")."""


def with_uncertainty(scene: dict) -> dict:
    """The scene with UNCERTAINTY unless it states one of its own."""
    if scene["task"].get("uncertainty") is None:
        scene = {**scene, "task": {**scene["task"], "uncertainty": UNCERTAINTY}}
    return scene


def _limit_excess(scene: Scene, result) -> float | None:
    """How far the delivered torque goes beyond the task's torque limit, relative to it
    (None without a limit)."""
    excess, limit = result.verification.torque_excess, scene.task.torque_limit
    if excess is None or limit is None:
        return None
    return excess / max(float(np.max(limit)), 1e-12)


def build_ahead(suite: str, count: int, seed: int, categories: tuple[str, ...],
                 changes: dict) -> None:
    """The compiled kernels every task's plan meets built before any task is timed, as a
    service has them once it has planned the task (`planner.prebuild`, each task planned
    once in full); their build time is printed, not counted in any task's."""
    from planner import compiled, prebuild

    scenes = []
    for _, scene in suite_tasks(suite, count, seed, tuple(categories)):
        with contextlib.suppress(ValidationError):
            scenes.append(Scene.model_validate(_merged(scene.model_dump(mode="json"),
                                                       changes)))
    started = time.perf_counter()
    built = prebuild.build([s for s in scenes if s.solver.jit], wait=BUILD_WAIT)
    print(f"compiled kernels: {len(built)} libraries built ahead in "
          f"{time.perf_counter() - started:.0f} s", flush=True)
    if still := compiled.building():
        print(f"compiled kernels: {len(still)} libraries still building after "
              f"{BUILD_WAIT:.0f} s; the tasks of their structures start interpreted",
              flush=True)


def started_service() -> None:
    """This process's cache folder a new one holding only what a service builds when it
    starts (`planner.prebuild`: the built-in examples' kernels), so that every other
    structure is met for the first time by its first task."""
    from planner import prebuild

    os.environ["UNDERTOW_CACHE_DIR"] = tempfile.mkdtemp(prefix="undertow-never-met-")
    started = time.perf_counter()
    built = prebuild.build(wait=BUILD_WAIT)
    print(f"compiled kernels: the examples' {len(built)} libraries built in "
          f"{time.perf_counter() - started:.0f} s, none of the tasks'", flush=True)


def run_planner(config: str, count: int, seed: int, suite: str = "default",
                cap: float | None = None, categories: tuple[str, ...] = ()) -> dict:
    """Every task with the planner in one configuration (in this process); `cap` [s]: the
    scene's solver.max_wall_time instead of its own."""
    from planner.ocp import plan

    if config == "one BLAS thread":  # read by OpenBLAS when the first solver loads it
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    changes = _settings(config)
    if cap is not None:
        changes = _merged(changes, {"solver": {"max_wall_time": cap}})
    hard = suite == "hard"
    if config == NEVER_MET:
        started_service()
    else:
        build_ahead(suite, count, seed, categories, changes)
    rows = []
    with harness.ipopt_options(*_ipopt(config, hard)):
        for name, scene in suite_tasks(suite, count, seed, tuple(categories)):
            try:
                scene = Scene.model_validate(with_uncertainty(
                    _merged(scene.model_dump(mode="json"), changes)))
            except ValidationError:  # a task this configuration cannot state (fatrop: free
                continue  # time, co-design), left out as the peers leave theirs
            cpu = harness.cpu_time()
            with solver_log() as log:
                started = time.perf_counter()
                result = plan(scene)
                elapsed = time.perf_counter() - started
            cpu = harness.cpu_time() - cpu
            v, s = result.verification, result.solver
            ok = bool(s.success and v.verified)
            row = {"task": name, "config": config, "verified": ok, "status": s.status,
                   "iterations": s.iterations, "solves": len(result.mesh_passes),
                   "intervals": len(result.t) - 1, "time": elapsed,
                   "time_to_verified": elapsed if ok else math.nan,
                   "local_error": v.local_error, "resimulation_error": v.resimulation_error,
                   "growth_factor": v.growth_factor, "closed_loop_error": v.closed_loop_error,
                   "perturbed_closed_loop_error": v.perturbed_closed_loop_error,
                   "objective": result.objective, "strategy": s.strategy,
                   "torque_excess": _limit_excess(scene, result),
                   "past_budget": elapsed - scene.solver.max_wall_time,
                   **_robust(result)}
            if hard:
                row = {"task": name, "category": hard_suite.category(name), **row,
                       **log_counts(log(), s.iterations), "cpu": cpu,
                       "time_to_plan": elapsed if s.success else math.nan,
                       "duration": result.duration}
            rows.append(row)
    return {"rows": rows}


def _robust(result) -> dict:
    """The plan's robustness figures under UNCERTAINTY: the worst closed-loop tracking and
    final-state errors, and the torque alone's final-state error."""
    r = result.verification.robustness
    return {"robust_tracking_error": None if r is None else r.worst_tracking_error,
            "robust_final_error": None if r is None else r.worst_final_error,
            "open_loop_final_error": None if r is None else r.open_loop_final_error}


def _peer_row(name: str, config: str, scene, out: dict, elapsed: float,
              hard: bool = False) -> dict:
    """A peer's row: verified when its solver succeeded, its plan passes the planner's
    interval check and it came within the cap WALL_TIME (on the hard suite with its
    columns, the counts in Ipopt's log unknown)."""
    ok = bool(out["success"] and out["local_error"] <= scene.solver.resimulation_tolerance
              and elapsed <= WALL_TIME)
    row = _peer_columns(name, config, scene, out, elapsed, ok)
    if hard:
        row = {"task": name, "category": hard_suite.category(name), **row,
               "restoration": math.nan, "factorizations": math.nan,
               "logged_iterations": math.nan, "cpu": out.get("cpu", math.nan),
               "time_to_plan": elapsed if out["success"] and elapsed <= WALL_TIME else math.nan,
               "duration": scene.task.duration}
    return row


def _peer_columns(name: str, config: str, scene, out: dict, elapsed: float, ok: bool) -> dict:
    return {"task": name, "config": config, "verified": ok, "status": out["status"],
            "iterations": out["iterations"], "solves": 1,
            "intervals": scene.transcription.intervals, "time": elapsed,
            "time_to_verified": elapsed if ok else math.nan, "local_error": out["local_error"],
            "resimulation_error": out["resimulation_error"], "growth_factor": math.nan,
            "closed_loop_error": math.nan, "perturbed_closed_loop_error": math.nan,
            "objective": out["objective"], "strategy": "direct"}


def peer_task(config: str, scene: dict, cap: float = WALL_TIME) -> dict:
    """One task with the Opti script or rockit, in this process: the peer's result (see
    `bench.peers.opti.solve`), its wall time [s] from the build through the check and its
    CPU time [s]."""
    from bench.peers import opti, rockit

    set_cap(cap)
    task = Scene.model_validate(scene)
    started, cpu = time.perf_counter(), harness.cpu_time()
    if config == "Opti script":
        out = opti.solve(task, wall_time=WALL_TIME)
    else:
        out = rockit.solve(task, *ROCKIT[config], wall_time=WALL_TIME)
    return {**out, "time": time.perf_counter() - started, "cpu": harness.cpu_time() - cpu}


def run_peer(config: str, count: int, seed: int, suite: str = "default",
             categories: tuple[str, ...] = ()) -> list[dict]:
    """Every task (that the peers can state) with the Opti script or rockit, each in a
    process of its own stopped at WALL_TIME + PEER_GRACE (fatrop has no wall-time option
    of its own)."""
    rows = []
    for name, scene in suite_tasks(suite, count, seed, categories):
        if not supported(scene):
            continue
        started = time.perf_counter()
        out = harness.isolated("suite", "peer_task",
                               {"config": config, "scene": scene.model_dump(mode="json"),
                                "cap": WALL_TIME},
                               WALL_TIME + PEER_GRACE)
        elapsed = out.get("time", time.perf_counter() - started)
        rows.append(_peer_row(name, config, scene, *_unfinished(out, elapsed),
                              hard=suite == "hard"))
    return rows


def _unfinished(out: dict, elapsed: float) -> tuple[dict, float]:
    """A peer's result and time [s]; for a process that returned none, a failed result
    saying why, and the cap WALL_TIME as its time when it was stopped there."""
    if "failure" not in out:
        return out, elapsed
    stopped = harness.stopped(out)
    return ({"success": False, "iterations": 0, "objective": math.nan,
             "status": f"stopped at the {WALL_TIME:g} s cap" if stopped else out["failure"][:80],
             "local_error": math.nan, "resimulation_error": math.nan},
            WALL_TIME if stopped else elapsed)


def run_opty(count: int, seed: int, suite: str = "default", cap: float = WALL_TIME,
             categories: tuple[str, ...] = ()) -> dict:
    """Every task with opty (midpoint on the same intervals), each in a process of the opty
    venv that derives, compiles and solves it within WALL_TIME (in this process: the
    check of its plan)."""
    from bench import peer_opty
    from planner.ocp.accuracy import interval_errors
    from planner.ocp.guess import hermite_guess
    from planner.ocp.verify import open_loop

    set_cap(cap)
    rng = np.random.default_rng(seed)
    rows = []
    for name, scene in suite_tasks(suite, count, seed, tuple(categories)):
        if not supported(scene):
            continue
        nodes = scene.transcription.intervals + 1
        guess = hermite_guess(scene, scene.robot, fixed_duration(scene))(
            np.linspace(0.0, 1.0, nodes))
        check = peer_opty.check_state(scene.robot, rng)
        spec = {"robot": scene.robot.model_dump(), "task": scene.task.model_dump(),
                "method": OPTY_METHOD, "nodes": nodes, "tol": scene.solver.tol,
                "repeats": 1, "check": check, "wall_time": WALL_TIME,
                "guess": {k: guess[k].tolist() for k in ("q", "dq", "tau")}}
        started = time.perf_counter()
        out = peer_opty.call_worker(spec, timeout=WALL_TIME + OPTY_GRACE)
        elapsed = time.perf_counter() - started
        if "failure" in out:
            result, elapsed = _unfinished(out, elapsed)
        else:
            solve = out["solves"][0]
            model_ok = (out["M_error"] <= peer_opty.CHECK_TOL * max(1.0, np.abs(check["M"]).max())
                        and out["h_error"] <= peer_opty.CHECK_TOL
                        * max(1.0, np.abs(check["h"]).max()))
            interp = peer_opty.interpolant(scene, OPTY_METHOD, out)
            local, replay = math.nan, None
            if interp is not None:
                local = float(interval_errors(scene.robot, interp)[0].max())
                replay = open_loop(scene.robot, interp)[0]
            result = {"success": solve["success"] and model_ok,
                      "status": solve["status"] if model_ok else "model differs",
                      "iterations": solve["iterations"], "objective": solve["nlp_objective"],
                      "local_error": local if math.isfinite(local) else math.nan,
                      "resimulation_error": math.nan if replay is None else replay}
        rows.append(_peer_row(name, "opty", scene, result, elapsed, hard=suite == "hard"))
    return {"rows": rows}


def missing(config: str) -> str:
    """Why a configuration cannot run here ("" when it can)."""
    if config in ROCKIT and importlib.util.find_spec("rockit") is None:
        return "rockit-meco is not installed (pip install -e '.[bench]')"
    if config == "opty":
        from bench import peer_opty

        if not peer_opty.opty_ready():
            print(f"installing opty into {peer_opty.VENV} ...", flush=True)
            install = peer_opty.install_opty()
            if "failure" in install:
                what, error = install["failure"]
                return f"installing opty failed: `{what}` ended with: {error}"
    return ""


_BEFORE_RUN = """
import json, sys, time
sys.path.insert(0, {root!r})
from planner.ocp import plan
from planner.scene import Scene
for line in sys.stdin:
    name, scene = json.loads(line)
    started = time.perf_counter()
    result = plan(Scene.model_validate(scene))
    elapsed = time.perf_counter() - started
    v = result.verification
    print("RESULT " + json.dumps({{"task": name, "status": result.solver.status,
          "verified": bool(result.solver.success and v.verified),
          "iterations": result.solver.iterations, "time": elapsed,
          "resimulation_error": v.resimulation_error, "objective": result.objective}}),
          flush=True)
"""


def run_before(count: int, seed: int, commit: str, suite: str = "default",
               categories: tuple[str, ...] = ()) -> list[dict]:
    """Every task with the planner of an earlier commit (a temporary worktree)."""
    chosen = suite_tasks(suite, count, seed, categories)
    count = len(chosen)
    lines = "".join(json.dumps([name, scene.model_dump(mode="json", exclude_defaults=True)])
                    + "\n" for name, scene in chosen)
    with harness.checkout(commit) as old:
        run = subprocess.run([harness.PYTHON, "-c", _BEFORE_RUN.format(root=str(old))],
                             input=lines, cwd=old, capture_output=True, text=True,
                             timeout=count * (2 * WALL_TIME + 30), check=False)
    rows = [{**out, "config": "before", "solves": 1, "intervals": 50,
             "time_to_verified": out["time"] if out["verified"] else math.nan,
             "local_error": math.nan, "growth_factor": math.nan,
             "closed_loop_error": math.nan, "perturbed_closed_loop_error": math.nan,
             "strategy": "direct"} for out in harness.result_lines(run.stdout)]
    if suite == "hard":
        rows = [{"task": r["task"], "category": hard_suite.category(r["task"]), **r,
                 "restoration": math.nan, "factorizations": math.nan,
                 "logged_iterations": math.nan, "cpu": math.nan,
                 "time_to_plan": math.nan, "duration": math.nan} for r in rows]
    if len(rows) != count:
        raise RuntimeError(f"before: {len(rows)} of {count} tasks ran: {harness.last_error(run)}")
    return rows


def _run(config: str, count: int, seed: int, suite: str = "default",
         categories: tuple[str, ...] = (), cap: float | None = None) -> list[dict]:
    timeout = count * (2 * WALL_TIME + 30)
    if config == "before":
        return run_before(count, seed, BEFORE, suite, categories)
    if config == "opty":
        timeout = count * (WALL_TIME + OPTY_GRACE + 30)
        out = harness.isolated("suite", "run_opty",
                               {"count": count, "seed": seed, "suite": suite, "cap": WALL_TIME,
                                "categories": list(categories)}, timeout)
    elif config in PEERS:
        return run_peer(config, count, seed, suite, categories)
    else:
        out = harness.isolated("suite", "run_planner",
                               {"config": config, "count": count, "seed": seed, "suite": suite,
                                "cap": cap, "categories": list(categories)}, timeout)
    if "failure" in out:
        raise RuntimeError(f"{config}: {out['failure']}")
    return out["rows"]


def _summary(rows: list[dict], config: str) -> dict:
    mine = [r for r in rows if r["config"] == config]
    times = [r["time_to_verified"] for r in mine if r["verified"]]
    verified = sum(r["verified"] for r in mine)
    every = sorted(r["time_to_verified"] if r["verified"] else math.inf for r in mine)
    middle = every[(len(every) - 1) // 2] if every else math.inf
    return {"config": config, "what": CONFIGS[config], "tasks": len(mine), "verified": verified,
            "share": f"{100 * verified / len(mine):.0f} %",
            "median_time": harness.median(times),
            "median_all": "never" if math.isinf(middle) else middle,
            "p90_time": float(np.percentile(times, 90)) if times else math.nan,
            "median_iterations": harness.median([r["iterations"] for r in mine]),
            "median_solves": harness.median([r["solves"] for r in mine])}


def _plot(rows: list[dict], configs: list[str]) -> None:
    from matplotlib.figure import Figure

    from planner.plots import PALETTE, render

    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    colours = PALETTE["joints"]
    for index, config in enumerate(configs):
        colour, style = colours[index % len(colours)], "-" if index < len(colours) else "--"
        mine = [r for r in rows if r["config"] == config]
        times = np.sort([r["time_to_verified"] for r in mine if r["verified"]])
        share = np.arange(1, len(times) + 1) / len(mine)
        ax.step(np.concatenate([[1e-2], times]), np.concatenate([[0.0], share]), where="post",
                color=colour, linestyle=style, label=config)
    ax.set_xscale("log")
    ax.set_xlabel("time to a verified plan [s]")
    ax.set_ylabel("share of the tasks verified")
    ax.set_ylim(0, 1.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    harness.output(harness.DOCS / "img" / "suite.png").write_bytes(render(fig))


def _task_table(rows: list[dict]) -> str:
    """Per task: the default planner's figures and the others' verdicts."""
    by = {(r["task"], r["config"]): r for r in rows}
    names = list(dict.fromkeys(r["task"] for r in rows))
    others = [c for c in CONFIGS if c != "undertow" and (names[0], c) in by]
    lines = []
    for name in names:
        r = by.get((name, "undertow"))
        if r is None:
            continue
        line = {"task": name, "ok": "yes" if r["verified"] else "no", "time": r["time"],
                "iterations": r["iterations"], "solves": r["solves"], "N": r["intervals"],
                "local": r["local_error"], "open": r["resimulation_error"],
                "growth": r["growth_factor"], "closed": r["closed_loop_error"],
                "perturbed": r["perturbed_closed_loop_error"],
                "robust": r.get("robust_tracking_error"),
                "alone": r.get("open_loop_final_error"), "strategy": r["strategy"]}
        for config in others:
            line[config] = "yes" if by[(name, config)]["verified"] else "no"
        lines.append(line)
    columns = [("task", "task"), ("ok", "verified"), ("time", "time [s]"),
               ("iterations", "iterations"), ("solves", "solves"), ("N", "intervals"),
               ("local", "interval error [rad]"), ("open", "open-loop replay [rad]"),
               ("growth", "growth factor"), ("closed", "closed-loop replay [rad]"),
               ("perturbed", "closed loop, perturbed start [rad]"),
               ("robust", "mass ±10 %: tracking [rad]"),
               ("alone", "mass ±10 %: final, torque alone"), ("strategy", "strategy"),
               *((c, c) for c in others)]
    return harness.table(lines, columns)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench suite", description=__doc__)
    parser.add_argument("--suite", choices=SUITES, default="default",
                        help="default: testbed.suites.ordinary; hard: testbed.suites.hard")
    parser.add_argument("--count", type=int, default=None,
                        help=f"tasks (default {COUNT}; hard: {hard_suite.COUNT})")
    parser.add_argument("--seed", type=int, default=None,
                        help=f"default {SEED}; hard: {hard_suite.SEED}, held out: "
                             + ", ".join(map(str, hard_suite.HELD_OUT)))
    parser.add_argument("--categories", default="",
                        help="hard suite only: comma-separated categories to run, from: "
                             + ", ".join((*hard_suite.CATEGORIES, *hard_suite.EXTRA_CATEGORIES))
                             + " (an extra category runs its own "
                             f"{hard_suite.EXTRA_COUNT} tasks)")
    parser.add_argument("--cap", type=float, default=None,
                        help=f"every configuration's cap on a task [s] (default {WALL_TIME:g}, "
                             "the planner's max_wall_time)")
    parser.add_argument("--merge", action="store_true",
                        help="keep the other configurations' rows of the CSV, and with "
                             "--categories the other categories' rows (runs split "
                             "over processes or cores write one table)")
    parser.add_argument("--note", default="",
                        help="where and how the rows were measured, when they come from "
                             "several invocations (printed above the manifest)")
    parser.add_argument("--configs", default=None,
                        help="comma-separated, from: " + ", ".join(CONFIGS)
                             + " (default: all of them; hard: undertow)")
    args = parser.parse_args(argv)
    hard = args.suite == "hard"
    args.count = args.count or (hard_suite.COUNT if hard else COUNT)
    args.seed = args.seed if args.seed is not None else hard_suite.SEED if hard else SEED
    args.configs = args.configs or ("undertow" if hard else ",".join(CONFIGS))
    categories = tuple(c.strip() for c in args.categories.split(",") if c.strip())
    wrong = [c for c in categories
             if c not in (*hard_suite.CATEGORIES, *hard_suite.EXTRA_CATEGORIES)]
    if categories and not hard:
        parser.error("--categories: only with --suite hard")
    if wrong:
        parser.error(f"--categories: unknown: {', '.join(wrong)}")
    if args.cap is not None:
        set_cap(args.cap)
    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    started = time.perf_counter()
    note = harness.machine_note()
    rows = []
    unknown = [c for c in configs if c not in CONFIGS]
    if unknown:
        parser.error(f"unknown configuration(s): {', '.join(unknown)}")
    skipped = {c: why for c in configs if (why := missing(c))}
    for config, why in skipped.items():
        print(f"skipping {config}: {why}", flush=True)
    configs = [c for c in configs if c not in skipped]
    chosen = len(suite_tasks(args.suite, args.count, args.seed, categories))
    for config in configs:
        print(f"running {config} on {chosen} tasks ...", flush=True)
        try:
            rows += _run(config, args.count, args.seed, args.suite, categories, args.cap)
        except RuntimeError as exc:  # a configuration that hangs or crashes: the rest stand
            print(f"{exc}", flush=True)
            skipped[config] = f"its run ended without results ({exc})"
    configs = [c for c in configs if c not in skipped]
    if hard:
        return report_hard(args, argv, configs, rows, skipped, started, note)
    own = args.seed == SEED
    csv = "suite.csv" if own else f"suite-seed-{args.seed}.csv"
    kept: list[dict] = []
    if args.merge and (harness.RESULTS / csv).exists():
        kept = [r for r in harness.read_csv(harness.RESULTS / csv) if r["config"] not in configs]
        rows = [r for r in kept if r["config"] in CONFIGS] + rows
        configs = [c for c in CONFIGS if c in {r["config"] for r in rows}]
    harness.write_csv(harness.RESULTS / csv, rows)
    summary = [_summary(rows, c) for c in configs]
    ours = next((r for r in summary if r["config"] == "undertow"), None)
    ratios = [f"{r['config']}: {r['median_all'] / ours['median_all']:.1f}x"
              for r in summary if ours and r is not ours and isinstance(r["median_all"], float)
              and isinstance(ours["median_all"], float)]
    if own:
        _plot(rows, configs)
    text = "\n\n".join(part for part in [
        f"{args.count} rest-to-rest tasks of `testbed.suites.ordinary` (seed {args.seed}): "
        "2, 3 and 4 links, every passive/active split with at least as many active as "
        "passive joints, waves on about half of the active joints, g = 0 and g = 9.81 in "
        "turn, moves of up to 0.6 rad per joint across a waveless singularity where M_pa is "
        "square; 2 s, "
        "|tau| <= 20 N m, effort objective. A plan is verified when its solver succeeded and "
        "every interval, re-integrated from the plan's own state with the torque its "
        "transcription delivers, lands within 1e-3 rad, within the same cap of "
        f"{WALL_TIME:g} s a task (a peer's task still running {PEER_GRACE:g} s past it, opty's "
        f"{OPTY_GRACE:g} s, is stopped: fatrop has no wall-time option); time to a verified "
        "plan is the wall time of the whole plan, counted for verified plans only. Peers: the "
        "Opti script (bench/peers/opti.py), "
        "rockit (bench/peers/rockit.py; its states between the nodes as rockit samples "
        "them), opty (bench/peers/opty.py; its states cubic Hermite between the nodes).",
        "".join(f"Not run here: {c}, {why}. " for c, why in skipped.items()).strip(),
        ("Rows of " + ", ".join(sorted({r["config"] for r in kept})) + " come from an earlier "
         "invocation on the same tasks, kept by `--merge`." if kept else ""),
        harness.table(summary, [("config", "configuration"), ("what", "settings"),
                                ("tasks", "tasks"), ("verified", "verified"),
                                ("share", "share"),
                                ("median_time", "median time to a verified plan [s]"),
                                ("median_all", "the same, unverified counted as never [s]"),
                                ("p90_time", "90th percentile [s]"),
                                ("median_iterations", "median iterations"),
                                ("median_solves", "median solves")]),
        ("Median time to a verified plan (unverified counted as never) against the default "
         "planner's: " + "; ".join(ratios) + "." if ratios else ""),
        "![Share of the suite verified within a time](img/suite.png)" if own else "",
        "Per task, the default planner: the interval error is what `verified` judges; the "
        "open-loop replay runs the delivered torque from the planned start over the whole "
        "horizon, the growth factor is the largest norm of the state transition matrix "
        "along the plan, and the closed-loop replays add the plan's LQR feedback, from the "
        "planned start and from one perturbed by 1e-3 on every angle and rate.",
        limits_and_robustness(rows),
        _task_table(rows),
        args.note,
        f"Rows: `bench/results/{csv}`. {harness.manifest('suite', argv, started, note)}"]
        if part)
    harness.write_section(DOC, SECTION if own else f"{SECTION}, seed {args.seed}", text)
    for row in summary:
        print(row)
    return 0


# --------------------------------------------------------------------------- the hard suite


def nearest_rank(values: list[float], share: float) -> float:
    """The nearest-rank percentile (share in (0, 1]) of values; inf (never) counts."""
    ordered = sorted(values)
    return ordered[max(math.ceil(share * len(ordered)) - 1, 0)] if ordered else math.nan


def _never(value: float) -> float | str:
    return "never" if math.isinf(value) else value


def hard_summary(rows: list[dict], config: str, key: str = "config") -> dict:
    """Of a configuration's (or category's, `key`) rows: the share verified; the median,
    90th percentile and maximum time to a verified plan with unverified tasks counted as
    never, the median over the verified ones; median iterations, restoration iterations,
    factorizations and CPU time; KKT factorizations per iteration (`per_iteration`); the
    median time to a plan the solver accepted (verified or not)."""
    mine = [r for r in rows if r[key] == config]
    verified = sum(bool(r["verified"]) for r in mine)
    every = [r["time_to_verified"] if r["verified"] else math.inf for r in mine]
    plans = [r["time_to_plan"] if math.isfinite(r["time_to_plan"]) else math.inf for r in mine]
    return {key: config, "tasks": len(mine), "verified": verified,
            "share": f"{100 * verified / len(mine):.0f} %" if mine else "–",
            "median_verified": harness.median([r["time_to_verified"] for r in mine
                                               if r["verified"]]),
            "median_all": _never(nearest_rank(every, 0.5)),
            "p90_all": _never(nearest_rank(every, 0.9)),
            "max_all": _never(max(every, default=math.nan)),
            "median_plan": _never(nearest_rank(plans, 0.5)),
            "median_iterations": harness.median([r["iterations"] for r in mine]),
            "median_restoration": harness.median([r["restoration"] for r in mine]),
            "median_factorizations": harness.median([r["factorizations"] for r in mine]),
            "per_iteration": per_iteration(mine),
            "median_cpu": harness.median([r["cpu"] for r in mine])}


_SUMMARY_COLUMNS = [("tasks", "tasks"), ("verified", "verified"), ("share", "share"),
                    ("median_all", "median time to a verified plan [s]"),
                    ("p90_all", "90th percentile [s]"), ("max_all", "max [s]"),
                    ("median_verified", "median of the verified [s]"),
                    ("median_plan", "median time to a plan the solver accepted [s]"),
                    ("median_iterations", "median iterations"),
                    ("median_restoration", "median restoration iterations"),
                    ("median_factorizations", "median KKT factorizations"),
                    ("per_iteration", "KKT factorizations per iteration"),
                    ("median_cpu", "median CPU [s]")]


def hard_task_table(rows: list[dict], configs: list[str]) -> str:
    """Per task and configuration: verdict, status and what the plan cost."""
    lines = [{**r, "ok": "yes" if r["verified"] else "no"}
             for config in configs for r in rows if r["config"] == config]
    return harness.table(lines, [
        ("task", "task"), ("config", "configuration"), ("ok", "verified"), ("status", "status"),
        ("iterations", "iterations"), ("restoration", "restoration iterations"),
        ("factorizations", "KKT factorizations"),
        ("logged_iterations", "iterations in the log"), ("solves", "solves"),
        ("cpu", "CPU [s]"), ("time", "wall [s]"), ("time_to_verified", "time to verified [s]"),
        ("local_error", "interval error [rad]"),
        ("robust_tracking_error", "mass ±10 %: tracking [rad]"),
        ("robust_final_error", "mass ±10 %: final, closed loop"),
        ("open_loop_final_error", "mass ±10 %: final, torque alone"),
        ("strategy", "strategy")])


def _finite(values) -> list[float]:
    """The finite numbers among values (None, or "" from a CSV cell, where a row has none)."""
    return [float(v) for v in values if v not in (None, "") and math.isfinite(float(v))]


def limits_and_robustness(rows: list[dict]) -> str:
    """A paragraph on the default planner's rows: the delivered torque against its limit on
    the succeeded plans, the latest return past the budget, and the robustness figures
    under UNCERTAINTY (medians and worst over the tasks that report them)."""
    ours = [r for r in rows if r["config"] == "undertow"]
    if not ours:
        return ""
    limited = [r for r in ours if _finite([r.get("torque_excess")])
               and r["status"] == "Solve_Succeeded" and r["verified"] in (True, "True")]
    excess = _finite(r["torque_excess"] for r in limited)
    late = _finite(r.get("past_budget") for r in ours)
    parts = []
    if limited:
        parts.append(f"Of the {len(limited)} verified plans with a torque limit, the delivered "
                     f"torque (its polynomial, exact extrema) exceeds the limit by at most "
                     f"{max(excess, default=0.0):.2g} of it (the verdict allows 1e-6)")
    if late:
        latest = max(late)
        parts.append(f"the latest plan returned {latest:.3g} s past its budget" if latest > 0
                     else f"every plan returned within its budget (the latest "
                          f"{-latest:.3g} s before it)")
    figures = {k: _finite(r.get(k) for r in ours) for k in
               ("robust_tracking_error", "robust_final_error", "open_loop_final_error")}
    if figures["robust_tracking_error"]:
        med = {k: harness.median(v) if v else math.nan for k, v in figures.items()}
        parts.append(
            f"with every link's mass 10 % off both ways (`task.uncertainty`, "
            f"`verification.robustness`, {len(figures['robust_tracking_error'])} tasks), "
            f"the plans' LQR feedback keeps the arm within a median "
            f"{med['robust_tracking_error']:.2g} rad of the plan (worst "
            f"{max(figures['robust_tracking_error']):.2g} rad) and ends a median "
            f"{med['robust_final_error']:.2g} from the goal (rad, rad/s; worst "
            f"{max(figures['robust_final_error']):.2g}), where the torque alone ends a "
            f"median {med['open_loop_final_error']:.2g} from it (worst "
            f"{max(figures['open_loop_final_error'], default=math.nan):.2g})")
    return ("; ".join(parts) + ".") if parts else ""


def report_hard(args, argv: list[str], configs: list[str], rows: list[dict],
                skipped: dict[str, str], started: float, note: str) -> int:
    """The hard suite's CSV and section of docs/benchmarks.md."""
    own = args.seed == hard_suite.SEED
    chosen = [c.strip() for c in args.categories.split(",") if c.strip()]
    extra = bool(chosen) and all(c in hard_suite.EXTRA_CATEGORIES for c in chosen)
    stem = f"hard-suite-{'-'.join(chosen)}" if extra else "hard-suite"
    csv = f"{stem}.csv" if own else f"{stem}-seed-{args.seed}.csv"
    kept: list[dict] = []
    if args.merge and (harness.RESULTS / csv).exists():
        ran = {(r["task"], r["config"]) for r in rows}
        earlier = harness.read_csv(harness.RESULTS / csv)
        kept = [r for r in earlier if (r["task"], r["config"]) not in ran
                and (r["config"] not in configs or chosen and not extra)]
        order = {r["task"]: k for k, r in enumerate(earlier)}
        rows = sorted([r for r in kept if r["config"] in CONFIGS] + rows,
                      key=lambda r: (list(CONFIGS).index(r["config"]),
                                     order.get(r["task"], len(order))))
        configs = [c for c in CONFIGS if c in {r["config"] for r in rows}]
    if not rows:
        print("no rows", flush=True)
        return 1
    harness.write_csv(harness.RESULTS / csv, rows)
    summary = [{**hard_summary(rows, c), "what": CONFIGS[c]} for c in configs]
    ours = [r for r in rows if r["config"] == "undertow"]
    kinds = list(dict.fromkeys(r["category"] for r in ours))
    by_kind = [hard_summary(ours, k, "category") for k in kinds]
    cap = f"{WALL_TIME:g} s" + (" (lowered by --cap)" if args.cap is not None else "")
    text = "\n\n".join(part for part in [
        f"{len({r['task'] for r in rows})} tasks of `testbed.suites.hard` (seed {args.seed}"
        + (f", categories {args.categories}" if args.categories else "") + "), every "
        f"configuration capped at {cap} a task. Time to a verified plan is the wall time of "
        "the whole plan, unverified tasks counted as never in the median, 90th percentile "
        "(nearest rank) and maximum. Iterations are Ipopt's over every solve of a plan; "
        "restoration iterations and KKT factorizations (the trial factorizations of every "
        "search direction and the least-squares multiplier estimates) are counted in Ipopt's "
        f"log at print level {LOG_LEVEL}, which holds the companion process's solves too, "
        "and factorizations per iteration divide by that log's own iterations (`log_counts`); "
        "CPU is this process's and its children's. Peers "
        "run only the tasks they can state (fixed duration, state to state, effort), a "
        "planner configuration the tasks its settings can state (fatrop: no free time or "
        "co-design); fatrop writes no log to count in.",
        "".join(f"Not run here: {c}, {why}. " for c, why in skipped.items()).strip(),
        (f"Only the tasks of {', '.join(chosen)} ran in this invocation; the other rows come "
         "from an earlier one on the same tasks, kept by `--merge`." if kept and chosen
         and not extra else
         "Rows of " + ", ".join(sorted({r["config"] for r in kept})) + " come from an earlier "
         "invocation on the same tasks, kept by `--merge`." if kept else ""),
        harness.table(summary, [("config", "configuration"), ("what", "settings"),
                                *_SUMMARY_COLUMNS]),
        "The default planner by category:" if by_kind else "",
        harness.table(by_kind, [("category", "category"), *_SUMMARY_COLUMNS]) if by_kind else "",
        limits_and_robustness(rows),
        hard_task_table(rows, configs),
        args.note,
        f"Rows: `bench/results/{csv}`. {harness.manifest('suite', argv, started, note)}"]
        if part)
    section = f"Hard suite: {', '.join(chosen)}" if extra else HARD_SECTION
    heading = section if own else f"{section}, seed {args.seed}"
    harness.write_section(DOC, heading, text)
    for row in summary:
        print(row, flush=True)
    for row in by_kind:
        print(row, flush=True)
    return 0
