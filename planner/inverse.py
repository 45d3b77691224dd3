"""Classical inverse dynamics of an underactuated arm for a prescribed passive motion.

The passive joints follow q_p(t) of a reference profile. Their rows of the equations of
motion carry no torque,

    M_pp(q) ddq_p + M_pa(q) ddq_a + h_p(q, dq) = 0,

and are solved for the active accelerations ddq_a (uniquely when M_pa is square and
regular; the minimum-norm solution M_pa^T (M_pa M_pa^T)^-1 (...) when there are more
active than passive joints). The active state is integrated with scipy's DOP853 at the
requested tolerances and stops as soon as sigma_min(M_pa) falls to `sigma_threshold`:
there the active accelerations, and the torques, would grow without bound. The active
torques are then the active rows of M ddq + h.

Feeding the torques forward: the samples are exact point values (to the integration
tolerance) of a smooth torque. Interpolate them with the not-a-knot cubic spline of
`planner.simulate.torque_coefficients(t, tau, "cubic")`; its error falls as h^4 with the
sample spacing h, so the reproduced passive motion converges at fourth order (the
built-in examples, 200 samples per second, reproduce it to better than 1e-7 rad).
Near a singular stop the torques grow like 1 / sigma_min: a smaller `sigma_threshold`
gets closer to the singularity at the price of larger torques in the last samples.
"""

from __future__ import annotations

import time
from functools import lru_cache
from typing import Literal

import casadi as ca
import numpy as np
from pydantic import BaseModel, Field, model_validator
from scipy.integrate import solve_ivp

from planner import budget
from planner.coupling_block import CHUNK, along, measures
from planner.coupling_request import check_split
from planner.dynamics import derive, functions
from planner.errors import InputError
from planner.model import Robot, Structure, parameters
from planner.profiles import PassiveMotion, SampledProfile
from planner.schema import REQUEST as _STRICT
from planner.schema import Duration, JointState

RESOLUTION = 1e-8
"""Smallest sigma_min(M_pa) / max_i M_ii the integration follows. The entries of M carry
rounding of about 1e-16 max_i M_ii, and the active accelerations divide by sigma_min, so
closer to the singularity the right-hand side is noise at the tolerance's scale and
DOP853's steps collapse (docs/stability.md, "Near-singular configurations"). The motion
stops at this floor when it lies above `sigma_threshold`, and says so."""

WALL_TIME = 60.0
"""[s] Longest the integration may run. A motion far too fast for its duration (rates of
1e200 rad/s, say) leaves every number finite but makes DOP853 take astronomically many
steps; past this budget the request is refused as such instead of holding a thread."""


_SCALE_DOWN = "scale down passive_motion, its rates over duration, or active_initial"
"""What to do about a motion too fast or too large to integrate."""


ACTIVE_INITIAL = "the active joints' angles and rates at t = 0, in joint order"
"""What an `active_initial` state holds."""


class _OverBudget(Exception):
    """The integration ran past its wall-time budget."""


class InverseDynamicsRequest(BaseModel):
    """A prescribed passive motion over [0, duration] and the active joints' initial state."""

    model_config = _STRICT

    robot: Robot
    passive_motion: PassiveMotion
    duration: Duration = Field(description="T [s], within [0.01, 10000] s")
    active_initial: JointState = Field(description=ACTIVE_INITIAL)
    samples: int = Field(default=201, ge=2, le=100_000,
                         description="output samples, evenly spaced over [0, T]")
    sigma_threshold: float = Field(default=1e-3, gt=0.0,
                                   description="stop where sigma_min(M_pa) < this [kg m^2]")
    rtol: float = Field(default=1e-10, ge=1e-13, le=1e-3, description="relative tolerance")
    atol: float = Field(default=1e-10, ge=1e-13, le=1e-3, description="absolute tolerance")

    @model_validator(mode="after")
    def _consistent(self) -> InverseDynamicsRequest:
        check_motion(self.robot, self.passive_motion, self.duration, self.active_initial)
        return self


