"""Closed loop on an arm that is not the model: replanning at a fixed rate against the
plan's LQR feedback alone.

Per scene: the plan of the scene at N intervals (the nominal model, default settings). The
arm it runs on has every link's mass `--mass` heavier (relative) and gets a push: its
first passive joint's rate jumps by `--push` rad/s at a third of the motion. Two
controllers drive it from the planned initial state to the end time T:
- "LQR feedback alone": the plan's torque with its LQR feedback (`feedback.gains`,
  applied at the torque's breakpoints, `planner.simulate.ClosedLoop`), the push at the
  breakpoint nearest T/3;
- "replanning": a `planner.ocp.replan.Replanner` on the nominal model, converged once
  from the initial state before the motion starts, then `--updates` real-time updates at
  a fixed rate (every T / updates seconds) from the arm's state measured at that instant;
  between updates the arm gets the latest update's torque, sampled `SUBSAMPLES` times per
  period and linearly interpolated (a servo loop's hold), the push at the update nearest
  T/3.
The arm is integrated by CVODES (`planner.simulate.simulate`, 1e-10). Reported: the final
error (largest |q - q_goal| [rad] and |dq - dq_goal| [rad/s] at T), the tracking error
(largest |q - q_plan| along the motion [rad]), the largest |tau| over the torque limit,
and per update the median and 99th percentile of wall and CPU time and the iterations;
a plot of the first passive joint under both.

    python -m bench closed_loop [--scenes seed-arm-plan,two-link-plan,five-link]
        [--N 50] [--updates 200] [--mass 0.1] [--push 0.2] [--wall 0.2]
"""

from __future__ import annotations

import argparse
import copy
import math
import time

import numpy as np

from bench import harness
from planner import compiled
from planner.examples import example
from planner.model import Robot
from planner.ocp import plan
from planner.ocp.replan import Replanner
from planner.ocp.result import Plan
from planner.ocp.robustness import models
from planner.scene import Scene, Uncertainty
from planner.simulate import ClosedLoop, simulate, torque_coefficients

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


def _errors(x: np.ndarray, scene: Scene) -> float:
    """max(|q - q_goal|, |dq - dq_goal|) at the end, over the entries the goal sets."""
    n = len(scene.robot.links)
    goal = [*scene.task.final.q, *scene.task.final.dq]
    return max(abs(x[j] - g) for j, g in enumerate(goal[:2 * n]) if g is not None)


def lqr_alone(scene: Scene, nominal: Plan, arm: Robot, push: float) -> dict:
    """The plan's torque with its LQR feedback on the arm, pushed at the breakpoint nearest
    T/3."""
    assert nominal.torque is not None and nominal.feedback is not None
    assert nominal.states is not None
    breaks = np.asarray(nominal.torque.breaks)
    coeffs = nominal.torque.array()
    q_p, dq_p = nominal.states.polynomials()
    loop = ClosedLoop(gains=nominal.feedback.gains, q=q_p(breaks).tolist(),
                      dq=dq_p(breaks).tolist())
    k = int(np.argmin(np.abs(breaks - breaks[-1] / 3)))
    x0 = np.concatenate([nominal.q[0], nominal.dq[0]])
    first = simulate(arm, breaks[:k + 1], coeffs[:k], x0, feedback=_sliced(loop, 0, k))
    x = np.concatenate([first.q[-1], first.dq[-1]])
    x[len(arm.links) + arm.passive[0]] += push
    second = simulate(arm, breaks[k:], coeffs[k:], x, feedback=_sliced(loop, k, len(coeffs)))
    q = np.vstack([first.q, second.q[1:]])
    t = np.concatenate([first.t, second.t[1:]])
    at_breaks = np.hstack([np.vstack([first.q[:-1], second.q]),
                           np.vstack([first.dq[:-1], second.dq])])
    at_breaks[k, len(arm.links) + arm.passive[0]] += push  # the state the k-th gain sees
    final = np.concatenate([second.q[-1], second.dq[-1]])
    return {"t": t, "q": q, "final": final,
            "tau_max": _applied_peak(coeffs, loop, at_breaks), "status": second.status}


def _applied_peak(coeffs: np.ndarray, loop: ClosedLoop, states: np.ndarray) -> float:
    """The largest |tau| [N m] the arm got: every interval's polynomial (sampled) less the
    feedback's correction held over it."""
    s = np.linspace(0.0, 1.0, 9)
    powers = s[:, None] ** np.arange(coeffs.shape[1])[None, :]
    peak = 0.0
    for k in range(coeffs.shape[0]):
        tau = powers @ coeffs[k] - loop.correction(k, states[k])[None, :]
        peak = max(peak, float(np.abs(tau).max()))
    return peak


