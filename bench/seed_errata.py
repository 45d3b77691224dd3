"""Evidence for the misprints of the seed's (30)-(31): energy drift and term deviations.

The seed's 4-link arm (planner.examples.VERTICAL_SEED_ARM, g = 9.81) moves freely
(tau = 0) for 5 s from three seeded initial states, integrated by scipy's DOP853 at
rtol = atol = 1e-12 with M and h assembled from
  - the printed terms (testbed/seed_printed.py, every misprint in),
  - the printed terms with one misprint at a time (the other terms corrected),
  - the corrected terms (testbed.seed_printed.CORRECTED),
  - the library (planner.dynamics).
A correct model conserves E = T + V; the drift is max_t |E(t) - E(0)| / (T(0) + |V(0)|)
with E measured by the library, and a motion is stopped once its drift reaches 1.
Then each misprinted term's largest deviation from the derived value over `--states`
random configurations, printed and corrected. Writes the section "Energy drift and term
deviations" of docs/seed-errata-evidence.md.

    python -m bench seed_errata [--states 1000] [--duration 5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

from bench import harness
from planner.dynamics import Dynamics
from planner.examples import VERTICAL_SEED_ARM
from planner.model import Robot
from testbed import seed_printed as sp

DOC = harness.DOCS / "seed-errata-evidence.md"
SECTION = "Energy drift and term deviations"
TOL = 1e-12
Rhs = Callable[[np.ndarray], np.ndarray]


def term_rhs(arm: sp.Arm, use: Callable[[str], bool]) -> Rhs:
    """ddq from the printed terms, replacing by its corrected form each term where use(term)."""
    def terms(q1: np.ndarray) -> dict[str, float]:
        out = {**sp.printed_mass(arm, q1), **sp.printed_bias(arm, q1)}
        out.update({k: f(arm, q1) for k, f in sp.CORRECTED.items() if use(k)})
        return out

    def rhs(x: np.ndarray) -> np.ndarray:
        q1, dq1 = np.r_[0.0, x[:4]], np.r_[0.0, x[4:]]
        t = terms(q1)
        M = sp.mass_matrix({k: v for k, v in t.items() if k[0] == "M"})
        h = sp.bias_vector({k: v for k, v in t.items() if k[0] == "h"}, dq1)
        return np.r_[x[4:], np.linalg.solve(M, -h)]
    return rhs


def library_rhs(dyn: Dynamics) -> Rhs:
    tau = np.zeros(len(dyn.structure.active_idx))
    return lambda x: np.r_[x[4:], dyn.forward(x[:4], x[4:], tau)]


class _Diverged:
    """solve_ivp's event of a motion whose energy error reaches `scale` (a terminal one:
    the integration stops there)."""

    terminal = True

    def __init__(self, dyn: Dynamics, scale: float, energy: float):
        self.dyn, self.scale, self.energy = dyn, scale, energy

    def __call__(self, t: float, x: np.ndarray) -> float:
        return self.scale - abs(sum(self.dyn.energy(x[:4], x[4:])) - self.energy)


def _all_but(term: str) -> Callable[[str], bool]:
    """`use` of `term_rhs` that corrects every term but `term`."""
    return lambda k: k != term


def drift(dyn: Dynamics, rhs: Rhs, x0: np.ndarray, duration: float) -> str:
    """Relative energy drift over `duration` [s]; a motion whose drift reaches 1 is stopped
    there."""
    T0, V0 = dyn.energy(x0[:4], x0[4:])
    scale, E0 = T0 + abs(V0), T0 + V0
    diverged = _Diverged(dyn, scale, E0)
    sol = solve_ivp(lambda t, x: rhs(x), (0.0, duration), x0, method="DOP853", rtol=TOL,
                    atol=TOL, t_eval=np.linspace(0.0, duration, 501), events=diverged)
    if sol.status == 1:
        assert sol.t_events is not None  # solve_ivp was given an event
        return f"> 1 (diverged at t = {sol.t_events[0][0]:.3g} s)"
    if sol.status != 0:
        return f"failed at t = {sol.t[-1]:.3g} s: {sol.message}"
    energy = np.array([sum(dyn.energy(x[:4], x[4:])) for x in sol.y.T])
    return f"{np.max(np.abs(energy - E0)) / scale:.2e}"


def derived(dyn: Dynamics, q: np.ndarray) -> dict[str, float]:
    """The misprinted terms' derived values (1-based names) at angles q (0-based)."""
    M = dyn.mass_matrix(q)
    h0 = dyn.bias(q, np.zeros(4))
    out = {"M12": M[0, 1]}
    for j in range(4):
        hj = dyn.bias(q, np.eye(4)[j]) - h0
        out.update({f"h{i + 1}.dq{j + 1}^2": hj[i] for i in range(4)})
    return out


