"""Which CVODES method `planner.simulate.simulate` should use: energy drift and CPU time.

Free motions (zero torque) of 5 s from a random state (angles uniform in [-pi, pi], rates
in [-2, 2] rad/s), 100 outputs, rtol = atol = 1e-12, through `simulate` itself, with
  - adams: Adams-Moulton with functional iteration (the default),
  - adams-newton: Adams-Moulton with Newton iteration (measured for comparison only),
  - bdf: BDF with Newton iteration (CVODES's default, used before).
Drift is max_t |E(t) - E(0)| / (T(0) + |V(0)|); CPU time is that of one simulate call
with its integrator already built. Robot sets (one seeded generator, drawn in this order):
  - random: the robots of tests/test_energy.py's sweep (`testbed.robots.random_robot`,
    1-8 links, g = 0 or 9.81, both rotational conventions, 2 each);
  - stiff: the same draws with every wave at frequency 20 and masses of 0.03 or 30 kg
    (ratio 1e3), 1-6 links;
  - stress: frequency 20, masses 0.03 or 30 kg, lengths log-uniform in 1e-2..10 m, 1-3 links.
`--sets` runs some of them only (the later ones then see other draws). Writes the section
"Free motions: energy drift and CPU time" of docs/bench-simulate.md.

    python -m bench simulate_integrator [--sets random,stiff,stress] [--duration 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Iterator
from typing import cast

import numpy as np

import planner.simulate as sim
from bench import harness
from planner.dynamics import Dynamics
from planner.model import Robot
from testbed.robots import random_robot, random_state

DOC = harness.DOCS / "bench-simulate.md"
SECTION = "Free motions: energy drift and CPU time"
OUTPUTS, TOL = 100, 1e-12
METHODS = ("adams", "adams-newton", "bdf")
ADAMS_NEWTON = {"linear_multistep_method": "adams", "nonlinear_solver_iteration": "newton"}
"""CVODES options of the comparison method, which `planner.simulate` does not offer."""


def drift(robot: Robot, q: list, dq: list) -> float:
    dyn = Dynamics(robot)
    energies = np.array([dyn.energy(a, b) for a, b in zip(q, dq, strict=True)])
    total = energies.sum(axis=1)
    return float(np.max(np.abs(total - total[0])) / (energies[0, 0] + abs(energies[0, 1])))


def measure(robot: Robot, x0: np.ndarray, method: str,
            duration: float) -> tuple[float | None, float]:
    """Drift (None if the integration failed) and CPU time [s] of one free motion of
    `duration` [s]."""
    zero = np.zeros((1, 1, len(robot.active)))

    def run(seconds: float) -> sim.Trajectory:
        # "adams-newton" is no sim.Method: main adds it to the methods simulate reads
        # (sim.METHODS) for this comparison only.
        return sim.simulate(robot, [0.0, seconds], zero, x0, OUTPUTS, TOL, TOL,
                            method=cast(sim.Method, method))

    run(1e-3)  # build the integrator
    start = time.process_time()
    trajectory = run(duration)
    elapsed = time.process_time() - start
    if trajectory.status != "completed":
        return None, elapsed
    return drift(robot, trajectory.q, trajectory.dq), elapsed


def heavy_light(rng: np.random.Generator, robot: Robot, lengths: bool) -> Robot:
    """The robot with waves at frequency 20, masses 0.03 or 30 kg, and optionally
    lengths log-uniform in 1e-2..10 m (amplitudes scaled along)."""
    doc = robot.model_dump()
    masses = rng.choice([0.03, 30.0], robot.n)
    if robot.n > 1:
        masses[rng.permutation(robot.n)[:2]] = [0.03, 30.0]
    for link, mass in zip(doc["links"], masses, strict=True):
        scale = 10 ** rng.uniform(-2, 1) / link["length"] if lengths else 1.0
        link["length"] *= scale
        link["mass"] = float(mass)
        link["inertia"] *= mass * scale**2
        if link["wave"]:
            link["wave"].update(amplitude=link["wave"]["amplitude"] * scale, frequency=20.0)
    return Robot.model_validate(doc)


def robots(rng: np.random.Generator, sizes: range, count: int,
           change: Callable[[Robot], Robot]) -> Iterator[Robot]:
    for n in sizes:
        for gravity in (0.0, 9.81):
            for rotational in ("cumulative", "absolute"):
                for _ in range(count):
                    yield change(random_robot(rng, n, gravity=gravity, rotational=rotational))


def sets(rng: np.random.Generator) -> dict[str, tuple[str, Iterator[Robot]]]:
    """Per set: its name in the table and its robots (drawn lazily from `rng`)."""
    return {
        "random": ("random (1-8 links)", robots(rng, range(1, 9), 2, lambda r: r)),
        "stiff": ("stiff-ish: frequency 20, mass ratio 1e3 (1-6 links)",
                  robots(rng, range(1, 7), 1, lambda r: heavy_light(rng, r, lengths=False))),
        "stress": ("stress: the above, lengths 1e-2..10 m (1-3 links)",
                   robots(rng, range(1, 4), 1, lambda r: heavy_light(rng, r, lengths=True))),
    }


def rows(name: str, results: dict[str, list[tuple[float | None, float]]]) -> list[str]:
    out = []
    bdf_time = sum(t for _, t in results["bdf"])
    for method in METHODS:
        done = [d for d, _ in results[method] if d is not None]
        cpu = sum(t for _, t in results[method])
        ratio = [t / b for (_, t), (_, b) in zip(results[method], results["bdf"], strict=True)
                 if b > 0]
        out.append(f"| {name} | {method} | {len(results[method])} | "
                   f"{len(results[method]) - len(done)} | {max(done):.1e} | "
                   f"{statistics.median(done):.1e} | {sum(d > 1e-8 for d in done)} | "
                   f"{cpu:.1f} | {cpu / bdf_time:.2f} | {statistics.median(ratio):.2f} |")
    return out


def per_robot_worst(results: dict[str, list[tuple[float | None, float]]]) -> tuple[int, int]:
    """How many robots adams drifts less than bdf on, out of how many both completed."""
    pairs = [(a, b) for (a, _), (b, _) in zip(results["adams"], results["bdf"], strict=True)
             if a is not None and b is not None]
    return sum(a < b for a, b in pairs), len(pairs)


def report(chosen: list[str], duration: float) -> str:
    rng = np.random.default_rng(20240611)
    lines = [("| robots | method | count | failed | max drift | median drift | drift > 1e-8 | "
              "CPU [s] | CPU / bdf | median per-robot CPU / bdf |"),
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    better = []
    for key, (name, drawn) in sets(rng).items():
        if key not in chosen:
            continue
        results: dict[str, list[tuple[float | None, float]]] = {m: [] for m in METHODS}
        for robot in drawn:
            q, dq = random_state(rng, robot.n)
            for method in METHODS:
                results[method].append(measure(robot, np.r_[q, dq], method, duration))
            print(name, robot.n, [f"{results[m][-1][0]}" for m in METHODS], flush=True)
        lines += rows(name, results)
        wins, total = per_robot_worst(results)
        better.append(f"- {name}: adams drifts less than bdf on {wins} of {total} robots.")
    return "\n".join([
        (f"Free motions (τ = 0) of {duration:g} s from random states through "
         "`planner.simulate.simulate` at rtol = atol = 1e-12, 100 outputs. Drift: "
         "max |E(t) − E(0)| / (T(0) + |V(0)|). CPU: process time of one `simulate` call, "
         "integrator already built. adams: Adams-Moulton, functional iteration (the "
         "default); adams-newton: Adams-Moulton, Newton iteration (comparison only); bdf: "
         "BDF, Newton iteration (CVODES's default, used before). The robot sets are those "
         "of `bench/simulate_integrator.py`'s docstring."),
        "", *lines, "", *better, "",
        ("The arm is conservative and oscillatory. BDF damps oscillations numerically, "
         "which shows as energy drift; Adams-Moulton does not, and drifts less on every "
         "robot above at a third to two thirds of the CPU time. Functional iteration never "
         "failed to converge (no robot is stiff in CVODES's sense) and is cheaper than "
         "Newton iteration, which buys no accuracy here. Hence `simulate` uses Adams with "
         'functional iteration; BDF stays available as `method="bdf"`. With frequency-20 '
         "waves and a mass ratio of 1e3, rtol = atol = 1e-12 holds the energy only to "
         "about 5e-8 with Adams (5e-7 for the worst stress robot; BDF: 2e-6 and 3e-6)."),
    ])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench simulate_integrator",
                                     description=__doc__)
    parser.add_argument("--sets", default="random,stiff,stress")
    parser.add_argument("--duration", type=float, default=5.0, help="[s] of each free motion")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    sim.METHODS.setdefault("adams-newton", ADAMS_NEWTON)
    text = report(args.sets.split(","), args.duration)
    harness.write_section(DOC, SECTION, "\n\n".join([
        text, harness.manifest("simulate_integrator", argv, started, note)]))
    print(text)
    return 0
