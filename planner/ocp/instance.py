"""The numbers of one solve: a scene's parameters, bounds and starting point on a mesh."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from planner.model import Robot, parameters
from planner.ocp.guess import Guess
from planner.ocp.key import ProblemKey
from planner.ocp.layout import torques
from planner.ocp.mesh import Mesh
from planner.ocp.problem import Problem, cached_problem, problem
from planner.ocp.terms import Numeric, terms_of
from planner.scene import DurationRange, Scene


@dataclass(frozen=True)
class Instance:
    """A built NLP and the numbers of one solve of it: parameters P, variable bounds."""

    problem: Problem
    mesh: Mesh
    P: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    cache_hit: bool


def instance(scene: Scene, robot: Robot, mesh: Mesh, T: float,
             virtual_weight: float | None = None) -> Instance:
    """The NLP of a scene on a mesh (built or taken from the cache) and its numbers.

    robot: the robot whose numbers the NLP starts from (co-designed waves: their start);
    T: the duration [s] (a free duration's starting value); virtual_weight: the relaxed NLP,
    whose passive joints have virtual torques of this effort weight (None: the scene's own).
    """
    key = ProblemKey.of(scene, mesh.intervals)
    if virtual_weight is not None:
        key = replace(key, relaxed=True)
    hits = cached_problem.cache_info().hits
    prob = problem(key)
    hit = cached_problem.cache_info().hits > hits
    lbx, ubx = _bounds(scene, prob, robot, mesh)
    return Instance(prob, mesh, parameters_of(scene, prob, robot, mesh, T, virtual_weight),
                    lbx, ubx, hit)


def _boundary_durations(prob: Problem, mesh: Mesh) -> np.ndarray:
    """(N + 1,) time (fraction of T) from a stage's last torque to the next torque in time
    order (0 where there is none)."""
    _, stage_at, _, terminal_at = torques(prob.layout)
    out = np.zeros(mesh.intervals + 1)
    if not stage_at:
        return out
    widths = np.append(mesh.widths, 0.0)
    first_next = np.full(mesh.intervals, stage_at[0])
    first_next[-1] = terminal_at[0] if terminal_at else np.nan
    out[:-1] = (1 - stage_at[-1]) * widths[:-1] + first_next * widths[1:]
    return np.nan_to_num(out)


def parameters_of(scene: Scene, prob: Problem, robot: Robot, mesh: Mesh, T: float,
                  virtual_weight: float | None = None) -> np.ndarray:
    """The NLP's parameter vector: the common numbers (robot, T, every term's), then per
    stage the mesh width, the quadrature weights, the boundary duration and every term's
    (virtual_weight: a relaxed NLP's, see `instance`)."""
    common, local = prob.params.common, prob.params.local
    N = mesh.intervals
    head = np.zeros(prob.params.n_common)
    head[common["robot"]] = parameters(robot, prob.key.structure)
    if "T" in common:
        head[common["T"]] = T
    table = np.zeros((N + 1, prob.params.n_local))
    table[:N, local["width"]] = mesh.widths[:, None]
    stage_w, terminal_w = prob.transcription.weights(mesh)
    table[:N, local["weights"]] = stage_w
    table[N, local["weights"].start:local["weights"].start + terminal_w.size] = terminal_w
    table[:, local["boundary"]] = _boundary_durations(prob, mesh)[:, None]
    num = Numeric(scene, robot, T, mesh, prob.transcription, prob.key, virtual_weight)
    for term in terms_of(prob.key):
        head[common[term.name]] = term.common_values(num)
        if term.name in local:
            table[:, local[term.name]] = term.local_values(num)
    return np.concatenate([head, table.ravel()])


def _set_rows(x: np.ndarray, idx: np.ndarray, values: list[float | None]) -> None:
    for i, v in enumerate(values):
        if v is not None:
            x[idx[i]] = v


def _bounds(scene: Scene, prob: Problem, robot: Robot, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Variable bounds: limits, boundary conditions, exact tracking, time and wave bounds."""
    task, lay = scene.task, prob.layout
    lbx, ubx = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
    kinds = {name: (kind, idx) for name, (kind, idx) in lay.blocks.items()}
    for kind, bounds in (("q", task.position_bounds), ("dq", task.velocity_bounds)):
        if bounds is not None:
            for k, idx in kinds.values():
                if k == kind:
                    _set_rows(lbx, idx, bounds.lower)
                    _set_rows(ubx, idx, bounds.upper)
    if task.torque_limit is not None:
        limit = np.broadcast_to(np.asarray(task.torque_limit, float), (len(robot.active),))
        for k, idx in kinds.values():
            if k == "tau":  # the active joints' rows (a relaxed NLP's virtual ones are free)
                active = idx[:len(limit)]
                lbx[active], ubx[active] = -limit[:, None], limit[:, None]
    if task.tracking is not None and task.tracking.mode == "exact":
        T = task.duration
        assert not isinstance(T, DurationRange)  # the scene refuses tracking a free T
        for name in prob.transcription.knot_blocks:
            times = lay.times(name, mesh)
            ref = task.tracking.motion.evaluate(times * T, T)[0]
            idx = lay.blocks[name][1][robot.passive, :]
            lbx[idx], ubx[idx] = ref.T, ref.T
    q, dq = lay.blocks["q"][1], lay.blocks["dq"][1]
    for bound in (lbx, ubx):
        bound[q[:, 0]], bound[dq[:, 0]] = task.initial.q, task.initial.dq
        _set_rows(bound, q[:, -1:], task.final.q)
        _set_rows(bound, dq[:, -1:], task.final.dq)
    if prob.key.free_time:  # the first copy of a global is bounded (planner.ocp.layout)
        assert isinstance(task.duration, DurationRange)  # what makes the key's time free
        lbx[lay.first("T")], ubx[lay.first("T")] = task.duration.min, task.duration.max
    if prob.key.codesign:
        assert task.co_design is not None  # what makes the key co-design
        amax = [min(task.co_design.amplitude_max, 0.95 * robot.links[j].length)
                for j in robot.active]
        lbx[lay.first("wave")] = [v for _ in amax for v in (0.0, -2 * np.pi)]
        ubx[lay.first("wave")] = [v for a in amax for v in (a, 2 * np.pi)]
    return lbx, ubx


def initial_point(inst: Instance, guess: Guess, T: float, robot: Robot) -> np.ndarray:
    """A guess laid out as the NLP's variable vector (T: the duration, robot: the waves)."""
    prob, lay = inst.problem, inst.problem.layout
    x0 = lay.zeros()
    values: dict[bytes, dict[str, np.ndarray]] = {}  # the guess at each distinct time grid
    for name, (kind, idx) in lay.blocks.items():
        if kind == "global":
            continue
        times = lay.times(name, inst.mesh)
        grid = times.tobytes()
        if grid not in values:
            values[grid] = guess(times)
        x0[idx] = values[grid][kind].T
    if prob.key.free_time:
        lay.put(x0, "T", T)
    if prob.key.codesign:
        design: list[float] = []
        for j in robot.active:
            wave = robot.links[j].wave
            assert wave is not None  # the co-design robot has a wave on every active joint
            design += [wave.amplitude, wave.phase]
        lay.put(x0, "wave", np.array(design)[:, None])
    return x0
