"""The small mode of every benchmark: `python -m bench NAME --smoke`.

A smoke run is the benchmark's own `main` on its smallest inputs (one task, few intervals,
one try, a short budget: the arguments of `SMALL`), once per way the benchmark runs, with
every output written under a temporary folder (or `--out DIR`) instead of docs/ and
bench/results/ (`bench.harness.outputs_to`), so that it never overwrites a committed
result. tests/test_benches.py runs every benchmark's smoke run.
"""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bench import harness


@dataclass(frozen=True)
class Small:
    """A benchmark's small mode: the arguments of each of its runs (one per way the
    benchmark runs), the environment they run in, and what they need of the machine
    (`NEEDS`)."""

    runs: tuple[tuple[str, ...], ...]
    needs: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)


SMALL: dict[str, Small] = {
    "blas_threads": Small((("--count", "2", "--rounds", "2"),)),
    "build": Small((("--links", "2"),)),
    "closed_loop": Small((("--scenes", "two-link-plan", "--N", "20", "--updates", "5"),)),
    "capacity": Small((("--points", "1"),)),
    "session": Small((("--scene", "two-link-plan", "--N", "20", "--updates", "5"),)),
    "container": Small((("--plans", "1"),), needs=("docker",)),
    "dynamics_size": Small((("--calls", "2", "--repeats", "1", "--builds", "1"),)),
    "examples": Small((("--repeats", "1", "--examples", "two-link-plan"),)),
    "plan_list": Small((("--repeats", "1"),)),
    "adversarial": Small((("--count", "2"),)),
    "impossible": Small((("--seeds", "20261126", "--count", "1"),)),
    "iteration_cost": Small((("--N", "10", "--iterations", "3", "--repeats", "1"),)),
    "memory": Small((("--bases", "1", "--variants", "1", "--moves", "0.05"),)),
    "moved_goals": Small((("--variants", "1", "--examples", "two-link-plan"),)),
    "cluster_ops": Small((("--tries", "1", "--probes", "leases"),), needs=("postgres",)),
    "faults": Small((("--tries", "1", "--probes", "1"),
                     ("--postgres", "--tries", "1", "--probes", "1")), needs=("postgres",)),
    "fuzz": Small((("--max-examples", "1", "--phases", "fuzzing,stateful"),)),
    "globals_cost": Small((("--categories", "free-time", "--count", "6", "--repeats", "1",
                            "--before", "HEAD"),)),
    "initial_guess": Small((("--scenes", "under-2", "--grids", "3:10"),)),
    "ipopt_settings": Small((("--repeats", "1", "--scenes", "arm-2:10"),
                             ("--inertia", "--tasks", "free-time-41", "--cap", "20",
                              "--variants", "Ipopt's own,idle 1/2 x4 1e-8"))),
    "job_latency": Small((("--before", "HEAD", "--count", "1", "--repeats", "1"),)),
    "limits": Small((("--methods", "trapezoidal"),)),
    "passive_margin": Small((("--finals", "0:1.75", "--durations", "2"),)),
    "peer_opty": Small((("--scenes", "arm-2", "--nodes", "20", "--methods", "midpoint"),),
                       needs=("opty",)),
    "planner_internals": Small((("--repeats", "1", "--seed-N", "10"),)),
    "pickup": Small((("--plans", "1"),), needs=("postgres",)),
    "plan_response": Small((("--repeats", "1"),)),
    "planner_speed": Small((("--N", "10", "--repeats", "1", "--baseline-repeats", "1"),)),
    "refined_tails": Small((("--before", "HEAD", "--tasks", "torque-limit-28:31415926"),)),
    "refinement": Small((("--intervals", "20", "--seeds", "20261123", "--count", "1",
                          "--max-iter", "5"),)),
    "replan": Small((("--moves", "1", "--no-jit"),)),
    "reliability": Small(((),), env={"UNDERTOW_SYNC_WALL_TIME": "4",
                                     "UNDERTOW_READ_TIMEOUT": "1",
                                     "UNDERTOW_COMPUTE_WAIT": "0.5"}),
    "scale_out": Small((("--plans", "1", "--durations", "1"),), needs=("postgres",)),
    "scaling": Small((("--N", "10", "--links", "1"),)),
    "seed_errata": Small((("--states", "10", "--duration", "0.5"),)),
    "seed_iterations": Small((("--N", "10", "--coarse", "10", "--fine", "20"),)),
    "seed_variants": Small((("--scene", "seed-hang", "--variants", "1"),)),
    "service_load": Small((("--requests", "2", "--workers", "1"),)),
    "simulate_integrator": Small((("--sets", "random", "--duration", "0.5"),)),
    "singularities": Small(((),)),
    "stress": Small((("--sigmas", "1e-3", "--sweeps", "mass ratio", "--robots", "2",
                      "--examples", "1"),)),
    "sync_memory": Small((("--points", "1"),)),
    "suite": Small((("--count", "1", "--cap", "20", "--configs",
                     "undertow,refinement off,retries off,fatrop,before,Opti script,rockit,"
                     "rockit fatrop"),
                    ("--suite", "hard", "--count", "1", "--cap", "20"))),
    "verification": Small((("--repeats", "1", "--scenes", "seed-arm-plan", "--jit", "off"),
                           ("--parts", "suite", "--count", "1", "--before", "none",
                            "--variants", "uncertain"))),
    "time_vs_error": Small((("--scenes", "arm-2", "--warm", "--quick",
                             "--transcriptions", "legendre-3"),)),
    "test_times": Small((("--runs", "quiet,loaded", "--venv", sys.prefix,
                          "--pytest-args", "tests/test_certify.py"),)),
    "wave_certificates": Small((("--arms", "two-link"),)),
    "wave_aliasing": Small((("--tasks", "free-time-05:31415926", "--intervals", "10"),)),
}
"""Every benchmark's small mode, by its name in `bench.__main__.BENCHES`."""


