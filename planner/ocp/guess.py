"""Initial guesses: functions of the time fraction t / T in [0, 1] giving q, dq, ddq and tau."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from planner.dynamics import functions
from planner.inverse import WALL_TIME, integrate
from planner.model import Robot, Structure, parameters
from planner.ocp.interpolant import PiecewisePolynomial, hermite
from planner.ocp.transcription import Interpolant
from planner.scene import Scene
from planner.schema import JointState
from planner.torque import TorquePolynomial

Guess = Callable[[np.ndarray], dict[str, np.ndarray]]


def _torques(robot: Robot, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                    rows: list[int]) -> np.ndarray:
    """Rows `rows` of M ddq + h [N m] along a motion (K, n) -> (K, len(rows))."""
    s = Structure.of(robot)
    Q = functions(s)["id"].map(len(q))(q.T, dq.T, ddq.T, parameters(robot, s))
    return np.array(Q)[rows, :].T


def hermite_guess(scene: Scene, robot: Robot, T: float, rows: list[int] | None = None) -> Guess:
    """`hermite_motion` and the torques that rows `rows` of the dynamics (default: the
    active joints') ask for along it."""
    motion = hermite_motion(scene, robot, T)
    rows = robot.active if rows is None else rows

    def guess(x: np.ndarray) -> dict[str, np.ndarray]:
        out = motion(x)
        return {**out, "tau": _torques(robot, out["q"], out["dq"], out["ddq"], rows)}

    return guess


def hermite_motion(scene: Scene, robot: Robot, T: float) -> Guess:
    """Cubic Hermite q, dq, ddq from the initial to the final state (free entries: stay put,
    come to rest), the prescribed passive motion where the task tracks one."""
    task = scene.task
    q0, dq0 = np.asarray(task.initial.q), np.asarray(task.initial.dq)
    qf = np.array([q0[i] if v is None else v for i, v in enumerate(task.final.q)])
    dqf = np.array([0.0 if v is None else v for v in task.final.dq])
    cubic = PiecewisePolynomial(np.array([0.0, T]), hermite(np.stack([q0, qf]),
                                                            np.stack([dq0, dqf]), np.array([T])))

    def guess(x: np.ndarray) -> dict[str, np.ndarray]:
        t = np.asarray(x, float) * T
        q, dq, ddq = (cubic(t, derivative=order) for order in range(3))
        if task.tracking is not None:
            ref = task.tracking.motion.evaluate(t, T)
            for arr, r in zip((q, dq, ddq), ref, strict=True):
                arr[:, robot.passive] = r
        return {"q": q, "dq": dq, "ddq": ddq}

    return guess


ID_SAMPLES = 2001  # samples of the inverse-dynamics guess over the horizon
ID_THRESHOLD = 1e-3  # [kg m^2] its singular stop when the task sets no coupling margin


class _PassivePath:
    """The passive columns of a motion, as the path the classical inverse dynamics follows."""

    def __init__(self, motion: Guess, passive: list[int]):
        self.motion, self.passive = motion, passive

    def evaluate(self, t, duration: float):
        g = self.motion(np.atleast_1d(np.asarray(t, dtype=float)) / duration)
        return tuple(g[k][:, self.passive] for k in ("q", "dq", "ddq"))


def inverse_dynamics_guess(scene: Scene, robot: Robot, T: float) -> Guess:
    """The classical inverse dynamics along the interpolation guess's passive path (the
    prescribed motion where the task tracks one), from the task's initial active state:
    every knot it reaches satisfies all rows of the equations of motion. Where it stops,
    sigma_min(M_pa) having fallen to the task's coupling margin (1e-3 without one), the
    interpolation guess takes over for the rest of the horizon. Raises ValueError when the
    inverse dynamics overflows or runs past min(60 s, solver.max_wall_time)."""
    base = hermite_guess(scene, robot, T)
    q0, dq0 = np.asarray(scene.task.initial.q), np.asarray(scene.task.initial.dq)
    result = integrate(robot, _PassivePath(hermite_motion(scene, robot, T), robot.passive), T,
                       JointState(q=q0[robot.active].tolist(), dq=dq0[robot.active].tolist()),
                       ID_SAMPLES, scene.task.coupling_margin or ID_THRESHOLD,
                       wall_time=min(WALL_TIME, scene.solver.max_wall_time))
    reached = np.asarray(result.t) / T
    arrays = {k: np.asarray(getattr(result, k)) for k in ("q", "dq", "ddq", "tau")}

    def guess(x: np.ndarray) -> dict[str, np.ndarray]:
        out = base(x)
        if len(reached) < 2:
            return out
        inside = np.asarray(x) <= reached[-1]
        for k, a in arrays.items():
            out[k][inside] = np.stack([np.interp(np.asarray(x)[inside], reached, a[:, j])
                                       for j in range(a.shape[1])], axis=1)
        return out

    return guess


def interpolant_guess(interp: Interpolant, T: float) -> Guess:
    """A solved plan's own interpolant, for a solve of the same task on another mesh."""

    def guess(x: np.ndarray) -> dict[str, np.ndarray]:
        t = np.asarray(x, float) * T
        return {"q": interp.q(t), "dq": interp.dq(t), "ddq": interp.dq(t, derivative=1),
                "tau": interp.tau(t)}

    return guess


def stretched(guess: Guess, factor: float, robot: Robot) -> Guess:
    """The guess's motion run `factor` times as long: the same path, rates divided by the
    factor, accelerations by its square, and the torques the active rows of the dynamics
    ask for along it."""

    def out(x: np.ndarray) -> dict[str, np.ndarray]:
        g = guess(x)
        q, dq, ddq = g["q"], g["dq"] / factor, g["ddq"] / factor ** 2
        return {"q": q, "dq": dq, "ddq": ddq, "tau": _torques(robot, q, dq, ddq, robot.active)}

    return out


class Recorded(Protocol):
    """A motion recorded at its nodes: a plan, or a plan example's remembered motion
    (`planner.ocp.recall`)."""

    @property
    def duration(self) -> float: ...
    @property
    def t(self) -> list[float]: ...
    @property
    def q(self) -> list[list[float]]: ...
    @property
    def dq(self) -> list[list[float]]: ...
    @property
    def ddq(self) -> list[list[float]]: ...
    @property
    def tau(self) -> list[list[float]]: ...
    @property
    def torque(self) -> TorquePolynomial | None: ...


def plan_guess(plan: Recorded) -> Guess:
    """An earlier plan (`plan_interpolant`) over fractions of its duration."""
    return interpolant_guess(plan_interpolant(plan), plan.duration)


def plan_interpolant(plan: Recorded) -> Interpolant:
    """A plan's motion [s]: cubic Hermite angles and rates through its nodes, its delivered
    torque (the node torques, linearly interpolated, in plans stored without it)."""
    t = np.asarray(plan.t)
    q, dq, ddq = (np.asarray(getattr(plan, k)) for k in ("q", "dq", "ddq"))
    h = np.diff(t)
    if plan.torque is not None:
        tau = PiecewisePolynomial(np.asarray(plan.torque.breaks),
                                  np.asarray(plan.torque.coefficients))
    else:
        nodes = np.asarray(plan.tau)
        tau = PiecewisePolynomial(t, np.stack([nodes[:-1], nodes[1:] - nodes[:-1]], axis=1))
    return Interpolant(PiecewisePolynomial(t, hermite(q, dq, h)),
                       PiecewisePolynomial(t, hermite(dq, ddq, h)), tau)