def check_prescribable(robot: Robot) -> None:
    """Raise InputError when the robot has no passive joint, or too few active joints
    for M_pa to have full row rank."""
    check_split(robot)
    n_p, n_a = len(robot.passive), len(robot.active)
    if n_a < n_p:
        raise InputError(f"robot: fewer active joints ({n_a}) than passive joints ({n_p}): "
                         "M_pa never has full row rank, so the passive motion cannot be "
                         "prescribed")


def check_motion(robot: Robot, motion, duration: float, initial: JointState,
                 prefix: str = "") -> None:
    """Raise InputError unless the motion and initial state fit the robot's joints."""
    check_prescribable(robot)
    n_p, n_a = len(robot.passive), len(robot.active)
    if motion.n != n_p:
        raise InputError(f"{prefix}passive_motion: needs {n_p} angle{'s' * (n_p > 1)} "
                         "per time, one per passive joint")
    if isinstance(motion, SampledProfile) and not np.isclose(
            motion.t[-1], duration, rtol=1e-12, atol=0.0):
        raise InputError(f"{prefix}passive_motion.t: must end at duration ({duration:g} s)")
    if len(initial.q) != n_a or len(initial.dq) != n_a:
        raise InputError(f"{prefix}active_initial: q and dq need {n_a} "
                         f"entr{'ies' if n_a > 1 else 'y'} each, one per active joint")


class Singularity(BaseModel):
    """Where the motion reached sigma_min(M_pa) = threshold: time [s], all angles [rad]."""

    time: float
    q: list[float]
    sigma_min: float


class InverseDynamicsResult(BaseModel):
    """The motion and active torques at the samples reached, time-major.

    q, dq, ddq hold every joint; tau the active joints' torques [N m]; sigma_min the
    coupling measure [kg m^2] at each sample. On a singular stop the samples end at the
    last sample before the stop plus the stop itself (none if the start is singular).
    """

    status: Literal["completed", "singular"]
    t: list[float]
    q: list[list[float]]
    dq: list[list[float]]
    ddq: list[list[float]]
    tau: list[list[float]]
    sigma_min: list[float]
    singularity: Singularity | None
    interpolation: Literal["cubic"] = Field(
        default="cubic", description="how to interpolate tau when feeding it forward")
    message: str


@lru_cache(maxsize=64)
def active_acceleration(s: Structure) -> ca.Function:
    """ddq_a(q, dq, ddq_p, p) from the passive rows (minimum norm when non-square)."""
    sym = derive(s)
    P, A = s.passive_idx, s.active_idx
    ddq_p = ca.SX.sym("ddq_p", len(P))
    mpa = sym.mass[P, A]
    rhs = -(ca.mtimes(sym.mass[P, P], ddq_p) + sym.bias[P])
    if len(P) == len(A):
        ddq_a = ca.solve(mpa, rhs)
    else:
        ddq_a = ca.mtimes(mpa.T, ca.solve(ca.mtimes(mpa, mpa.T), rhs))
    return ca.Function("ddq_a", [sym.q, sym.dq, ddq_p, sym.p], [ddq_a],
                       ["q", "dq", "ddq_p", "p"], ["ddq_a"])


