"""planner.simulate: CVODES forward simulation of piecewise-polynomial torques.

- energy: under zero torque, E = T + V stays constant to 1e-8 (relative) over 5 s, on
  random robots and on a heavy-light arm with fast waves where BDF drifts 4e-8;
- agreement: each interval matches SciPy's DOP853 (rtol = atol = 1e-12) restarted at its
  breakpoint from the simulated state, with torques from SciPy's own interpolants and
  accelerations from the d'Alembert reference of conftest (no CasADi), to 1e-8;
- torque_coefficients reproduces the samples (zoh, linear) and SciPy's CubicSpline;
- a failed integration returns status "failed" with a message, and SimulationRequest
  reports each mistake at its field with an exact message.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import point_mass_dynamics
from pydantic import ValidationError
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline, interp1d

from planner.dynamics import Dynamics
from planner.model import Robot
from planner.simulate import SimulationRequest, run, simulate, torque_coefficients
from testbed.robots import random_robot, random_state

DURATION, OUTPUTS, TOL, DRIFT = 5.0, 100, 1e-12, 1e-8


def drift(robot: Robot, q: list, dq: list) -> float:
    """max |E - E(0)| / (T(0) + |V(0)|) along the states."""
    dyn = Dynamics(robot)
    energies = np.array([dyn.energy(a, b) for a, b in zip(q, dq, strict=True)])
    total = energies.sum(axis=1)
    return float(np.max(np.abs(total - total[0])) / (energies[0, 0] + abs(energies[0, 1])))


@pytest.mark.parametrize(("n", "gravity", "rotational"), [
    (1, 9.81, "absolute"), (2, 9.81, "cumulative"), (3, 0.0, "absolute"),
    (5, 9.81, "absolute"), (8, 9.81, "cumulative"),
])
def test_free_motion_conserves_energy(rng, n, gravity, rotational):
    robot = random_robot(rng, n, gravity=gravity, rotational=rotational)
    q, dq = random_state(rng, n)
    zero = np.zeros((1, 1, len(robot.active)))
    trajectory = simulate(robot, [0.0, DURATION], zero, np.r_[q, dq], OUTPUTS, TOL, TOL)
    assert trajectory.status == "completed"
    assert len(trajectory.t) == OUTPUTS + 1
    value = drift(robot, trajectory.q, trajectory.dq)
    assert value < DRIFT, f"energy drift {value:.2e} for {robot.model_dump_json()}"


def test_a_heavy_light_arm_with_fast_waves_conserves_energy():
    """Frequency 20, masses 30 and 0.03 kg: Adams drifts 9e-10 here, BDF (used before) 4e-8."""
    robot = Robot.model_validate({"links": [
        {"length": 0.34, "mass": 30.0, "inertia": 0.79, "joint": "active",
         "wave": {"amplitude": 0.076, "frequency": 20.0, "phase": -2.25}},
        {"length": 0.48, "mass": 0.03, "inertia": 0.0011, "joint": "active",
         "wave": {"amplitude": 0.021, "frequency": 20.0, "phase": -1.19}}], "gravity": 9.81})
    trajectory = simulate(robot, [0.0, DURATION], np.zeros((1, 1, 2)), [2.33, -2.12, -0.18, 0.65],
                          OUTPUTS, TOL, TOL)
    assert trajectory.status == "completed"
    assert drift(robot, trajectory.q, trajectory.dq) < DRIFT


# --------------------------------------------------------------------------- against SciPy

def reference_rhs(robot: Robot, torque):
    """dx/dt from d'Alembert's M and h (conftest), torque(t) of the active joints."""
    B = np.zeros((robot.n, len(robot.active)))
    B[robot.active, range(len(robot.active))] = 1.0

    def rhs(t, x):
        q, dq = x[:robot.n], x[robot.n:]
        M, h = point_mass_dynamics(robot, q, dq)
        return np.r_[dq, np.linalg.solve(M, B @ torque(t) - h)]
    return rhs


def interpolant(t: np.ndarray, tau: np.ndarray, kind: str):
    """SciPy's own interpolant of the samples, evaluated at a time on interval k."""
    if kind == "cubic":
        spline = CubicSpline(t, tau, bc_type="not-a-knot")
        return lambda k: spline
    if kind == "linear":
        return lambda k: interp1d(t, tau, axis=0)
    return lambda k: (lambda _: tau[k])


