"""Ipopt settings of the planner: MUMPS' ordering and scaling, the barrier update.

For each reference scene and each variant of `planner.ocp.solvers.ipopt.IPOPT_OPTIONS`
(`mumps_pivot_order`: Ipopt's automatic choice, AMD, PORD, METIS; `mumps_scaling`:
MUMPS' automatic choice (77) or none (0); `mu_strategy`: adaptive or monotone; the
adaptive update's `mu_oracle`: quality-function or probing), the NLP is built with those
settings and solved `--repeats` times from the interpolation guess, one solve per plan
(refinement and retries off: the same iterates every time, only the timing varies).
Reported: iterations, status, median solve wall time, the median of "Ipopt itself" per
iteration (solve time less CasADi's function evaluations: KKT factorizations,
back-solves, line search), function evaluations per iteration, objective, interval error
and open-loop replay error.

Settings change rounding and steps, so on the hard underactuated scenes Ipopt can take
another path to another optimum; the table shows both the cost and where each ends.
Writes docs/benchmarks.md section "Ipopt settings" and bench/results/ipopt_settings.csv.

`--inertia` measures instead how Ipopt corrects the inertia of the KKT matrix: hard-suite
tasks (`INERTIA_TASKS`: two or three of every category of `testbed.suites.hard`), each
planned once with each variant of `INERTIA_VARIANTS` (the idle variable, Ipopt's
perturbation settings, its inertia-free curvature test, CasADi's convexification of the
Hessian, a Hessian of the objective alone), one process per plan (no companion: its solves
would race the plan's own). Counted in Ipopt's log (`bench.suite.log_counts`): iterations
and KKT factorizations; reported per variant with the plans verified. Writes section "Ipopt
settings: inertia corrections" and bench/results/ipopt_inertia.csv.

    python -m bench ipopt_settings [--repeats 3]
        [--scenes seed-hang:100,seed-hang:50,seed-4:100,seed-4:50,under-2:50,arm-2:50]
    python -m bench ipopt_settings --inertia [--variants NAME,...] [--tasks TASK,...]
        [--cap 60] [--merge]
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import casadi as ca

from bench import harness, suite
from bench.scenes import make_scene
from planner.ocp import plan, stages
from planner.ocp.assembly import Blocks, Derivatives, Kernels
from planner.ocp.portfolio import ENVIRONMENT
from planner.ocp.problem import ProblemKey, cached_problem, problem
from planner.ocp.solvers.ipopt import INERTIA_OPTIONS, IPOPT, IPOPT_OPTIONS
from planner.scene import Scene
from testbed.suites import hard as hard_suite

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Ipopt settings"
ORDERINGS = {"automatic": 7, "AMD": 0, "PORD": 4, "METIS": 5}
SCALINGS = {"automatic": 77, "none": 0}
VARIANTS = [("automatic", "automatic", "adaptive", "quality-function"),
            ("AMD", "automatic", "adaptive", "quality-function"),
            ("PORD", "automatic", "adaptive", "quality-function"),
            ("METIS", "automatic", "adaptive", "quality-function"),
            ("automatic", "automatic", "monotone", "–"),
            ("AMD", "automatic", "monotone", "–"),
            ("AMD", "none", "adaptive", "quality-function"),
            ("AMD", "automatic", "adaptive", "probing"),
            ("AMD", "none", "adaptive", "probing")]
"""(ordering, scaling, barrier update, oracle of the adaptive update)"""
SCENES = "seed-hang:100,seed-hang:50,seed-4:100,seed-4:50,under-2:50,arm-2:50"
FUNCTIONS = ("t_wall_nlp_hess_l", "t_wall_nlp_jac_g", "t_wall_nlp_g", "t_wall_nlp_grad_f",
             "t_wall_nlp_f", "t_wall_callback_fun")
COLUMNS = [("scene", "scene"), ("N", "N"), ("ordering", "ordering"), ("scaling", "scaling"),
           ("mu", "barrier"), ("oracle", "oracle"),
           ("status", "status"), ("iterations", "iterations"), ("solve", "solve [s]"),
           ("ipopt_per_iteration", "Ipopt itself per iteration [ms]"),
           ("functions_per_iteration", "functions per iteration [ms]"),
           ("objective", "objective"), ("interval_error", "interval error [rad]"),
           ("replay_error", "open-loop replay [rad]")]


def measure(name: str, N: int, variant: tuple[str, str, str, str], repeats: int) -> dict:
    """Solve one scene `repeats` times with one variant; the row of medians."""
    ordering, scaling, mu, oracle = variant
    options = {"mumps_pivot_order": ORDERINGS[ordering], "mumps_scaling": SCALINGS[scaling],
               "mu_strategy": mu}
    if mu == "adaptive":
        options["mu_oracle"] = oracle
    scene = make_scene(name, N=N, one_solve=True,
                       solver={"max_iter": 500, "max_wall_time": 120.0})
    with harness.ipopt_options(options):
        prob = problem(ProblemKey.of(scene))
        solves, own, funcs = [], [], []
        for _ in range(repeats):
            result = plan(scene)
            stats = prob.solver.stats()
            spent = sum(float(stats.get(k, 0.0)) for k in FUNCTIONS)
            its = max(1, result.solver.iterations)
            solves.append(result.solver.solve_time)
            own.append(1e3 * (result.solver.solve_time - spent) / its)
            funcs.append(1e3 * spent / its)
    v = result.verification
    return {"scene": name, "N": N, "ordering": ordering, "scaling": scaling, "mu": mu,
            "oracle": oracle,
            "status": result.solver.status, "iterations": result.solver.iterations,
            "solve": harness.median(solves), "ipopt_per_iteration": harness.median(own),
            "functions_per_iteration": harness.median(funcs), "objective": result.objective,
            "interval_error": v.local_error, "replay_error": v.resimulation_error,
            "runs": repeats, "load": harness.load()}


# --------------------------------------------------------------------------- inertia


@dataclass(frozen=True)
class Inertia:
    """A way to correct the inertia of the KKT matrix: Ipopt `options` (beside
    `bench.suite.IPOPT_INERTIA`, Ipopt's own), the idle variable or not, CasADi's options of
    its Ipopt plugin (`plugin`: its convexification of the Hessian), the Hessian of the
    objective alone (`objective_hessian`)."""

    options: dict = field(default_factory=dict)
    idle: bool = False
    plugin: dict = field(default_factory=dict)
    objective_hessian: bool = False

    def settings(self) -> str:
        """What it sets, in words."""
        parts = [f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}"
                 for k, v in {**self.options, **self.plugin}.items()]
        parts += ["idle variable"] if self.idle else []
        parts += ["Hessian of the objective alone"] if self.objective_hessian else []
        return ", ".join(parts) or "Ipopt's own"


DEFAULT = "idle 1/2 x4 1e-8"
"""The variant compared task by task with Ipopt's own (the planner's setting): the idle
variable with `planner.ocp.solvers.ipopt.INERTIA_OPTIONS`."""
INERTIA_VARIANTS = {
    "Ipopt's own": Inertia(),
    "1/2 x4 1e-8": Inertia(dict(INERTIA_OPTIONS)),
    "curvature test 1e-12": Inertia({"neg_curv_test_tol": 1e-12}),
    "curvature test 1e-6": Inertia({"neg_curv_test_tol": 1e-6}),
    "always perturb rows": Inertia({"perturb_always_cd": "yes"}),
    "MUMPS pivtol 1e-4": Inertia({"mumps_pivtol": 1e-4}),
    "eigen-clip": Inertia(plugin={"convexify_strategy": "eigen-clip"}),
    "eigen-reflect 1e5": Inertia(plugin={"convexify_strategy": "eigen-reflect",
                                         "max_iter_eig": 100000}),
    "regularize": Inertia(plugin={"convexify_strategy": "regularize"}),
    "objective Hessian": Inertia(objective_hessian=True),
    "idle": Inertia(idle=True),
    "idle 1/2 x4": Inertia({"perturb_dec_fact": 0.5, "perturb_inc_fact": 4.0}, idle=True),
    DEFAULT: Inertia(dict(INERTIA_OPTIONS), idle=True),
    "idle 0.6 x4": Inertia({"perturb_dec_fact": 0.6, "perturb_inc_fact": 4.0}, idle=True),
}
"""The variants, by name: "1/2 x4 1e-8" is perturb_dec_fact 1/2, perturb_inc_fact 4,
first_hessian_perturbation 1e-8 (`planner.ocp.solvers.ipopt.INERTIA_OPTIONS`)."""
INERTIA_TASKS = ",".join([
    "seed-g0-cross-12", "seed-g0-cross-33", "seed-g9.81-cross-01", "seed-g9.81-cross-13",
    "seed-swing-02", "seed-swing-38", "links-5to8-15", "links-5to8-39", "torque-limit-16",
    "torque-limit-40", "free-time-05", "free-time-41", "tip-target-06", "tip-target-30",
    "bounds-19", "bounds-43", "co-design-32"])
"""Tasks of `testbed.suites.hard` (its own seed), two of every category but co-design, of
which one (its plans take up to a minute and none verifies)."""
INERTIA_SECTION = "Ipopt settings: inertia corrections"


@contextlib.contextmanager
def plugin_options(options: dict) -> Iterator[None]:
    """NLPs built within get CasADi's options of its Ipopt plugin `options` too."""
    own = IPOPT.options
    IPOPT.options = lambda nlp: {**own(nlp), **options}  # type: ignore[method-assign]
    cached_problem.cache_clear()
    try:
        yield
    finally:
        del IPOPT.options
        cached_problem.cache_clear()


