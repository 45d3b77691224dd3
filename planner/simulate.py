"""Forward simulation of given torques with CasADi's CVODES.

Torques are piecewise polynomials in time: on interval k, with s = (t - t_k) / (t_{k+1} - t_k)
in [0, 1], tau(t) = sum_j coeffs[k, j] s^j (one column per active joint, N m). Zero-order
hold, linear and cubic-spline interpolation of samples are special cases.

CVODES integrates each interval with the variable-order Adams-Moulton method and
functional iteration (method "adams", the default): the arm is conservative and
oscillatory, not stiff, and on every robot measured Adams drifts less in energy than BDF
(median about 10x less) at 0.3-0.7 of its CPU time (docs/bench-simulate.md). Method
"bdf" (BDF with Newton iteration) remains available for stiff problems.
"""

from __future__ import annotations

import itertools
import math
import re
from functools import lru_cache
from typing import Any, Literal

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator
from scipy.interpolate import CubicSpline

from planner import budget
from planner.dynamics import functions
from planner.exclusive import Exclusive
from planner.model import Robot, Structure, parameters
from planner.schema import REQUEST as _STRICT
from planner.schema import JointState
from planner.torque import TorquePolynomial

Interpolation = Literal["zoh", "linear", "cubic"]
Method = Literal["adams", "bdf"]

MAX_STEPS = 200_000
"""CVODES steps to one output, at most."""
SLICE_STEPS = 5_000
"""CVODES steps of one call under a deadline (0.2 s on an 8-link arm): the deadline is
checked at least this often (`_output`)."""
METHODS: dict[str, dict[str, str]] = {
    "adams": {"linear_multistep_method": "adams", "nonlinear_solver_iteration": "functional"},
    "bdf": {"linear_multistep_method": "bdf", "nonlinear_solver_iteration": "newton"},
}
"""CVODES' options of each method."""
_FAILURES = {
    "CV_TOO_MUCH_WORK": f"more than {MAX_STEPS} steps before the next output "
                        "(the motion is too fast for the tolerances)",
    "CV_TOO_MUCH_ACC": "the tolerances are finer than double precision allows",
    "CV_ERR_FAILURE": "the error test failed repeatedly (the motion is too fast)",
    "CV_CONV_FAILURE": "the corrector did not converge (the motion is too fast)",
    "CV_ILL_INPUT": "the state or its rate is not finite (values too large)",
    "CV_FIRST_RHSFUNC_ERR": "the dynamics are not finite at the start of the interval "
                            "(values too large)",
    "CV_REPTD_RHSFUNC_ERR": "the dynamics became non-finite (values too large)",
    "CV_UNREC_RHSFUNC_ERR": "the dynamics became non-finite (values too large)",
    "CV_BAD_T": "the integrator stopped short of the output time (values too large)",
}


class Trajectory(BaseModel):
    """A simulated motion: times [s], angles [rad] and rates [rad/s], time-major."""

    model_config = ConfigDict(frozen=True)

    t: list[float]
    q: list[list[float]]
    dq: list[list[float]]
    status: Literal["completed", "failed"] = "completed"
    message: str = ""


def torque_coefficients(t: np.ndarray, tau: np.ndarray, kind: Interpolation) -> np.ndarray:
    """Piecewise-polynomial coefficients (K, degree + 1, n_active) through torque samples."""
    t, tau = np.asarray(t, float), np.asarray(tau, float).reshape(len(t), -1)
    if kind == "zoh":
        return tau[:-1, None, :]
    if kind == "linear":
        return np.stack([tau[:-1], tau[1:] - tau[:-1]], axis=1)
    spline = CubicSpline(t, tau, bc_type="not-a-knot")
    h = np.diff(t)[:, None]
    c = spline.c  # (4, K, na), descending powers of (t - t_k)
    return np.stack([c[3], c[2] * h, c[1] * h**2, c[0] * h**3], axis=1)


