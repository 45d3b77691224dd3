"""Closed loop on an arm that is not the model: replanning at a fixed rate against the
plan's LQR feedback alone.

Per scene: the plan of the scene at N intervals (the nominal model, default settings). The
arm it runs on has every link's mass `--mass` heavier (relative) and gets a push: its
first passive joint's rate jumps by `--push` rad/s at the update nearest a third of the
motion. Two controllers drive it from the planned initial state to the end time T, each
through the same servo loop (`drive`: `SUBSAMPLES` steps per update period, each holding
the controller's `Replan.command` for the state at its start, the torque with its LQR
correction):
- "LQR feedback alone": the plan's torque and its LQR gains (`Replan.of_plan`);
- "replanning": a `planner.ocp.replan.Replanner` on the nominal model, converged once
  from the initial state before the motion starts, then `--updates` real-time updates at
  a fixed rate (every T / updates seconds) from the arm's state measured at that instant;
  the servo loop follows the last accepted update and its gains (after a fallback, and in
  the final stretch where updates hold, the last plan stands).
The arm is integrated by CVODES (`planner.simulate.simulate`, 1e-10). Reported: the final
error (largest |q - q_goal| [rad] and |dq - dq_goal| [rad/s] at T), the tracking error
(largest |q - q_plan| along the motion [rad]), the largest |tau| over the torque limit,
and over the updates that solved (not those held in the final stretch) the median and
99th percentile of wall and CPU time, the iterations, escalations and fallbacks; a plot
of the first passive joint under both.

    python -m bench closed_loop [--scenes seed-arm-plan,two-link-plan,five-link]
        [--N 50] [--updates 200] [--mass 0.1] [--push 0.2] [--wall 0.2]
"""

from __future__ import annotations

import argparse
import copy
import math
import time
from typing import Protocol

import numpy as np

from bench import harness
from planner import compiled
from planner.examples import example
from planner.model import Robot
from planner.ocp import plan
from planner.ocp.replan import FINAL_STRETCH, HELD, REALTIME_ITERATIONS, Replan, Replanner
from planner.ocp.result import Plan
from planner.ocp.robustness import models
from planner.scene import Scene, Uncertainty
from planner.simulate import simulate

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Closed loop: replanning against LQR feedback alone"
SUBSAMPLES = 10
"""Torque samples per update period that the arm gets between updates."""
FIVE_LINK = {"gravity": 9.81, "links": [
    {"mass": 1.0, "length": 0.5, "inertia": 0.02, "joint": "passive"},
    {"mass": 0.8, "length": 0.45, "inertia": 0.015, "joint": "active",
     "wave": {"amplitude": 0.03, "frequency": 4, "phase": 0.0}},
    {"mass": 0.6, "length": 0.4, "inertia": 0.01, "joint": "active",
     "wave": {"amplitude": 0.03, "frequency": 4, "phase": 0.0}},
    {"mass": 0.5, "length": 0.35, "inertia": 0.008, "joint": "passive"},
    {"mass": 0.4, "length": 0.3, "inertia": 0.005, "joint": "active",
     "wave": {"amplitude": 0.02, "frequency": 4, "phase": 0.0}}]}
"""A five-link arm, passive joints 0 and 3, hanging in gravity."""


def request(name: str, N: int) -> dict:
    """The scene's request on N intervals."""
    if name == "five-link":
        base: dict = {"robot": FIVE_LINK, "task": {
            "duration": 3.0, "initial": {"q": [-1.5708, 0.0, 0.0, 0.0, 0.0], "dq": [0.0] * 5},
            "final": {"q": [-1.3708, 0.3, -0.2, 0.1, 0.2], "dq": [0.0] * 5},
            "torque_limit": 40.0}}
    else:
        base = copy.deepcopy(example(name).request)
    base.setdefault("transcription", {})["intervals"] = N
    return base


def final_error(x: np.ndarray, scene: Scene) -> float:
    """max(|q - q_goal|, |dq - dq_goal|) at the end, over the entries the goal sets."""
    n = len(scene.robot.links)
    goal = [*scene.task.final.q, *scene.task.final.dq]
    return float(max(abs(x[j] - g) for j, g in enumerate(goal[:2 * n]) if g is not None))


class Command(Protocol):
    """What the servo loop applies between updates."""

    def command(self, t: float, x: np.ndarray) -> np.ndarray: ...


class Controller(Protocol):
    """What the servo loop asks of a controller at each update."""

    def update(self, k: int, t: float, x: np.ndarray) -> Command: ...


