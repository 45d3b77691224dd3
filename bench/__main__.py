"""`python -m bench NAME [options]` runs the benchmark NAME; `python -m bench list` lists them
with the commit of each one's last committed run; `python -m bench headline` writes the
headline table of docs/benchmarks.md from the committed results.

Every benchmark also takes `--smoke` (its smallest inputs, outputs to a temporary folder:
`bench.smoke`) and `--out DIR` (its outputs under DIR instead of docs/ and bench/results/).
"""

from __future__ import annotations

import contextlib
import importlib
import sys

from bench import harness

BENCHES = {
    "blas_threads": ("bench.blas_threads", "two solver processes at once on the hard suite, "
                                           "the solver's OpenBLAS on one thread or on its "
                                           "own count"),
    "build": ("bench.build", "building an NLP against the number of links, now and at an "
                             "earlier commit"),
    "cluster_ops": ("bench.cluster_ops", "a PostgreSQL cluster through a 60 s database outage, "
                                         "mixed leases, requeues and a rolling upgrade"),
    "closed_loop": ("bench.closed_loop", "an arm heavier than its model and pushed: "
                                         "replanning at a fixed rate against LQR feedback "
                                         "alone"),
    "session": ("bench.session", "replanning through a service session: the round trip of "
                                 "each update, and the closed loop driven over HTTP"),
    "capacity": ("bench.capacity", "the memory of one plan's NLP against app/capacity.py's "
                                   "estimate"),
    "container": ("bench.container", "the container image: its size and a running container's "
                                     "memory, idle and after plans"),
    "dynamics_size": ("bench.dynamics_size", "the derived dynamics: expression size, build time "
                                             "and evaluation cost"),
    "examples": ("bench.examples", "the built-in plan examples, now and at an earlier commit"),
    "plan_list": ("bench.plan_list", "listing 100 plan jobs with large plans, decoding the "
                                     "plans or not"),
    "adversarial": ("bench.adversarial", "tasks drawn to make a verdict lie: verified plans "
                                         "checked against their task, infeasible verdicts "
                                         "challenged, evidence checked"),
    "impossible": ("bench.impossible", "tasks that cannot be done: how many end infeasible, "
                                       "how soon"),
    "iteration_cost": ("bench.iteration_cost", "CPU per iteration on the seed arm at N = 50 and "
                                               "100: Ipopt compiled and interpreted, fatrop, "
                                               "and an earlier commit"),
    "memory": ("bench.memory", "plans started from a neighbour's plan against the same plans "
                               "from scratch: time, and how often the optimum is the same"),
    "moved_goals": ("bench.moved_goals", "the built-in plan examples with their goals moved by "
                                         "up to 0.05 rad: how many verify, how fast"),
    "fuzz": ("bench.fuzz", "generated requests on every operation of a live server with a "
                           "solver worker: 5xx answers and dead workers"),
    "faults": ("bench.faults", "process and store faults against a live server: does an "
                               "accepted job get lost"),
    "globals_cost": ("bench.globals_cost", "CPU per iteration on the hard suite's co-design "
                                           "and free-time tasks, and at an earlier commit"),
    "initial_guess": ("bench.initial_guess", "interpolation against inverse-dynamics initial "
                                             "guesses on the underactuated scenes"),
    "ipopt_settings": ("bench.ipopt_settings", "MUMPS ordering and scaling and the barrier "
                                               "update: cost per iteration and where Ipopt ends"),
    "job_latency": ("bench.job_latency", "plan jobs through the service, submit to answer: "
                                         "what the service adds to the plan, now and before"),
    "limits": ("bench.limits", "torque limits held at the torque variables only against on "
                               "whole intervals, on time-optimal tasks"),
    "passive_margin": ("bench.passive_margin", "the two-link example with its end state and "
                                               "duration moved: how many plans verify"),
    "peer_opty": ("bench.peer_opty", "the planner against the Opti script and opty on the "
                                     "two-link scenes"),
    "planner_internals": ("bench.planner_internals", "the residual form, compiled against "
                                                     "interpreted NLPs, the seed arm's accuracy"),
    "pickup": ("bench.pickup", "submit-to-claim latency with an idle worker: LISTEN/NOTIFY on "
                               "PostgreSQL, the server's pipe and a node's poll on SQLite"),
    "plan_response": ("bench.plan_response", "where a GET of a finished plan job spends its "
                                             "time"),
    "planner_speed": ("bench.planner_speed", "the planner against a plain Opti script on a seed "
                                             "scene, and where a solve's time goes"),
    "refined_tails": ("bench.refined_tails", "the hard suite's slowest tasks solve by solve, "
                                             "now and at an earlier commit"),
    "refinement": ("bench.refinement", "mesh refinement on the two-link example at other "
                                       "numbers of intervals; what each retry recovers"),
    "replan": ("bench.replan", "warm replanning: a moved goal on the seed arm, warm against "
                               "cold, in the library and through the service"),
    "reliability": ("bench.reliability", "a live server under bad input, slow clients and long "
                                         "synchronous requests"),
    "scale_out": ("bench.scale_out", "plans per second with 1 and 2 worker nodes on one "
                                     "PostgreSQL, and a 50-member batch sweep"),
    "scaling": ("bench.scaling", "build time, solve time and memory against intervals and "
                                 "links"),
    "seed_errata": ("bench.seed_errata", "energy drift of the seed's printed equations and "
                                         "their misprinted terms"),
    "seed_iterations": ("bench.seed_iterations", "where the horizontal seed arm's Ipopt "
                                                 "iterations go (restoration)"),
    "seed_variants": ("bench.seed_variants", "a seed scene with its end states moved: how many "
                                             "plans verify"),
    "service_load": ("bench.service_load", "concurrent plan requests against a live server"),
    "simulate_integrator": ("bench.simulate_integrator", "CVODES methods for free motions: "
                                                         "energy drift and CPU time"),
    "singularities": ("bench.singularities", "the examples' inverse dynamics with and without "
                                             "waves, wave design, coupling analysis"),
    "stress": ("bench.stress", "near-singular starts, badly scaled and random robots, the "
                               "service under faults"),
    "sync_memory": ("bench.sync_memory", "the memory of one synchronous computation against "
                                         "app/sync_memory.py's estimate"),
    "suite": ("bench.suite", "the task suite: verified plans and time to a verified plan, "
                             "against refinement off, retries off and a plain Opti script"),
    "verification": ("bench.verification", "what a plan's checks cost, now and at an earlier "
                                           "commit"),
    "time_vs_error": ("bench.time_vs_error", "run time against error of every transcription "
                                             "on the reference scenes"),
    "test_times": ("bench.test_times", "make test from a fresh clone, quiet and with every "
                                       "core kept busy: passes, and its time"),
    "wave_certificates": ("bench.wave_certificates", "wave designs and co-designs proven along "
                                                     "their motions and over regions: bound, "
                                                     "boxes, time"),
    "wave_aliasing": ("bench.wave_aliasing", "the hard suite's slowest tasks on coarse "
                                             "meshes: interval errors against the wave's "
                                             "phase across an interval"),
}
"""Every benchmark: its module (with main(argv)) and what it measures."""


def listing() -> None:
    """Every benchmark: its name, the commit of its last committed run, what it measures."""
    from bench import runs

    width = max(map(len, BENCHES))
    for name, (_, what) in BENCHES.items():
        print(f"{name:<{width}}  {runs.last_run(name):<18}  {what}")


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("list", "-h", "--help"):
        if argv[:1] != ["list"]:
            print(__doc__)
        listing()
        return 0 if argv else 2
    name, (shared, rest) = argv[0], harness.shared_arguments(argv[1:])
    module = "bench.headline" if name == "headline" else BENCHES.get(name, ("",))[0]
    if not module:
        print(f"no benchmark called {name!r}; `python -m bench list` lists them", file=sys.stderr)
        return 2
    if shared.smoke:
        from bench import smoke

        return smoke.run(name, module, rest, shared.out)
    with harness.outputs_to(shared.out) if shared.out else contextlib.nullcontext():
        return importlib.import_module(module).main(rest) or 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