def _objective_only(blocks: Blocks) -> Blocks:
    """The kernels with the Hessian of the cost alone (the rows' multipliers zero)."""
    hess = blocks.hess
    ins = [ca.SX.sym(hess.name_in(i), hess.sparsity_in(i)) for i in range(hess.n_in())]
    out = hess(*ins[:-1], ca.SX.zeros(ins[-1].sparsity()))
    return replace(blocks, hess=ca.Function(hess.name(), ins, [out]))


@contextlib.contextmanager
def objective_hessian() -> Iterator[None]:
    """NLPs built within have the Hessian of the objective alone (a Gauss-Newton Hessian,
    positive semidefinite where the objective is convex) in place of the Lagrangian's."""
    own = stages.derivatives

    def derivatives(kernels: Kernels) -> Derivatives | None:
        found = own(kernels)
        return None if found is None else Derivatives(_objective_only(found.stage),
                                                      _objective_only(found.terminal))

    stages.derivatives = derivatives
    stages.stages.cache_clear()
    cached_problem.cache_clear()
    try:
        yield
    finally:
        stages.derivatives = own
        stages.stages.cache_clear()
        cached_problem.cache_clear()


@contextlib.contextmanager
def inertia(variant: Inertia) -> Iterator[None]:
    """NLPs built within correct the inertia as `variant` does, their Ipopt logging at
    `bench.suite.LOG_LEVEL`."""
    with contextlib.ExitStack() as stack:
        options = {"print_level": suite.LOG_LEVEL, **suite.IPOPT_INERTIA, **variant.options}
        stack.enter_context(harness.ipopt_options(options, variant.idle))
        if variant.plugin:
            stack.enter_context(plugin_options(variant.plugin))
        if variant.objective_hessian:
            stack.enter_context(objective_hessian())
        yield