def _sliced(loop: ClosedLoop, first: int, last: int) -> ClosedLoop:
    return ClosedLoop(gains=loop.gains[first:last], q=loop.q[first:last + 1],
                      dq=loop.dq[first:last + 1])


def replanning(scene: Scene, nominal: Plan, arm: Robot, push: float, updates: int,
               wall: float) -> dict:
    """Real-time replanning at `updates` evenly spaced instants on the arm, each solve of an
    update within `wall` seconds."""
    T = nominal.duration
    period = T / updates
    replanner = Replanner(scene, nominal)
    x = np.concatenate([nominal.q[0], nominal.dq[0]])
    n = len(arm.links)
    replanner.update(0.0, list(x[:n]), list(x[n:]), mode="converged")
    push_at = int(round(updates / 3))
    times, states, walls, cpus, iterations, taus = [0.0], [x], [], [], [], []
    fallbacks = escalations = 0
    current = None
    for k in range(updates):
        t = k * period
        if k == push_at:
            x = x.copy()
            x[n + arm.passive[0]] += push
        update = replanner.update(t, list(x[:n]), list(x[n:]), wall_time=wall)
        escalations += update.escalated
        walls.append(update.wall)
        cpus.append(update.cpu)
        iterations.append(update.iterations)
        if update.fallback:
            fallbacks += 1
        else:
            current = update
        assert current is not None
        samples = np.linspace(t, t + period, SUBSAMPLES + 1)
        tau = current.torque(samples)
        taus.append(np.abs(tau).max())
        coeffs = torque_coefficients(samples, tau, "linear")
        run = simulate(arm, samples, coeffs, x)
        x = np.concatenate([run.q[-1], run.dq[-1]])
        times.append(t + period)
        states.append(x)
    q = np.array(states)[:, :n]
    return {"t": np.array(times), "q": q, "final": x, "tau_max": float(max(taus)),
            "walls": walls, "cpus": cpus, "iterations": iterations, "fallbacks": fallbacks,
            "escalations": escalations}


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
    lqr = lqr_alone(scene, nominal, arm, push)
    rep = replanning(scene, nominal, arm, push, updates, wall)
    limit = _limit(scene)
    rows = [{"scene": name, "controller": "LQR feedback alone", "N": N, "updates": "",
             "final_error": float(_errors(lqr["final"], scene)),
             "tracking_error": _tracking(lqr, nominal),
             "over_limit": lqr["tau_max"] - limit if math.isfinite(limit) else "",
             "median_wall_ms": "", "p99_wall_ms": "", "median_cpu_ms": "", "p99_cpu_ms": "",
             "median_iterations": "", "escalations": "", "fallbacks": "",
             "verified_plan": nominal.status}]
    rows.append({"scene": name, "controller": "replanning (real-time)", "N": N,
                 "updates": updates, "final_error": float(_errors(rep["final"], scene)),
                 "tracking_error": _tracking(rep, nominal),
                 "over_limit": rep["tau_max"] - limit if math.isfinite(limit) else "",
                 "median_wall_ms": 1e3 * harness.median(rep["walls"]),
                 "p99_wall_ms": 1e3 * float(np.percentile(rep["walls"], 99)),
                 "median_cpu_ms": 1e3 * harness.median(rep["cpus"]),
                 "p99_cpu_ms": 1e3 * float(np.percentile(rep["cpus"], 99)),
                 "median_iterations": harness.median(rep["iterations"]),
                 "escalations": rep["escalations"], "fallbacks": rep["fallbacks"],
                 "verified_plan": nominal.status})
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
        f"{args.push:g} rad/s at a third of the motion. LQR feedback alone: the plan's "
        f"torque and gains. Replanning: {args.updates} real-time updates (3 Ipopt iterations "
        f"each, from the last update's primal and dual) at a fixed rate from the measured "
        f"state, on the nominal model, after one converged update before the motion; an "
        f"update whose iterations end beyond the accepted violation escalates to a converged "
        f"solve, one that cannot be made leaves the last update's torque in force (each "
        f"solve within {args.wall:g} s). Final "
        f"error: the largest of |q - q_goal| [rad] and |dq - dq_goal| [rad/s] at the end; "
        f"tracking: the largest |q - q_plan| [rad]; over the limit: the largest |tau| less "
        f"the torque limit [N m] (negative: within). Times per update, this process.",
        harness.table(rows, [("scene", "scene"), ("controller", "controller"),
                             ("updates", "updates"), ("final_error", "final error"),
                             ("tracking_error", "tracking error [rad]"),
                             ("over_limit", "over the limit [N m]"),
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
