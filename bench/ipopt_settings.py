"""Ipopt settings of the planner: MUMPS' ordering and scaling, the barrier update.

For each reference scene and each variant of `planner.ocp.problem.IPOPT_OPTIONS`
(`mumps_pivot_order`: Ipopt's automatic choice, AMD, PORD, METIS; `mumps_scaling`:
MUMPS' automatic choice (77) or none (0); `mu_strategy`: adaptive or monotone; the
adaptive update's `mu_oracle`: quality-function or probing), the NLP is built with those
settings and solved `--repeats` times from the interpolation guess (the same iterates
every time: only the timing varies). Reported:
iterations, status, median solve wall time, the median of "Ipopt itself" per iteration
(solve time less CasADi's function evaluations: KKT factorizations, back-solves, line
search), function evaluations per iteration, objective and re-simulation error.

Settings change rounding and steps, so on the hard underactuated scenes Ipopt can take
another path to another optimum; the table shows both the cost and where each ends.
Writes docs/benchmarks.md section "Ipopt settings" and bench/results/ipopt_settings.csv.

    .venv/bin/python bench/ipopt_settings.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (
    DOCS,
    RESULTS,
    load,
    machine_note,
    make_scene,
    median,
    table,
    write_csv,
    write_section,
)
from planner.ocp import plan
from planner.ocp import problem as problem_module
from planner.ocp.problem import ProblemKey, problem

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
SCENES = [("seed-hang", 100), ("seed-hang", 50), ("seed-4", 100), ("seed-4", 50),
          ("under-2", 50), ("arm-2", 50)]
FUNCTIONS = ("t_wall_nlp_hess_l", "t_wall_nlp_jac_g", "t_wall_nlp_g", "t_wall_nlp_grad_f",
             "t_wall_nlp_f", "t_wall_callback_fun")
COLUMNS = [("scene", "scene"), ("N", "N"), ("ordering", "ordering"), ("scaling", "scaling"),
           ("mu", "barrier"), ("oracle", "oracle"),
           ("status", "status"), ("iterations", "iterations"), ("solve", "solve [s]"),
           ("ipopt_per_iteration", "Ipopt itself per iteration [ms]"),
           ("functions_per_iteration", "functions per iteration [ms]"),
           ("objective", "objective"), ("error", "re-sim. error [rad]")]


def measure(name: str, N: int, variant: tuple[str, str, str, str], default: dict,
            repeats: int) -> dict:
    """Solve one scene `repeats` times with one variant; the row of medians."""
    ordering, scaling, mu, oracle = variant
    options = {**default, "mumps_pivot_order": ORDERINGS[ordering],
               "mumps_scaling": SCALINGS[scaling], "mu_strategy": mu}
    if mu == "adaptive":
        options["mu_oracle"] = oracle
    problem_module.IPOPT_OPTIONS.clear()
    problem_module.IPOPT_OPTIONS.update(options)
    problem.cache_clear()
    scene = make_scene(name, N=N, solver={"max_iter": 500, "max_wall_time": 120.0})
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
            "solve": median(solves), "ipopt_per_iteration": median(own),
            "functions_per_iteration": median(funcs), "objective": result.objective,
            "error": v.resimulation_error, "runs": repeats, "load": load()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    note, started = machine_note(), time.perf_counter()
    default = dict(problem_module.IPOPT_OPTIONS)
    rows = []
    for name, N in SCENES:
        for variant in VARIANTS:
            rows.append(measure(name, N, variant, default, args.repeats))
            print(table(rows[-1:], COLUMNS), flush=True)
    problem_module.IPOPT_OPTIONS.clear()
    problem_module.IPOPT_OPTIONS.update(default)
    command = ".venv/bin/python bench/ipopt_settings.py " + " ".join(sys.argv[1:])
    text = "\n\n".join([
        (f"Generated by `{command.strip()}` in {(time.perf_counter() - started) / 60:.0f} min "
         f"on {note}. Legendre 3, interpolation guess, at most 500 iterations and 120 s; "
         f"`solve` is the median Ipopt wall time of {args.repeats} solves, the per-iteration "
         "columns split it into CasADi's function evaluations and Ipopt's own work (KKT "
         "factorizations, back-solves, line search). The planner's setting when measured: "
         f"{default}. Load averages in the CSV."),
        table(rows, COLUMNS)])
    print(text)
    if not args.no_write:
        write_csv(RESULTS / "ipopt_settings.csv", rows)
        write_section(DOCS / "benchmarks.md", SECTION, text)


if __name__ == "__main__":
    main()