class _Problem:
    """The active-state ODE x_a' = (dq_a, ddq_a) along a prescribed passive motion (any
    object with `evaluate(t, duration) -> (q, dq, ddq)`)."""

    def __init__(self, robot: Robot, motion, duration: float, threshold: float,
                 wall_time: float | None = None, deadline: float | None = None):
        self.robot = robot
        self.s = Structure.of(self.robot)
        self.p = parameters(self.robot, self.s)
        self.P, self.A = self.s.passive_idx, self.s.active_idx
        self.motion, self.T = motion, duration
        self.accel = active_acceleration(self.s)
        self.mass = functions(self.s)["M"]
        self.threshold = threshold
        self.wall_time = WALL_TIME if wall_time is None else wall_time
        self.deadline = time.monotonic() + self.wall_time
        self.budget = deadline  # the caller's, apart from the motion's own wall time

    def full(self, t, xa: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All joints' q, dq and the passive ddq at times t (K,) for active states (K, 2 na)."""
        qp, dqp, ddqp = self.motion.evaluate(np.atleast_1d(t), self.T)
        na, K = len(self.A), len(qp)
        q, dq = np.empty((K, self.s.n)), np.empty((K, self.s.n))
        q[:, self.P], dq[:, self.P] = qp, dqp
        q[:, self.A], dq[:, self.A] = xa[:, :na], xa[:, na:]
        return q, dq, ddqp

    def rhs(self, t: float, x: np.ndarray) -> np.ndarray:
        budget.check(self.budget, f"the inverse dynamics (at t = {t:.6g} s of {self.T:g} s)")
        if time.monotonic() > self.deadline:
            raise _OverBudget
        q, dq, ddqp = self.full(t, x[None, :])
        ddq_a = np.array(self.accel(q[0], dq[0], ddqp[0], self.p)).ravel()
        return np.concatenate([x[len(self.A):], ddq_a])

    def sigma(self, t: float, x: np.ndarray) -> tuple[float, float]:
        """sigma_min(M_pa) and the level where the motion stops, max(threshold,
        RESOLUTION max_i M_ii), both [kg m^2], at time t and active state x."""
        q, _, _ = self.full(t, x[None, :])
        mass = np.array(self.mass(q[0], self.p))
        block = mass[np.ix_(self.P, self.A)]
        level = max(self.threshold, RESOLUTION * float(np.diag(mass).max()))
        return float(measures(block[None]).sigma_min[0]), level


class _SigmaEvent:
    """solve_ivp's event where sigma_min(M_pa) falls through its level (terminal: the
    integration stops there)."""

    terminal = True
    direction = -1.0

    def __init__(self, pb: _Problem):
        self.pb = pb

    def __call__(self, t: float, x: np.ndarray) -> float:
        sigma, level = self.pb.sigma(t, x)
        return sigma - level


def solve(request: InverseDynamicsRequest, *,
          deadline: float | None = None) -> InverseDynamicsResult:
    """Active motion and torques for the prescribed passive motion, or the singular stop
    (BudgetExceeded past `deadline`, a `time.monotonic()` value)."""
    return integrate(request.robot, request.passive_motion, request.duration,
                     request.active_initial, request.samples, request.sigma_threshold,
                     request.rtol, request.atol, deadline=deadline)


def integrate(robot: Robot, motion, duration: float, active_initial: JointState,
              samples: int, sigma_threshold: float, rtol: float = 1e-10,
              atol: float = 1e-10, wall_time: float | None = None, *,
              deadline: float | None = None) -> InverseDynamicsResult:
    """`solve` for an already checked robot and motion; the motion may be any object with
    `evaluate(t, duration) -> (q, dq, ddq)` of the passive joints. Past wall_time [s] of
    integration (default WALL_TIME) it raises InputError, as it does when the results
    overflow; past `deadline` (`time.monotonic()`) BudgetExceeded."""
    pb = _Problem(robot, motion, duration, sigma_threshold, wall_time, deadline)
    x0 = np.concatenate([active_initial.q, active_initial.dq])
    grid = np.linspace(0.0, duration, samples)
    sigma0, level0 = pb.sigma(0.0, x0)
    if sigma0 < level0:
        q0, _, _ = pb.full(0.0, x0[None, :])
        return _result("singular", pb, np.empty(0), np.empty((0, len(x0))),
                       Singularity(time=0.0, q=q0[0].tolist(), sigma_min=sigma0),
                       f"sigma_min(M_pa) = {sigma0:.3g} < {level0:.3g} at the start"
                       + _floor_note(pb, level0))

    try:
        sol = solve_ivp(pb.rhs, (0.0, duration), x0, method="DOP853", dense_output=True,
                        rtol=rtol, atol=atol, events=_SigmaEvent(pb))
    except _OverBudget:
        raise InputError(f"the inverse dynamics did not finish within {pb.wall_time:g} s: the "
                         f"motion is far too fast for its duration; {_SCALE_DOWN}") from None
    dense = sol.sol
    assert dense is not None  # dense_output=True
    if sol.status == 0:
        return _result("completed", pb, grid, dense(grid).T, None, "completed")

    t_stop = float(sol.t[-1])
    x_stop = sol.y[:, -1]
    times = np.append(grid[grid < t_stop], t_stop)
    states = np.vstack([dense(times[:-1]).T, x_stop]) if len(times) > 1 else x_stop[None, :]
    q_stop, _, _ = pb.full(t_stop, x_stop[None, :])
    sigma_stop, level = pb.sigma(t_stop, x_stop)
    floor = level > pb.threshold
    why = (f"sigma_min(M_pa) fell to the {'resolution floor' if floor else 'threshold'}"
           if sol.status == 1 else
           f"the integrator stopped ({sol.message}) as the accelerations grew")
    singular = Singularity(time=t_stop, q=q_stop[0].tolist(), sigma_min=sigma_stop)
    return _result("singular", pb, times, states, singular,
                   f"{why} at t = {t_stop:.6g} s (sigma_min = {sigma_stop:.3g})"
                   + _floor_note(pb, level))


def _floor_note(pb: _Problem, level: float) -> str:
    """Why the motion stopped above sigma_threshold, when it did."""
    if level <= pb.threshold:
        return ""
    return (f"; the floor is {RESOLUTION:g} of the largest diagonal entry of M, above "
            f"sigma_threshold = {pb.threshold:.3g}: closer to the singularity rounding "
            "swamps the accelerations")


def _result(status, pb: _Problem, t: np.ndarray, xa: np.ndarray,
            singularity: Singularity | None, message: str) -> InverseDynamicsResult:
    """Complete the samples with the passive motion, accelerations, torques and sigma_min."""
    if len(t) == 0:
        return InverseDynamicsResult(status=status, t=[], q=[], dq=[], ddq=[], tau=[],
                                     sigma_min=[], singularity=singularity, message=message)
    q, dq, ddqp = pb.full(t, xa)
    ddq, tau = _torques(pb, q, dq, ddqp)
    sigma = along(pb.robot, q, pb.s, pb.budget).sigma_min
    arrays = (q, dq, ddq, tau, sigma)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise InputError(f"the inverse dynamics of this motion overflow (values too large): "
                         f"{_SCALE_DOWN}")
    return InverseDynamicsResult(status=status, t=t.tolist(), q=q.tolist(), dq=dq.tolist(),
                                 ddq=ddq.tolist(), tau=tau.tolist(), sigma_min=sigma.tolist(),
                                 singularity=singularity, message=message)


def _torques(pb: _Problem, q: np.ndarray, dq: np.ndarray,
             ddqp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All joints' accelerations (K, n) [rad/s^2] and the active torques (K, na) [N m] at
    the samples (q, dq (K, n), passive ddq (K, np)), CHUNK samples per call with the
    caller's deadline checked before each."""
    ddq = np.empty(q.shape)
    ddq[:, pb.P] = ddqp
    tau = np.empty((len(q), len(pb.A)))
    inverse = functions(pb.s)["id"]
    for part in budget.chunks(len(q), CHUNK, pb.budget, "the inverse dynamics' torques",
                              "sample"):
        size, Q, dQ = part.stop - part.start, q[part].T, dq[part].T
        ddq[part, pb.A] = np.array(pb.accel.map(size)(Q, dQ, ddqp[part].T, pb.p)).T
        tau[part] = np.array(inverse.map(size)(Q, dQ, ddq[part].T, pb.p)).T[:, pb.A]
    return ddq, tau