def deviations(arm: sp.Arm, dyn: Dynamics, rng: np.random.Generator,
               states: int) -> dict[str, tuple]:
    """Per misprinted term, over `states` random configurations: max |derived|,
    max |printed - derived|, max |corrected - derived|."""
    stats = {k: np.zeros(3) for k in sp.CORRECTED}
    for _ in range(states):
        q = rng.uniform(-np.pi, np.pi, 4)
        q1, d = np.r_[0.0, q], derived(dyn, q)
        printed = {**sp.printed_mass(arm, q1), **sp.printed_bias(arm, q1)}
        for k, f in sp.CORRECTED.items():
            row = np.abs([d[k], printed[k] - d[k], f(arm, q1) - d[k]])
            stats[k] = np.maximum(stats[k], row)
    return {k: tuple(v) for k, v in stats.items()}


def report(states: int, duration: float) -> str:
    robot = Robot.model_validate(VERTICAL_SEED_ARM)
    arm, dyn = sp.arm_of(robot), Dynamics(robot)
    rng = np.random.default_rng(2021)
    starts = [np.r_[rng.uniform(-np.pi, np.pi, 4), rng.uniform(-2.0, 2.0, 4)] for _ in range(3)]
    variants: list[tuple[str, Rhs]] = [
        ("printed (all misprints)", term_rhs(arm, lambda k: False)),
        *[(f"only `{m}` misprinted", term_rhs(arm, _all_but(m))) for m in sp.CORRECTED],
        ("corrected", term_rhs(arm, lambda k: True)),
        ("library (planner.dynamics)", library_rhs(dyn)),
    ]
    lines = [(f"Seed 4-link arm, g = {robot.gravity} m/s^2, tau = 0, {duration:g} s, DOP853 "
              f"rtol = atol = {TOL:g}. Drift = max |E(t) - E(0)| / (T(0) + |V(0)|); "
              "a motion is stopped once its drift reaches 1."), "",
             "Initial states (q [rad], dq [rad/s]):", ""]
    lines += [f"- x{k}: q = {np.round(x[:4], 4).tolist()}, dq = {np.round(x[4:], 4).tolist()}"
              for k, x in enumerate(starts)]
    lines += ["", "| model | " + " | ".join(f"drift x{k}" for k in range(len(starts))) + " |",
              "|---|" + "---:|" * len(starts)]
    for name, rhs in variants:
        cells = [drift(dyn, rhs, x0, duration) for x0 in starts]
        print(name, cells, flush=True)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", (f"Largest deviation from the derived value over {states} random configurations "
              "(q uniform in [-pi, pi]^4), kg m^2:"), "",
              "| term | max abs derived | max abs (printed - derived) "
              "| max abs (corrected - derived) |",
              "|---|---:|---:|---:|"]
    found = deviations(arm, dyn, np.random.default_rng(1000), states)
    for k, (size, printed, corrected) in found.items():
        lines.append(f"| `{k}` | {size:.4g} | {printed:.4g} | {corrected:.2e} |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench seed_errata", description=__doc__)
    parser.add_argument("--states", type=int, default=1000)
    parser.add_argument("--duration", type=float, default=5.0, help="[s] of each free motion")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    text = report(args.states, args.duration)
    harness.write_section(DOC, SECTION, "\n\n".join([
        text, harness.manifest("seed_errata", argv, started, note)]))
    print(f"wrote {DOC.relative_to(harness.ROOT)} in {time.perf_counter() - started:.1f} s")
    return 0