@lru_cache(maxsize=64)
def _integrator(s: Structure, degree: int, n_out: int, rtol: float, atol: float,
                method: Method, max_steps: int = MAX_STEPS) -> Exclusive:
    """CVODES over one interval in normalised time s in [0, 1], outputs at n_out points,
    at most `max_steps` steps to each.

    A clock quadrature (ds/ds = 1, outside the error control) is read at every output:
    CVODES can stop at s = 0 without an error (torques near the largest double), and
    reading the clock at an output never reached then fails (CV_BAD_T) instead of
    returning the initial state as the result."""
    f = functions(s)["ode"]
    na = len(s.active_idx)
    x = ca.SX.sym("x", 2 * s.n)
    sn = ca.SX.sym("s")
    coeffs = ca.SX.sym("c", (degree + 1) * na)
    p = ca.SX.sym("p", s.n_params)
    h = ca.SX.sym("h")
    tau = sum(coeffs[j * na:(j + 1) * na] * sn**j for j in range(degree + 1))
    dae: dict[str, Any] = {"x": x, "t": sn, "p": ca.vertcat(p, coeffs, h),
                           "ode": h * f(x, tau, p), "quad": 1}
    grid = np.linspace(0.0, 1.0, n_out + 1)[1:]
    opts: dict[str, Any] = {"abstol": atol, "reltol": rtol, "max_num_steps": max_steps,
                            "show_eval_warnings": False, "disable_internal_warnings": True,
                            **METHODS[method]}
    return Exclusive(ca.integrator("sim", "cvodes", dae, 0.0, list(grid), opts))


def _reason(error: RuntimeError) -> str:
    """What CVODES reported, in words."""
    flag = re.search(r'CVode\w* returned "(\w+)"', str(error))
    if flag is None:
        return str(error).strip().splitlines()[-1]
    return f"{_FAILURES.get(flag[1], 'the integrator stopped')} (CVODES {flag[1]})"


def simulate(robot: Robot, breakpoints, coeffs, x0, samples_per_interval: int = 1,
             rtol: float = 1e-10, atol: float = 1e-10, *, method: Method = "adams",
             deadline: float | None = None, feedback: ClosedLoop | None = None) -> Trajectory:
    """Integrate M ddq + h = B tau from x0 = (q, dq) under piecewise-polynomial torques.

    breakpoints (K + 1,) [s]; coeffs (K, degree + 1, n_active) as in `torque_coefficients`.
    feedback: on interval k the torque is tau(t) - K_k (x(t_k) - x_ref(t_k)), the
    correction held over the interval (a plan's LQR feedback, `ClosedLoop`).
    Returns the state at every breakpoint and `samples_per_interval - 1` points between.
    A failed integration does not raise: it returns what was reached with status
    "failed" and a message saying in which interval and why.

    With a `deadline` (`time.monotonic()`) every output is integrated on its own (the
    interval's torque polynomial restricted to it) in CVODES calls of at most SLICE_STEPS
    steps, each checked against the deadline before it starts, so that past it
    BudgetExceeded comes after at most SLICE_STEPS steps; without one, one call
    integrates a whole interval.
    """
    s = Structure.of(robot)
    p = parameters(robot, s)
    tk, coeffs = np.asarray(breakpoints, float), np.asarray(coeffs, float)
    K, degree = coeffs.shape[0], coeffs.shape[1] - 1
    pieces = 1 if deadline is None else samples_per_interval
    per_call = samples_per_interval // pieces
    sim = _integrator(s, degree, per_call, rtol, atol, method,
                      MAX_STEPS if deadline is None else SLICE_STEPS)
    x = np.asarray(x0, float)
    times, states = [tk[0]], [x]
    for k in range(K):
        h, start = tk[k + 1] - tk[k], x
        where = f"between t = {tk[k]:.6g} s and t = {tk[k + 1]:.6g} s"
        outputs = tk[k] + h * np.linspace(0, 1, samples_per_interval + 1)[1:]
        for j in range(pieces):
            c = _restricted(coeffs[k], j / pieces, 1 / pieces)
            if feedback is not None:
                c = c.copy()
                c[0] -= feedback.correction(k, start)
            try:
                xf = _output(sim, x, p, c, (tk[k] + h * j / pieces, h / pieces, tk[-1]),
                             deadline)
            except RuntimeError as exc:
                return _trajectory(times, states, s.n, "failed",
                                   f"integration failed {where}: {_reason(exc)}")
            if not np.all(np.isfinite(xf)):
                return _trajectory(times, states, s.n, "failed",
                                   f"the state became non-finite {where}")
            times += list(outputs[j * per_call:(j + 1) * per_call])
            states += list(xf.T)
            x = xf[:, -1]
    return _trajectory(times, states, s.n, "completed", "")