@pytest.mark.parametrize(("kind", "method"), [
    ("linear", "adams"), ("zoh", "adams"), ("cubic", "adams"), ("linear", "bdf")])
def test_each_interval_agrees_with_scipy(rng, kind, method):
    robot = random_robot(rng, 3, gravity=9.81)
    t = np.array([0.0, 0.3, 0.7, 1.0, 1.5])
    tau = rng.uniform(-3.0, 3.0, (len(t), len(robot.active)))
    q0, dq0 = random_state(rng, robot.n)
    samples = 4
    trajectory = simulate(robot, t, torque_coefficients(t, tau, kind), np.r_[q0, dq0], samples,
                          1e-12, 1e-12, method=method)
    assert trajectory.status == "completed"
    times, states = np.array(trajectory.t), np.hstack([trajectory.q, trajectory.dq])
    expected_times = np.r_[t[0], (t[:-1, None] + np.diff(t)[:, None]
                                  * np.linspace(0, 1, samples + 1)[1:]).ravel()]
    np.testing.assert_allclose(times, expected_times, rtol=0, atol=1e-15)
    torque_on = interpolant(t, tau, kind)
    worst = 0.0
    for k in range(len(t) - 1):
        start, chunk = k * samples, slice(k * samples + 1, (k + 1) * samples + 1)
        sol = solve_ivp(reference_rhs(robot, torque_on(k)), (t[k], t[k + 1]), states[start],
                        method="DOP853", t_eval=times[chunk], rtol=1e-12, atol=1e-12)
        assert sol.status == 0
        worst = max(worst, float(np.abs(sol.y.T - states[chunk]).max()))
    assert worst < 1e-8


# --------------------------------------------------------------------------- coefficients