def _docker() -> str | None:
    if shutil.which("docker") is None:
        return "no docker command"
    image = os.environ.get("UNDERTOW_IMAGE", "undertow:ci")
    found = subprocess.run(["docker", "image", "inspect", image], capture_output=True,
                           text=True, check=False)
    if found.returncode != 0:
        return (f"no docker image {image} (or no docker daemon): `bash .ci/docker` builds "
                f"it ({(found.stderr.strip().splitlines() or ['no output'])[-1][:120]})")
    return None


def _postgres() -> str | None:
    from testbed import postgres

    return postgres.missing()


def _opty() -> str | None:
    from bench import peer_opty

    if peer_opty.opty_ready():
        return None
    return (f"no opty virtualenv at {peer_opty.VENV} (`python -m bench peer_opty` makes "
            "it, with Debian's Ipopt development packages)")


NEEDS: dict[str, Callable[[], str | None]] = {
    "docker": _docker, "postgres": _postgres, "opty": _opty}
"""What a small mode may need of the machine: why it is missing here, or None."""


def missing(name: str) -> str | None:
    """Why the small mode of benchmark `name` cannot run on this machine, or None."""
    for need in SMALL[name].needs:
        why = NEEDS[need]()
        if why is not None:
            return f"bench {name} needs {need}: {why}"
    return None


def run(name: str, module: str, argv: Sequence[str], folder: Path | None) -> int:
    """The smoke run of benchmark `name` (whose module is `module`), `argv` after each
    run's own arguments, its outputs under `folder` (default: a new temporary folder):
    the first non-zero exit code of its runs, or 0."""
    small = SMALL.get(name)
    if small is None:
        print(f"{name} has no small mode", file=sys.stderr)
        return 2
    os.environ.update(small.env)  # before the import: a module may read its settings then
    main = importlib.import_module(module).main
    folder = folder or Path(tempfile.mkdtemp(prefix=f"undertow-smoke-{name}-"))
    with harness.outputs_to(folder):
        for arguments in small.runs:
            print(f"smoke: python -m bench {name} {' '.join(arguments + tuple(argv))}",
                  flush=True)
            code = main([*arguments, *argv]) or 0
            if code:
                return code
    print(f"smoke: outputs under {folder}", flush=True)
    return 0