def _output(sim: Exclusive, x: np.ndarray, p: np.ndarray, c: np.ndarray,
            span: tuple[float, float, float], deadline: float | None) -> np.ndarray:
    """The states (2n, outputs) of one CVODES call from x under the torque polynomial c
    (degree + 1, na) over span = (start, length, end of the simulation) [s].

    With a deadline there is one output, reached slice by slice in calls of at most
    SLICE_STEPS steps, each checked against the deadline before it starts: a slice that
    needs more is halved, and the next one sized by the steps the last one took. Raises
    RuntimeError (CVODES' CV_TOO_MUCH_WORK) once the slices have taken more than MAX_STEPS
    steps, those of the halved ones included."""
    t0, h, end = span
    if deadline is None:
        out, _ = sim(None, x0=x, p=np.concatenate([p, c.ravel(), [h]]))
        return np.array(out["xf"])
    at, width, spent = 0.0, 1.0, 0
    while True:
        last = width >= 1.0 - at
        width = min(width, 1.0 - at)
        what = f"the simulation (at t = {t0 + h * at:.6g} s of {end:.6g} s)"
        budget.check(deadline, what)
        part = np.concatenate([p, _restricted(c, at, width).ravel(), [h * width]])
        try:
            out, stats = sim(deadline, what, x0=x, p=part)
        except RuntimeError as exc:
            spent += SLICE_STEPS
            if "CV_TOO_MUCH_WORK" not in str(exc) or spent > MAX_STEPS:
                raise
            width /= 2
            continue
        steps = max(int(stats["nsteps"]), 1)
        spent += steps
        x = np.array(out["xf"])[:, -1]
        if last or not np.all(np.isfinite(x)):
            return x[:, None]
        if spent > MAX_STEPS:  # what one call would have said at its MAX_STEPS-th step
            raise RuntimeError('CVode returned "CV_TOO_MUCH_WORK"')
        at += width
        width *= SLICE_STEPS / (2 * steps)  # the next slice: about half the steps allowed


def _restricted(c: np.ndarray, start: float, width: float) -> np.ndarray:
    """Coefficients (degree + 1, n_active) of sum_j c[j] s^j on s in [start, start + width],
    in the local u = (s - start) / width in [0, 1]."""
    if start == 0.0 and width == 1.0:
        return c
    out = np.zeros_like(c)
    for j in range(len(c)):
        for m in range(j + 1):
            out[m] += math.comb(j, m) * start ** (j - m) * width**m * c[j]
    return out


def _trajectory(times, states, n, status, message) -> Trajectory:
    X = np.asarray(states)
    return Trajectory(t=list(map(float, times)), q=X[:, :n].tolist(), dq=X[:, n:].tolist(),
                      status=status, message=message)


class ClosedLoop(BaseModel):
    """A tracking feedback, applied at the torque's breakpoints t_k: on interval k the torque
    is tau(t) - K_k (x(t_k) - x_ref(t_k)), x = (q, dq) the simulated state at t_k, the
    correction held until t_{k+1}. A plan's `feedback.gains` with its `q` and `dq` (at its
    `t`, the breakpoints of its `torque`) are one."""

    model_config = _STRICT

    gains: list[list[list[float]]] = Field(
        description="K_k for every interval: n_active x 2n [N m/rad, N m s/rad]")
    q: list[list[float]] = Field(description="reference angles at every breakpoint [rad]")
    dq: list[list[float]] = Field(description="reference rates at every breakpoint [rad/s]")

    def correction(self, k: int, x: np.ndarray) -> np.ndarray:
        """K_k (x - x_ref(t_k)) [N m] for the state x (2n,) at breakpoint k."""
        reference = np.concatenate([self.q[k], self.dq[k]])
        return np.asarray(self.gains[k]) @ (np.asarray(x) - reference)

    def check(self, intervals: int, n: int, na: int) -> None:
        """ValueError naming the first field whose shape disagrees with the torque's
        intervals and the robot's n joints, na of them active."""
        if len(self.gains) != intervals:
            raise ValueError(f"gains: needs {intervals} matrices, one per interval "
                             f"(got {len(self.gains)})")
        for k, K in enumerate(self.gains):
            if len(K) != na or any(len(row) != 2 * n for row in K):
                raise ValueError(f"gains.{k}: needs {na} rows of {2 * n} entries")
        for name in ("q", "dq"):
            rows = getattr(self, name)
            if len(rows) != intervals + 1 or any(len(r) != n for r in rows):
                raise ValueError(f"{name}: needs {intervals + 1} rows of {n} entries, one "
                                 f"per breakpoint")