def evaluate(coeffs: np.ndarray, t: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The piecewise polynomial at times `at` (each within [t[0], t[-1]])."""
    k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    s = (at - t[k]) / (t[k + 1] - t[k])
    powers = s[:, None] ** np.arange(coeffs.shape[1])[None, :]
    return np.einsum("kj,kja->ka", powers, coeffs[k])


@pytest.fixture
def samples(rng):
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.5, 7)])
    return t, rng.uniform(-5.0, 5.0, (len(t), 2))


def test_zero_order_hold_keeps_each_sample_over_its_interval(samples):
    t, tau = samples
    coeffs = torque_coefficients(t, tau, "zoh")
    assert coeffs.shape == (len(t) - 1, 1, 2)
    middle = (t[:-1] + t[1:]) / 2
    assert np.array_equal(evaluate(coeffs, t, t[:-1]), tau[:-1])
    assert np.array_equal(evaluate(coeffs, t, middle), tau[:-1])


def test_linear_coefficients_reproduce_samples_and_midpoints(samples):
    t, tau = samples
    coeffs = torque_coefficients(t, tau, "linear")
    assert coeffs.shape == (len(t) - 1, 2, 2)
    np.testing.assert_allclose(coeffs.sum(axis=1), tau[1:], rtol=0, atol=1e-15)
    assert np.array_equal(coeffs[:, 0], tau[:-1])
    middle = (t[:-1] + t[1:]) / 2
    np.testing.assert_allclose(evaluate(coeffs, t, middle), (tau[:-1] + tau[1:]) / 2,
                               rtol=0, atol=1e-14)


def test_cubic_coefficients_are_scipys_spline(samples):
    t, tau = samples
    coeffs = torque_coefficients(t, tau, "cubic")
    assert coeffs.shape == (len(t) - 1, 4, 2)
    at = np.linspace(t[0], t[-1], 301)
    np.testing.assert_allclose(evaluate(coeffs, t, at), CubicSpline(t, tau)(at), rtol=0, atol=1e-12)
    np.testing.assert_allclose(evaluate(coeffs, t, t), tau, rtol=0, atol=1e-12)
    np.testing.assert_allclose(coeffs.sum(axis=1), tau[1:], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- requests

TWO_LINK = {"links": [
    {"length": 0.5, "mass": 1.0, "joint": "passive"},
    {"length": 0.4, "mass": 0.5, "joint": "active", "wave": {"amplitude": 0.05, "frequency": 3.0}}],
    "gravity": 9.81}


def request(**change) -> dict:
    body = {"robot": TWO_LINK, "t": [0.0, 0.5, 1.0], "tau": [[0.0], [0.2], [0.1]],
            "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]}}
    return {**body, **change}


def test_a_failed_integration_reports_where_and_why_instead_of_raising():
    trajectory = run(SimulationRequest.model_validate(
        request(tau=[[0.0], [1.7e308], [0.0]], interpolation="zoh", samples_per_interval=2)))
    assert trajectory.status == "failed"
    assert trajectory.message == (
        "integration failed between t = 0.5 s and t = 1 s: the dynamics are not finite at "
        "the start of the interval (values too large) (CVODES CV_FIRST_RHSFUNC_ERR)")
    assert trajectory.t == [0.0, 0.25, 0.5]
    assert trajectory.q[0] == [0.3, -0.2]


@pytest.mark.parametrize("samples", [1, 2])
def test_torques_near_the_largest_double_fail_instead_of_returning_the_start(samples):
    """CVODES stops at the first step without an error here; the result must not pass
    the initial state off as the end of the motion."""
    trajectory = run(SimulationRequest.model_validate(
        request(t=[0.0, 1.0], tau=[[1e300], [1e300]], samples_per_interval=samples)))
    assert (trajectory.status, trajectory.message) == ("failed", (
        "integration failed between t = 0 s and t = 1 s: the integrator stopped short of the "
        "output time (values too large) (CVODES CV_BAD_T)"))
    assert trajectory.t == [0.0] and trajectory.q == [[0.3, -0.2]]


REQUEST_ERRORS = {
    "decreasing t": (request(t=[0.0, 1.0, 0.5]), ("t",),
                     "Value error, must be strictly increasing"),
    "repeated t": (request(t=[0.0, 0.5, 0.5]), ("t",), "Value error, must be strictly increasing"),
    "one time": (request(t=[0.0], tau=[[0.0]]), ("t",),
                 "List should have at least 2 items after validation, not 1"),
    "nan time": (request(t=[0.0, float("nan"), 1.0]), ("t", 1), "Input should be a finite number"),
    "too few rows": (request(tau=[[0.0], [0.1]]), ("tau",),
                     "Value error, needs 3 rows, one per time in t (got 2)"),
    "too wide a row": (request(tau=[[0.0], [0.1, 0.2], [0.0]]), ("tau",),
                       "Value error, every row needs 1 entry, one per active joint (row 1 has 2)"),
    "infinite torque": (request(tau=[[0.0], [float("inf")], [0.0]]), ("tau", 1, 0),
                        "Input should be a finite number"),
    "rows against an invalid t": (request(t=[1.0, 0.0], tau=[[0.0]] * 3), ("t",),
                                  "Value error, must be strictly increasing"),
    "short initial q": (request(initial={"q": [0.3], "dq": [0.0, 0.5]}), ("initial",),
                        "Value error, q: needs 2 entries, one per joint (got 1)"),
    "long initial dq": (request(initial={"q": [0.3, 0.1], "dq": [0.0, 0.5, 1.0]}), ("initial",),
                        "Value error, dq: needs 2 entries, one per joint (got 3)"),
    "initial against an invalid robot": (
        request(robot={**TWO_LINK, "gravity": -1.0}, initial={"q": [0.3], "dq": [0.0]}),
        ("robot", "gravity"), "Input should be greater than or equal to 0"),
    "unknown interpolation": (request(interpolation="spline"), ("interpolation",),
                              "Input should be 'zoh', 'linear' or 'cubic'"),
    "no samples": (request(samples_per_interval=0), ("samples_per_interval",),
                   "Input should be greater than or equal to 1"),
    "zero tolerance": (request(rtol=0.0), ("rtol",),
                       "Input should be greater than or equal to 0.00000000000001"),
    "unknown field": (request(method="rk4"), ("method",), "Extra inputs are not permitted"),
}


@pytest.mark.parametrize("case", REQUEST_ERRORS)
def test_request_errors_name_the_field(case):
    body, loc, msg = REQUEST_ERRORS[case]
    with pytest.raises(ValidationError) as info:
        SimulationRequest.model_validate(body)
    assert [(e["loc"], e["msg"]) for e in info.value.errors()] == [(loc, msg)]
