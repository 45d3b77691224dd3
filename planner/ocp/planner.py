"""plan(): set a scene's numbers into its structure's NLP, solve with Ipopt, verify."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from planner.model import Robot, Wave, parameters
from planner.ocp.guess import Guess, hermite_guess, inverse_dynamics_guess, plan_guess
from planner.ocp.problem import Problem, ProblemKey, problem
from planner.ocp.result import (
    DenseTrajectory,
    Plan,
    Progress,
    SolverReport,
    Verification,
    WaveOut,
)
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import coupling_along, verify
from planner.scene import DurationRange, Scene

DENSE_POINTS = 2000  # about this many dense samples per plan
_STOP_STATUS = {"cancelled": "User_Requested_Stop", "max_iter": "Maximum_Iterations_Exceeded",
                "max_wall_time": "Maximum_WallTime_Exceeded"}


def plan(scene: Scene, progress: Callable[[Progress], bool] | None = None,
         warm_start: Plan | None = None) -> Plan:
    """Plan feed-forward torques for a scene.

    progress is called once per Ipopt iteration; returning False stops the solve.
    warm_start: an earlier plan whose trajectory seeds the initial guess.
    A failed solve is returned (success False, best iterate), never raised.
    """
    key = ProblemKey.of(scene)
    hits = problem.cache_info().hits
    prob = problem(key)
    cache_hit = problem.cache_info().hits > hits
    robot = _design_robot(scene, key)
    p_robot = parameters(robot, key.structure)
    T_guess = _duration_guess(scene)
    guess, guess_used = _guess(scene, robot, T_guess, warm_start)
    lbx, ubx = _bounds(scene, prob, robot)
    x0 = _initial_point(prob, guess, T_guess, robot, scene)
    P = _parameters(scene, prob, p_robot, T_guess)

    solver = scene.solver
    prob.monitor.reset(progress, solver.max_iter, solver.max_wall_time, prob.lbg, prob.ubg)
    started = time.perf_counter()
    try:
        out = prob.solver(x0=x0, lbx=lbx, ubx=ubx, lbg=prob.lbg, ubg=prob.ubg, p=P)
        x, objective = np.array(out["x"]).ravel(), float(out["f"])
        message = ""
    except RuntimeError as exc:  # evaluation errors: report the last iterate Ipopt saw
        x, objective, message = x0, math.nan, str(exc).splitlines()[-1]
    stats = {**prob.solver.stats(), "solve_time": time.perf_counter() - started}
    status = _STOP_STATUS.get(prob.monitor.reason, stats.get("return_status", "Error"))
    success = bool(stats.get("success", False)) and not prob.monitor.reason
    if not message:
        message = _message(status, success)
    return _result(scene, prob, robot, x, objective, status, success, message, stats,
                   0.0 if cache_hit else prob.build_time, cache_hit, guess_used)


def _guess(scene: Scene, robot: Robot, T: float, warm_start: Plan | None) -> tuple[Guess, str]:
    """The initial guess (an earlier plan, else the scene's `solver.initial_guess`) and
    what it was: an inverse dynamics that cannot be computed leaves the interpolation."""
    if warm_start is not None:
        return plan_guess(warm_start), "warm start"
    if scene.solver.initial_guess == "inverse-dynamics":
        try:
            return inverse_dynamics_guess(scene, robot, T), "inverse-dynamics"
        except ValueError as exc:
            return hermite_guess(scene, robot, T), f"interpolation; inverse-dynamics refused: {exc}"
    return hermite_guess(scene, robot, T), "interpolation"


def _message(status: str, success: bool) -> str:
    if success:
        return "optimal solution found"
    return {"User_Requested_Stop": "the solve was cancelled",
            "Maximum_Iterations_Exceeded": "the iteration limit was reached",
            "Maximum_WallTime_Exceeded": "the wall-time limit was reached",
            "Infeasible_Problem_Detected": "the task is infeasible (constraints cannot all hold)",
            }.get(status, f"the solver stopped: {status}")


def _design_robot(scene: Scene, key: ProblemKey) -> Robot:
    """The robot whose numbers seed the NLP: co-designed joints get their fixed frequency
    and a starting amplitude of half the bound."""
    co = scene.task.co_design
    if co is None:
        return scene.robot
    waves = {}
    for col, joint in enumerate(scene.robot.active):
        link = scene.robot.links[joint]
        amp = min(co.amplitude_max, 0.95 * link.length) / 2
        phase = link.wave.phase if link.wave is not None else 0.0
        waves[joint] = Wave(amplitude=amp, frequency=co.frequency[col], phase=phase)
    return scene.robot.with_waves(waves)


def _duration_guess(scene: Scene) -> float:
    d = scene.task.duration
    return math.sqrt(d.min * d.max) if isinstance(d, DurationRange) else d


def _each(prob: Problem, kind: str):
    """(block name, time fractions) of every block holding quantity `kind`."""
    for name, (k, times) in prob.discrete.block_times.items():
        if k == kind and name in prob.layout:
            yield name, times


def _set_rows(view: np.ndarray, values: list[float | None]) -> None:
    for i, v in enumerate(values):
        if v is not None:
            view[i, :] = v


def _bounds(scene: Scene, prob: Problem, robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Variable bounds: limits, boundary conditions, exact tracking, time and wave bounds."""
    task, lay = scene.task, prob.layout
    lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
    pairs = (("q", task.position_bounds), ("dq", task.velocity_bounds))
    for kind, bounds in pairs:
        if bounds is not None:
            for name, _ in _each(prob, kind):
                _set_rows(lay.view(lbx, name), bounds.lower)
                _set_rows(lay.view(ubx, name), bounds.upper)
    if task.torque_limit is not None:
        limit = np.broadcast_to(np.asarray(task.torque_limit, float), (len(robot.active),))
        for name, _ in _each(prob, "tau"):
            lay.view(lbx, name)[:] = -limit[:, None]
            lay.view(ubx, name)[:] = limit[:, None]
    if task.tracking is not None and task.tracking.mode == "exact":
        passive = robot.passive
        for name in prob.discrete.knot_blocks:
            times = prob.discrete.block_times[name][1]
            ref = task.tracking.motion.evaluate(times * task.duration, task.duration)[0]
            for bound in (lbx, ubx):
                lay.view(bound, name)[passive, :] = ref.T
    for bound in (lbx, ubx):
        lay.view(bound, "q")[:, 0] = task.initial.q
        lay.view(bound, "dq")[:, 0] = task.initial.dq
        _set_rows(lay.view(bound, "q")[:, -1:], task.final.q)
        _set_rows(lay.view(bound, "dq")[:, -1:], task.final.dq)
    if prob.key.free_time:
        lay.view(lbx, "T")[:] = task.duration.min
        lay.view(ubx, "T")[:] = task.duration.max
    if prob.key.codesign:
        amax = [min(task.co_design.amplitude_max, 0.95 * robot.links[j].length) for j in robot.active]
        lay.view(lbx, "wave")[:] = [[0.0] * len(amax), [-2 * np.pi] * len(amax)]
        lay.view(ubx, "wave")[:] = [amax, [2 * np.pi] * len(amax)]
    return lbx, ubx


def _initial_point(prob: Problem, guess: Guess, T: float, robot: Robot, scene: Scene) -> np.ndarray:
    """The guess laid out as the NLP's variable vector."""
    lay = prob.layout
    x0 = lay.zeros()
    values = {}
    for name, (kind, times) in prob.discrete.block_times.items():
        if name in lay:
            if kind not in values or len(values[kind][0]) != len(times) or not np.allclose(values[kind][0], times):
                values[kind] = (times, guess(times))
            lay.view(x0, name)[:] = values[kind][1][kind].T
    if prob.key.free_time:
        lay.view(x0, "T")[:] = T
    if prob.key.codesign:
        lay.view(x0, "wave")[:] = [[robot.links[j].wave.amplitude for j in robot.active],
                                   [robot.links[j].wave.phase for j in robot.active]]
    return x0


def _parameters(scene: Scene, prob: Problem, p_robot: np.ndarray, T: float) -> np.ndarray:
    task, par = scene.task, prob.params
    P = np.zeros(prob.n_params)
    P[par["robot"]] = p_robot
    tracking_weight = task.tracking.weight if task.tracking is not None else 0.0
    P[par["weights"]] = [task.objective.effort, task.objective.time, task.objective.smoothness,
                         tracking_weight]
    if "T" in par:
        P[par["T"]] = T
    if "ref" in par:
        times = prob.discrete.knot_times * T
        P[par["ref"]] = task.tracking.motion.evaluate(times, T)[0].ravel()  # (K, np) row-major
    if "tip" in par:
        P[par["tip"]] = [task.tip_target.x, task.tip_target.y]
    if "margin" in par:
        start = np.array([task.initial.q])
        det = coupling_along(_design_robot(scene, prob.key), start)[1]
        P[par["margin"]] = [task.coupling_margin, 1.0 if det is None or det[0] >= 0 else -1.0]
    return P


def _solution_blocks(prob: Problem, x: np.ndarray, P: np.ndarray) -> dict[str, np.ndarray]:
    blocks = {name: prob.layout.view(x, name).copy() for name in prob.layout.blocks}
    accel = prob.accelerations(x, P)
    blocks.update(accel)
    return blocks


def _result(scene: Scene, prob: Problem, robot: Robot, x: np.ndarray, objective: float,
            status: str, success: bool, message: str, stats: dict, build_time: float,
            cache_hit: bool, guess_used: str) -> Plan:
    lay, key = prob.layout, prob.key
    robot = _solved_robot(scene, prob, robot, x)
    p_robot = parameters(robot, key.structure)
    T = float(lay.view(x, "T")[0, 0]) if key.free_time else float(scene.task.duration)
    P = _parameters(scene, prob, p_robot, T)
    blocks = _solution_blocks(prob, x, P)
    breaks = np.linspace(0.0, T, key.intervals + 1)
    interp: Interpolant = prob.transcription.interpolant(blocks, breaks)
    per = max(1, math.ceil(DENSE_POINTS / key.intervals))
    t_dense = np.linspace(0.0, T, key.intervals * per + 1)
    q_nodes, dq_nodes = blocks["q"].T, blocks["dq"].T
    finite = np.all(np.isfinite(x)) and math.isfinite(objective)
    tolerance = scene.solver.resimulation_tolerance
    verification = verify(robot, interp, t_dense, per, tolerance) if finite else None
    if not finite:
        success, message = False, message or "the solve produced non-finite values"
    return Plan(
        t=breaks.tolist(), q=_finite(q_nodes), dq=_finite(dq_nodes),
        ddq=_finite(interp.dq(breaks, derivative=1)), tau=_finite(interp.tau(breaks)),
        dense=DenseTrajectory(t=t_dense.tolist(), q=_finite(interp.q(t_dense)),
                              tau=_finite(interp.tau(t_dense))),
        duration=T,
        objective=objective if math.isfinite(objective) else 0.0,
        waves=[WaveOut(joint=j, amplitude=link.wave.amplitude, frequency=link.wave.frequency,
                       phase=link.wave.phase)
               for j, link in enumerate(robot.links) if link.wave is not None],
        solver=SolverReport(status=status, success=success, message=message,
                            iterations=int(stats.get("iter_count", 0)), build_time=build_time,
                            solve_time=float(stats["solve_time"]), cache_hit=cache_hit,
                            initial_guess=guess_used),
        verification=verification or _unverified(tolerance),
    )


def _solved_robot(scene: Scene, prob: Problem, robot: Robot, x: np.ndarray) -> Robot:
    """The robot with the co-designed waves of the solution (unchanged otherwise)."""
    if not prob.key.codesign:
        return robot
    amp, phase = prob.layout.view(x, "wave")
    waves = {}
    for col, joint in enumerate(robot.active):
        freq = robot.links[joint].wave.frequency
        a = float(np.clip(amp[col], 0.0, 0.95 * robot.links[joint].length))
        waves[joint] = Wave(amplitude=a, frequency=freq, phase=float(phase[col]))
    return robot.with_waves(waves)


def _unverified(tolerance: float) -> Verification:
    return Verification(resimulation_error=None, resimulation_status="not run: non-finite solution",
                        verified=False, tolerance=tolerance, defect=None, min_sigma=None,
                        waveless_min_sigma=None, waveless_singular_crossings=[])


def _finite(a: np.ndarray) -> list[list[float]]:
    """Rows as lists, with any non-finite entry replaced by 0 (the plan then says it failed)."""
    return np.where(np.isfinite(a), a, 0.0).tolist()