class LqrAlone:
    """The plan's torque and its LQR feedback, the same at every update."""

    def __init__(self, nominal: Plan):
        self.plan = Replan.of_plan(nominal)

    def update(self, k: int, t: float, x: np.ndarray) -> Replan:
        return self.plan


class Replanning:
    """A `Replanner` on the nominal model: a real-time update at every update instant
    (each solve within `wall` seconds); the last accepted update is followed."""

    def __init__(self, scene: Scene, nominal: Plan, wall: float):
        self.replanner, self.wall = Replanner(scene, nominal), wall
        x0 = np.concatenate([nominal.q[0], nominal.dq[0]])
        n = x0.size // 2
        self.current = self.replanner.update(0.0, list(x0[:n]), list(x0[n:]),
                                             mode="converged")
        self.updates: list[Replan] = []

    def update(self, k: int, t: float, x: np.ndarray) -> Replan:
        n = x.size // 2
        update = self.replanner.update(t, list(x[:n]), list(x[n:]), wall_time=self.wall)
        self.updates.append(update)
        if not update.fallback:
            self.current = update
        return self.current


def drive(arm: Robot, x0: np.ndarray, T: float, updates: int, push: float,
          controller: Controller) -> dict:
    """The arm from x0 over [0, T] under the controller: an update every T / updates
    seconds from the state measured then, and between updates a servo loop of SUBSAMPLES
    steps per period, each holding `Replan.command` of the state at its start; the first
    passive joint's rate pushed by `push` at the update nearest T/3."""
    period, n = T / updates, len(arm.links)
    x, push_at = np.asarray(x0, float), int(round(updates / 3))
    times, states, peaks = [0.0], [x], []
    for k in range(updates):
        t = k * period
        if k == push_at:
            x = x.copy()
            x[n + arm.passive[0]] += push
        current = controller.update(k, t, x)
        for j in range(SUBSAMPLES):
            ts = t + period * np.array([j, j + 1]) / SUBSAMPLES
            tau = current.command(ts[0], x)
            peaks.append(float(np.abs(tau).max()))
            run = simulate(arm, ts, tau[None, None, :], x)
            if run.status != "completed":
                raise RuntimeError(f"the arm's simulation failed: {run.message}")
            x = np.concatenate([run.q[-1], run.dq[-1]])
            times.append(float(ts[1]))
            states.append(x)
    return {"t": np.array(times), "q": np.array(states)[:, :n], "final": x,
            "tau_max": max(peaks)}


def _limit(scene: Scene) -> float:
    lim = scene.task.torque_limit
    if lim is None:
        return math.inf
    return float(min(lim)) if isinstance(lim, list) else float(lim)


def _tracking(run: dict, nominal: Plan) -> float:
    """The largest |q - q_plan| [rad] along the run."""
    assert nominal.states is not None
    q_p, _ = nominal.states.polynomials()
    return float(np.abs(run["q"] - q_p(run["t"])).max())


def run_scene(name: str, N: int, updates: int, mass: float, push: float,
              wall: float) -> tuple[list[dict], dict]:
    scene = Scene.model_validate(request(name, N))
    nominal = plan(scene)
    compiled.wait()
    nominal = plan(scene)
    arm = dict(models(scene.robot, Uncertainty(mass=mass)))["mass+"]
    x0, T = np.concatenate([nominal.q[0], nominal.dq[0]]), nominal.duration
    lqr = drive(arm, x0, T, updates, push, LqrAlone(nominal))
    replanning = Replanning(scene, nominal, wall)
    rep = drive(arm, x0, T, updates, push, replanning)
    solved = [u for u in replanning.updates if u.status != HELD]
    walls, cpus = [u.wall for u in solved], [u.cpu for u in solved]
    limit = _limit(scene)
    rows = []
    for controller, run in (("LQR feedback alone", lqr), ("replanning (real-time)", rep)):
        rows.append({"scene": name, "controller": controller, "N": N, "updates": updates,
                     "final_error": final_error(run["final"], scene),
                     "tracking_error": _tracking(run, nominal),
                     "over_limit": run["tau_max"] - limit if math.isfinite(limit) else "",
                     "verified_plan": nominal.status})
    rows[1].update({
        "solved": len(solved), "held": len(replanning.updates) - len(solved),
        "median_wall_ms": 1e3 * harness.median(walls),
        "p99_wall_ms": 1e3 * float(np.percentile(walls, 99)),
        "median_cpu_ms": 1e3 * harness.median(cpus),
        "p99_cpu_ms": 1e3 * float(np.percentile(cpus, 99)),
        "median_iterations": harness.median([u.iterations for u in solved]),
        "escalations": sum(u.escalated for u in solved),
        "fallbacks": sum(u.fallback for u in solved)})
    for row in rows:
        print(row, flush=True)
    return rows, {"nominal": nominal, "lqr": lqr, "replanning": rep, "arm": arm}


