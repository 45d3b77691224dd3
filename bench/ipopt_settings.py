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

    python -m bench ipopt_settings [--repeats 3]
        [--scenes seed-hang:100,seed-hang:50,seed-4:100,seed-4:50,under-2:50,arm-2:50]
"""

from __future__ import annotations

import argparse
import time

from bench import harness
from bench.scenes import make_scene
from planner.ocp import plan
from planner.ocp.problem import ProblemKey, problem
from planner.ocp.solvers.ipopt import IPOPT_OPTIONS

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


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench ipopt_settings", description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", default=SCENES, help="scene:N, comma-separated")
    args = parser.parse_args(argv)
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
