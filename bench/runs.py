"""When each benchmark last ran: the commit that last changed its committed results.

A benchmark's results are the files it writes under bench/results/ and docs/img/
(`RESULTS`, patterns relative to the checkout); a run is committed with them, and nothing
else changes them, so the last commit that touched them is the last committed run (a
moved document does not change it). A benchmark none of whose results is committed (it
writes a document section alone, or its results were never committed) ran last where its
section's manifest line, "Regenerate: `python -m bench NAME ...`", last changed.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from bench.harness import ROOT

RESULTS: dict[str, tuple[str, ...]] = {
    "build": ("bench/results/build.csv",),
    "blas_threads": ("bench/results/blas_threads.csv",),
    "capacity": ("bench/results/capacity.csv",),
    "closed_loop": ("bench/results/closed_loop.csv", "docs/img/closed_loop.png"),
    "cluster_ops": ("bench/results/cluster_ops.csv",),
    "container": ("bench/results/container.csv",),
    "session": ("bench/results/session.csv",),
    "dynamics_size": (),
    "examples": ("bench/results/examples.csv",),
    "plan_list": ("bench/results/plan_list.csv",),
    "adversarial": ("bench/results/adversarial.csv",),
    "impossible": ("bench/results/impossible.csv",),
    "iteration_cost": ("bench/results/iteration_cost.csv",),
    "memory": ("bench/results/memory.csv",),
    "moved_goals": ("bench/results/moved_goals.csv",),
    "faults": ("bench/results/faults.csv", "bench/results/faults_postgres.csv"),
    "fuzz": ("bench/results/fuzz.csv",),
    "globals_cost": ("bench/results/globals_cost.csv",),
    "initial_guess": ("bench/results/initial_guess.csv",),
    "ipopt_settings": ("bench/results/ipopt_settings.csv", "bench/results/ipopt_inertia.csv"),
    "job_latency": ("bench/results/job_latency.csv",),
    "limits": ("bench/results/limits.csv",),
    "passive_margin": ("bench/results/passive_margin.csv",),
    "peer_opty": ("bench/results/peer_opty.csv",),
    "planner_internals": ("bench/results/planner_internals_*.csv",),
    "pickup": ("bench/results/pickup.csv",),
    "plan_response": ("bench/results/plan_response.csv",),
    "planner_speed": ("bench/results/planner_speed*.csv",),
    "refined_tails": ("bench/results/refined_tails.csv",),
    "refinement": ("bench/results/refinement_*.csv",),
    "replan": ("bench/results/replan.csv",),
    "reliability": ("bench/results/reliability.csv",),
    "scale_out": (),
    "scaling": ("bench/results/scaling.csv", "docs/img/scaling_*.png"),
    "seed_errata": (),
    "seed_iterations": ("bench/results/seed_iterations.csv",),
    "seed_variants": ("bench/results/seed_variants*.csv",),
    "service_load": (),
    "simulate_integrator": (),
    "singularities": ("docs/img/singularity_*.png",),
    "stress": ("bench/results/stress_*.csv",),
    "sync_memory": ("bench/results/sync_memory.csv",),
    "suite": ("bench/results/suite*.csv", "bench/results/hard-suite*.csv",
              "docs/img/suite.png"),
    "verification": ("bench/results/verification.csv", "bench/results/verification_suite.csv"),
    "time_vs_error": ("bench/results/time_vs_error*.csv", "docs/img/pareto_*.png"),
    "test_times": ("bench/results/test_times.csv",),
    "wave_certificates": ("bench/results/wave_certificates.csv",),
    "wave_aliasing": ("bench/results/wave_aliasing.csv",),
}
"""Every benchmark's result files (glob patterns under the checkout), by its name in
`bench.__main__.BENCHES`; none for one that writes a document section alone."""


def _git_log(*args: str) -> str:
    """The last commit that `git log args` names, as "hash date", "" if none."""
    return subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h %as", *args],
                          check=False, capture_output=True, text=True).stdout.strip()


def committed(paths: list[Path]) -> str:
    """The last commit that changed any of `paths`: "hash date" ("uncommitted" if none)."""
    return (_git_log("--", *map(str, paths)) if paths else "") or "uncommitted"


def result_files(name: str) -> list[Path]:
    """The files of benchmark `name`'s results there are in the checkout."""
    return sorted({path for pattern in RESULTS[name] for path in ROOT.glob(pattern)})


def last_run(name: str) -> str:
    """The commit of benchmark `name`'s last committed run, as "hash date", or "never"."""
    files = result_files(name)
    found = _git_log("--", *map(str, files)) if files else ""
    return (found or _git_log("-G", f"Regenerate: `python -m bench {name}[ `]", "--", "docs")
            or "never")