def _plot(traces: dict[str, dict]) -> None:
    from matplotlib.figure import Figure

    from planner.plots import PALETTE, render

    fig = Figure(figsize=(6.4, 2.6 * len(traces)))
    colours = PALETTE["joints"]
    for i, (name, trace) in enumerate(traces.items()):
        ax = fig.add_subplot(len(traces), 1, i + 1)
        j = trace["arm"].passive[0]
        nominal = trace["nominal"]
        q_p, _ = nominal.states.polynomials()
        t = np.linspace(0, nominal.duration, 400)
        ax.plot(t, q_p(t)[:, j], color="0.5", linestyle=":", label="plan")
        ax.plot(trace["lqr"]["t"], trace["lqr"]["q"][:, j], color=colours[0],
                label="LQR feedback alone")
        ax.plot(trace["replanning"]["t"], trace["replanning"]["q"][:, j], color=colours[1],
                label="replanning")
        ax.set_title(f"{name}: passive joint {j}", fontsize=9)
        ax.set_ylabel("q [rad]")
        ax.grid(True, alpha=0.3)
        if i == 0:
            ax.legend(fontsize=8)
    fig.axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    harness.output(harness.DOCS / "img" / "closed_loop.png").write_bytes(render(fig))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench closed_loop", description=__doc__)
    parser.add_argument("--scenes", default="seed-arm-plan,two-link-plan,five-link")
    parser.add_argument("--N", type=int, default=50)
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--mass", type=float, default=0.1)
    parser.add_argument("--push", type=float, default=0.2)
    parser.add_argument("--wall", type=float, default=0.2,
                        help="[s] the most each solve of an update may take")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows, traces = [], {}
    for name in args.scenes.split(","):
        scene_rows, traces[name] = run_scene(name, args.N, args.updates, args.mass, args.push,
                                             args.wall)
        rows += scene_rows
    harness.write_csv(harness.RESULTS / "closed_loop.csv", rows)
    _plot(traces)
    text = "\n\n".join([
        f"Each scene planned at N = {args.N} on the nominal model; the arm has every mass "
        f"{100 * args.mass:g} % heavier and its first passive joint's rate pushed by "
        f"{args.push:g} rad/s at a third of the motion. Both controllers run through the "
        f"same servo loop ({SUBSAMPLES} steps per update period, each holding the torque "
        f"with its LQR correction for the state measured at its start). LQR feedback "
        f"alone: the plan's torque and gains. Replanning: {args.updates} updates at a fixed "
        f"rate from the measured state on the nominal model (real-time: "
        f"{REALTIME_ITERATIONS} Ipopt iterations from the last update's primal and dual "
        f"point; beyond the accepted violation a converged solve follows; an update that "
        f"cannot be made leaves the last accepted one in force; each solve within "
        f"{args.wall:g} s), after one converged update before the motion; updates in the "
        f"last {100 * FINAL_STRETCH:g} % of the motion hold the last plan and its gains. "
        f"Final error: the largest of |q - q_goal| [rad] and |dq - dq_goal| [rad/s] at the "
        f"end; tracking: the largest |q - q_plan| [rad]; over the limit: the largest |tau| "
        f"less the torque limit [N m] (negative: within). Times per update that solved, "
        f"this process.",
        harness.table(rows, [("scene", "scene"), ("controller", "controller"),
                             ("updates", "updates"), ("final_error", "final error"),
                             ("tracking_error", "tracking error [rad]"),
                             ("over_limit", "over the limit [N m]"),
                             ("solved", "updates solved"), ("held", "held"),
                             ("median_wall_ms", "median wall [ms]"),
                             ("p99_wall_ms", "99th pct wall [ms]"),
                             ("median_cpu_ms", "median CPU [ms]"),
                             ("p99_cpu_ms", "99th pct CPU [ms]"),
                             ("median_iterations", "iterations"),
                             ("escalations", "escalated"), ("fallbacks", "fallbacks")]),
        "![The first passive joint under both controllers](img/closed_loop.png)",
        f"Rows: `bench/results/closed_loop.csv`. "
        f"{harness.manifest('closed_loop', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