def inertia_row(name: str, scene: Scene, variant: str) -> dict:
    """Plan one task under the variant in force: verdict and what Ipopt's log counts (a
    plan that raises has its error as status and no counts)."""
    started = time.perf_counter()
    try:
        with suite.solver_log() as log:
            result = plan(scene)
    except RuntimeError as exc:
        return {"variant": variant, "task": name, "category": hard_suite.category(name),
                "verified": False, "status": "error: " + str(exc).strip().splitlines()[-1],
                "iterations": 0, "restoration": math.nan, "factorizations": math.nan,
                "logged_iterations": math.nan, "time": time.perf_counter() - started}
    s = result.solver
    return {"variant": variant, "task": name, "category": hard_suite.category(name),
            "verified": bool(s.success and result.verification.verified), "status": s.status,
            "iterations": s.iterations, **suite.log_counts(log(), s.iterations),
            "time": time.perf_counter() - started, "load": harness.load()}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench ipopt_settings", description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", default=SCENES, help="scene:N, comma-separated")
    parser.add_argument("--inertia", action="store_true",
                        help="the inertia corrections on hard-suite tasks instead")
    parser.add_argument("--variants", default=",".join(INERTIA_VARIANTS),
                        help="--inertia: comma-separated, from: " + ", ".join(INERTIA_VARIANTS))
    parser.add_argument("--tasks", default=INERTIA_TASKS,
                        help="--inertia: hard-suite tasks, comma-separated")
    parser.add_argument("--cap", type=float, default=None,
                        help="--inertia: every plan's wall-time cap [s] (default: the task's)")
    parser.add_argument("--merge", action="store_true",
                        help="--inertia: keep the other variants' rows of the CSV")
    args = parser.parse_args(argv)
    if args.inertia:
        return inertia_main(args, argv)
    started, note = time.perf_counter(), harness.machine_note()
    default = dict(IPOPT_OPTIONS)
    rows = []
    for spec in args.scenes.split(","):
        name, N = spec.split(":")
        for variant in VARIANTS:
            rows.append(measure(name, int(N), variant, args.repeats))
            print(harness.table(rows[-1:], COLUMNS), flush=True)
    harness.write_csv(harness.RESULTS / "ipopt_settings.csv", rows)
    text = "\n\n".join([
        ("Legendre 3, interpolation guess, one solve per plan (refinement and retries off), "
         f"at most 500 iterations and 120 s; `solve` is the median Ipopt wall time of "
         f"{args.repeats} solves, the per-iteration columns split it into CasADi's function "
         "evaluations and Ipopt's own work (KKT factorizations, back-solves, line search). "
         f"The planner's setting when measured: {default}. Load averages in the CSV."),
        harness.table(rows, COLUMNS),
        f"Rows: `bench/results/ipopt_settings.csv`. "
        f"{harness.manifest('ipopt_settings', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0


def inertia_tasks(names: list[str], cap: float | None) -> list[tuple[str, Scene]]:
    """The named tasks of the hard suite's own seed as the suite states them (its model
    error to report robustness under), with `cap` [s] as their wall-time cap if given."""
    categories = tuple(dict.fromkeys(hard_suite.category(n) for n in names))
    found = dict(suite.suite_tasks("hard", hard_suite.COUNT, hard_suite.SEED, categories))
    out = []
    for name in names:
        scene = suite.with_uncertainty(found[name].model_dump(mode="json"))
        if cap is not None:
            scene["solver"] = {**scene["solver"], "max_wall_time": cap}
        out.append((name, Scene.model_validate(scene)))
    return out


def inertia_summary(rows: list[dict], variant: str, base: dict) -> dict:
    """A variant's totals over its tasks, its factorizations and iterations against `base`'s
    (Ipopt's own) where the counts exist."""
    mine = [r for r in rows if r["variant"] == variant]
    counted = [r for r in mine if math.isfinite(float(r["factorizations"]))]
    fact = sum(int(r["factorizations"]) for r in counted)
    its = sum(int(r["logged_iterations"]) for r in counted)
    failed = sorted({r["status"] for r in mine if not r["verified"]})
    return {"variant": variant, "settings": INERTIA_VARIANTS[variant].settings(),
            "tasks": len(mine), "verified": sum(bool(r["verified"]) for r in mine),
            "iterations": its, "factorizations": fact,
            "per_iteration": suite.per_iteration(counted),
            "fact_ratio": fact / base["factorizations"] if base.get("factorizations") else math.nan,
            "it_ratio": its / base["iterations"] if base.get("iterations") else math.nan,
            "failures": "; ".join(failed) or "–"}


INERTIA_COLUMNS = [("variant", "variant"), ("settings", "settings"), ("tasks", "tasks"),
                   ("verified", "verified"), ("iterations", "iterations"),
                   ("factorizations", "KKT factorizations"),
                   ("per_iteration", "factorizations per iteration"),
                   ("fact_ratio", "factorizations / Ipopt's own"),
                   ("it_ratio", "iterations / Ipopt's own"),
                   ("failures", "status of the unverified")]


def inertia_text(rows: list[dict], argv: list[str], started: float, note: str) -> str:
    """The section: what ran, the table of variants, and the default's tasks beside Ipopt's
    own."""
    variants = [v for v in INERTIA_VARIANTS if any(r["variant"] == v for r in rows)]
    base = inertia_summary(rows, "Ipopt's own", {}) if "Ipopt's own" in variants else {}
    table = [inertia_summary(rows, v, base) for v in variants]
    pair = [{**r, "ok": "yes" if r["verified"] else "no"} for r in rows
            if r["variant"] in ("Ipopt's own", DEFAULT)]
    tasks = harness.table(sorted(pair, key=lambda r: r["task"]), [
        ("task", "task"), ("variant", "variant"), ("ok", "verified"),
        ("status", "status"), ("logged_iterations", "iterations"),
        ("factorizations", "KKT factorizations"), ("restoration", "restoration iterations")])
    return "\n\n".join([
        f"{len({r['task'] for r in rows})} tasks of `testbed.suites.hard` (seed "
        f"{hard_suite.SEED}), each planned once per variant in one process (no companion), "
        "Ipopt's log at print level "
        f"{suite.LOG_LEVEL}: iterations are the log's (every solve of the plan), KKT "
        "factorizations the trial factorizations of every search direction and the "
        "least-squares multiplier estimates; per iteration is their ratio over the tasks "
        "with a log. Every variant sets Ipopt's perturbation settings to Ipopt's own but "
        "where it says otherwise; Ipopt's own is the planner's setting. Counts, not times: "
        "a plan's time only decides where a capped plan stops (the co-design task). "
        "Load averages in the CSV.",
        harness.table(table, INERTIA_COLUMNS),
        f"Task by task, Ipopt's own against `{DEFAULT}`:", tasks,
        f"Rows: `bench/results/ipopt_inertia.csv`. "
        f"{harness.manifest('ipopt_settings', argv, started, note)}"])


def inertia_main(args: argparse.Namespace, argv: list[str]) -> int:
    """`--inertia`: every variant on every task, the CSV and the section."""
    started, note = time.perf_counter(), harness.machine_note()
    os.environ[ENVIRONMENT] = "1"
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in INERTIA_VARIANTS]
    if unknown:
        raise SystemExit(f"unknown variant(s): {', '.join(unknown)}")
    tasks = inertia_tasks([t.strip() for t in args.tasks.split(",") if t.strip()], args.cap)
    rows = []
    for variant in names:
        with inertia(INERTIA_VARIANTS[variant]):
            for name, scene in tasks:
                rows.append(inertia_row(name, scene, variant))
                print(rows[-1], flush=True)
    path = harness.RESULTS / "ipopt_inertia.csv"
    if args.merge and path.exists():
        rows = [r for r in harness.read_csv(path) if r["variant"] not in names] + rows
        rows.sort(key=lambda r: list(INERTIA_VARIANTS).index(r["variant"]))
    harness.write_csv(path, rows)
    text = inertia_text(rows, argv, started, note)
    harness.write_section(DOC, INERTIA_SECTION, text)
    print(text)
    return 0