class SimulationRequest(BaseModel):
    """The torques of the active joints, as samples with their interpolation or as a
    piecewise polynomial, and the initial state."""

    # Rules that read other fields (tau against t and the robot, initial against the robot)
    # run only when those fields are valid, and report at the field they check.
    model_config = _STRICT

    robot: Robot
    t: list[float] | None = Field(
        default=None, min_length=2,
        description="strictly increasing sample times [s] of `tau` (or give `torque`)")
    tau: list[list[float]] | None = Field(
        default=None, description="active torques at each time of `t` [N m]")
    interpolation: Interpolation = "linear"
    torque: TorquePolynomial | None = Field(
        default=None, description="the torques as a piecewise polynomial, simulated as they "
                                  "are (a plan's `torque`), instead of `t` and `tau`")
    initial: JointState = Field(description="the state at the first time, one entry per "
                                            "joint")
    samples_per_interval: int = Field(default=1, ge=1, le=100)
    feedback: ClosedLoop | None = Field(
        default=None, description="a tracking feedback on top of the torques (closed loop; "
                                  "docs/api.md, \"The feedback law\")")
    rtol: float = Field(default=1e-10, ge=1e-14, le=1e-2)
    atol: float = Field(default=1e-10, ge=1e-14, le=1e-2)

    @property
    def breaks(self) -> list[float]:
        """The interval boundaries [s]: the sample times, or the polynomial's breaks."""
        if self.torque is not None:
            return self.torque.breaks
        assert self.t is not None  # the request holds one of t and torque
        return self.t

    @property
    def output_samples(self) -> int:
        """Samples of the trajectory `run` returns: (intervals) * samples_per_interval + 1."""
        return (len(self.breaks) - 1) * self.samples_per_interval + 1

    @field_validator("t")
    @classmethod
    def _increasing(cls, t: list[float] | None) -> list[float] | None:
        if t is not None and any(b <= a for a, b in itertools.pairwise(t)):
            raise ValueError("must be strictly increasing")
        return t

    @field_validator("tau")
    @classmethod
    def _one_row_per_time(cls, tau: list[list[float]] | None,
                          info: ValidationInfo) -> list[list[float]] | None:
        t, robot = info.data.get("t"), info.data.get("robot")
        if tau is None:
            return tau
        if t is not None and len(tau) != len(t):
            raise ValueError(f"needs {len(t)} rows, one per time in t (got {len(tau)})")
        if robot is not None:
            na = len(robot.active)
            for k, row in enumerate(tau):
                if len(row) != na:
                    raise ValueError(f"every row needs {na} {'entry' if na == 1 else 'entries'}, "
                                     f"one per active joint (row {k} has {len(row)})")
        return tau

    @field_validator("torque")
    @classmethod
    def _one_column_per_active_joint(cls, torque: TorquePolynomial | None,
                                     info: ValidationInfo) -> TorquePolynomial | None:
        robot = info.data.get("robot")
        if torque is not None and robot is not None and torque.joints != len(robot.active):
            raise ValueError(f"coefficients: every power needs {len(robot.active)} entries, one "
                             f"per active joint (got {torque.joints})")
        return torque

    @model_validator(mode="after")
    def _one_torque(self) -> SimulationRequest:
        given = [name for name in ("t", "tau", "torque") if getattr(self, name) is not None]
        if given not in (["t", "tau"], ["torque"]):
            raise ValueError(f"give either t and tau, or torque (got {', '.join(given) or 'none'})")
        if self.feedback is not None:
            try:
                self.feedback.check(len(self.breaks) - 1, self.robot.n, len(self.robot.active))
            except ValueError as exc:
                raise ValueError(f"feedback.{exc}") from None
        return self

    @field_validator("initial")
    @classmethod
    def _one_per_joint(cls, initial: JointState, info: ValidationInfo) -> JointState:
        robot = info.data.get("robot")
        if robot is None:
            return initial
        for name in ("q", "dq"):
            got = len(getattr(initial, name))
            if got != robot.n:
                raise ValueError(f"{name}: needs {robot.n} entries, one per joint (got {got})")
        return initial


def run(request: SimulationRequest, *, deadline: float | None = None) -> Trajectory:
    """Simulate a request: interpolate its torques and integrate from its initial state
    (BudgetExceeded past `deadline`, a `time.monotonic()` value)."""
    if request.torque is not None:
        coeffs = request.torque.array()
    else:
        coeffs = torque_coefficients(np.asarray(request.t), np.asarray(request.tau),
                                     request.interpolation)
    x0 = np.concatenate([request.initial.q, request.initial.dq])
    return simulate(request.robot, request.breaks, coeffs, x0, request.samples_per_interval,
                    request.rtol, request.atol, deadline=deadline, feedback=request.feedback)
