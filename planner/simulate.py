"""Forward simulation of given torques with CasADi's CVODES.

Torques are piecewise polynomials in time: on interval k, with s = (t - t_k) / (t_{k+1} - t_k)
in [0, 1], tau(t) = sum_j coeffs[k, j] s^j (one column per active joint, N m). Zero-order
hold, linear and cubic-spline interpolation of samples are special cases.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.interpolate import CubicSpline

from planner.dynamics import functions
from planner.model import Robot, Structure, parameters

Interpolation = Literal["zoh", "linear", "cubic"]

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


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
def _integrator(s: Structure, degree: int, n_out: int, rtol: float, atol: float) -> ca.Function:
    """CVODES over one interval in normalised time s in [0, 1], outputs at n_out points."""
    f = functions(s)["ode"]
    na = len(s.active_idx)
    x = ca.SX.sym("x", 2 * s.n)
    sn = ca.SX.sym("s")
    coeffs = ca.SX.sym("c", (degree + 1) * na)
    p = ca.SX.sym("p", s.n_params)
    h = ca.SX.sym("h")
    tau = sum(coeffs[j * na:(j + 1) * na] * sn**j for j in range(degree + 1))
    dae = {"x": x, "t": sn, "p": ca.vertcat(p, coeffs, h), "ode": h * f(x, tau, p)}
    grid = np.linspace(0.0, 1.0, n_out + 1)[1:]
    opts = {"abstol": atol, "reltol": rtol, "max_num_steps": 200000, "show_eval_warnings": False}
    return ca.integrator("sim", "cvodes", dae, 0.0, list(grid), opts)


def simulate(robot: Robot, breakpoints, coeffs, x0, samples_per_interval: int = 1,
             rtol: float = 1e-10, atol: float = 1e-10) -> Trajectory:
    """Integrate M ddq + h = B tau from x0 = (q, dq) under piecewise-polynomial torques.

    Returns the state at every breakpoint and `samples_per_interval - 1` points between.
    A failed integration returns what was reached with status "failed".
    """
    s = Structure.of(robot)
    p = parameters(robot, s)
    tk = np.asarray(breakpoints, float)
    coeffs = np.asarray(coeffs, float)
    K, degree = coeffs.shape[0], coeffs.shape[1] - 1
    sim = _integrator(s, degree, samples_per_interval, rtol, atol)
    x = np.asarray(x0, float)
    times, states = [tk[0]], [x]
    for k in range(K):
        h = tk[k + 1] - tk[k]
        try:
            out = sim(x0=x, p=np.concatenate([p, coeffs[k].ravel(), [h]]))
        except RuntimeError as exc:
            return _trajectory(times, states, s.n, "failed",
                               f"integration failed at t = {tk[k]:.6g} s: {exc}")
        xf = np.array(out["xf"])
        if not np.all(np.isfinite(xf)):
            return _trajectory(times, states, s.n, "failed",
                               f"the state became non-finite after t = {tk[k]:.6g} s")
        times += list(tk[k] + h * np.linspace(0, 1, samples_per_interval + 1)[1:])
        states += list(xf.T)
        x = xf[:, -1]
    return _trajectory(times, states, s.n, "completed", "")


def _trajectory(times, states, n, status, message) -> Trajectory:
    X = np.asarray(states)
    return Trajectory(t=list(map(float, times)), q=X[:, :n].tolist(), dq=X[:, n:].tolist(),
                      status=status, message=message)


class SimulationRequest(BaseModel):
    """Torque samples of the active joints, their interpolation, and the initial state."""

    model_config = _STRICT

    robot: Robot
    t: list[float] = Field(min_length=2, description="strictly increasing sample times [s]")
    tau: list[list[float]] = Field(description="active torques at each time [N m]")
    interpolation: Interpolation = "linear"
    initial: "InitialState"
    samples_per_interval: int = Field(default=1, ge=1, le=100)
    rtol: float = Field(default=1e-10, ge=1e-14, le=1e-2)
    atol: float = Field(default=1e-10, ge=1e-14, le=1e-2)

    @model_validator(mode="after")
    def _consistent(self) -> SimulationRequest:
        na, n = len(self.robot.active), self.robot.n
        if any(b <= a for a, b in zip(self.t, self.t[1:])):
            raise ValueError("t: must be strictly increasing")
        if len(self.tau) != len(self.t):
            raise ValueError(f"tau: needs {len(self.t)} rows, one per time in t")
        if any(len(row) != na for row in self.tau):
            raise ValueError(f"tau: every row needs {na} entries, one per active joint")
        if len(self.initial.q) != n or len(self.initial.dq) != n:
            raise ValueError(f"initial: q and dq need {n} entries each")
        return self


class InitialState(BaseModel):
    """Joint angles [rad] and rates [rad/s] at t[0]."""

    model_config = _STRICT

    q: list[float]
    dq: list[float]


SimulationRequest.model_rebuild()


def run(request: SimulationRequest) -> Trajectory:
    """Simulate a request: interpolate its torques and integrate from its initial state."""
    coeffs = torque_coefficients(np.asarray(request.t), np.asarray(request.tau), request.interpolation)
    x0 = np.concatenate([request.initial.q, request.initial.dq])
    return simulate(request.robot, request.t, coeffs, x0, request.samples_per_interval,
                    request.rtol, request.atol)
