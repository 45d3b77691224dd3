"""Energy conservation of the derived dynamics under zero torque.

With tau = 0 the arm is conservative: E = T + V must stay constant along any motion.
Motions of 5 s are integrated at rtol = atol = 1e-12 and the drift
max_t |E(t) - E(0)| / (T(0) + |V(0)|) must stay below 1e-8. Any inconsistency between
M, h and the energy (a wrong Christoffel term, a gravity sign) shows up far above that
(the seed's printed equations drift by 1e-4 and more, see docs/seed-errata.md).
"""

from __future__ import annotations

from functools import cache

import casadi as ca
import numpy as np
import pytest
from conftest import seed_arm

from planner.dynamics import Dynamics, functions
from planner.model import Robot, Structure, parameters
from planner.simulate import simulate
from testbed.robots import random_robot, random_state

DURATION = 5.0
TOL = 1e-12
DRIFT = 1e-8
OUTPUTS = 100


@cache
def free_motion(s: Structure) -> ca.Function:
    """CVODES (Adams, functional iteration) over [0, DURATION] for tau = 0, outputs on a grid."""
    x = ca.SX.sym("x", 2 * s.n)
    p = ca.SX.sym("p", s.n_params)
    ode = functions(s)["ode"](x, ca.DM.zeros(len(s.active_idx)), p)
    grid = list(np.linspace(0.0, DURATION, OUTPUTS + 1)[1:])
    opts = {"abstol": TOL, "reltol": TOL, "max_num_steps": 10**6,
            "linear_multistep_method": "adams", "nonlinear_solver_iteration": "functional"}
    return ca.integrator("free", "cvodes", {"x": x, "p": p, "ode": ode}, 0.0, grid, opts)


def integrate(robot: Robot, x0: np.ndarray) -> np.ndarray:
    """States (OUTPUTS + 1, 2n) of the free motion from x0."""
    s = Structure.of(robot)
    xf = np.array(free_motion(s)(x0=x0, p=parameters(robot, s))["xf"])
    return np.vstack([x0, xf.T])


def drift(robot: Robot, states: np.ndarray) -> float:
    """max |E - E(0)| / (T(0) + |V(0)|) along the states."""
    dyn, n = Dynamics(robot), robot.n
    energies = np.array([dyn.energy(x[:n], x[n:]) for x in states])
    total = energies.sum(axis=1)
    T0, V0 = energies[0]
    return float(np.max(np.abs(total - total[0])) / (T0 + abs(V0)))


def check(robot: Robot, rng: np.random.Generator) -> float:
    q, dq = random_state(rng, robot.n)
    value = drift(robot, integrate(robot, np.r_[q, dq]))
    assert value < DRIFT, f"energy drift {value:.2e} for {robot.model_dump_json()}"
    return value


@pytest.mark.parametrize(("n", "gravity", "rotational"), [
    (1, 9.81, "cumulative"), (2, 0.0, "absolute"), (3, 9.81, "absolute"),
    (4, 9.81, "cumulative"), (6, 0.0, "cumulative"), (8, 9.81, "absolute"),
])
def test_free_motion_conserves_energy(rng, n, gravity, rotational):
    check(random_robot(rng, n, gravity=gravity, rotational=rotational), rng)


def test_seed_arm_conserves_energy(rng):
    check(seed_arm(), rng)


@pytest.mark.slow
@pytest.mark.parametrize("n", range(1, 9))
@pytest.mark.parametrize("gravity", [0.0, 9.81])
@pytest.mark.parametrize("rotational", ["cumulative", "absolute"])
def test_free_motion_conserves_energy_sweep(rng, n, gravity, rotational):
    for _ in range(4):
        check(random_robot(rng, n, gravity=gravity, rotational=rotational), rng)


@pytest.mark.parametrize("robot", [seed_arm(), seed_arm(gravity=0.0, rotational="absolute")],
                         ids=["seed", "seed-horizontal-absolute"])
def test_simulate_conserves_energy(rng, robot):
    """The product's CVODES simulation under zero torque coefficients."""
    q, dq = random_state(rng, robot.n)
    na = len(robot.active)
    trajectory = simulate(robot, [0.0, DURATION], np.zeros((1, 1, na)), np.r_[q, dq],
                          samples_per_interval=OUTPUTS, rtol=TOL, atol=TOL)
    assert trajectory.status == "completed"
    states = np.hstack([trajectory.q, trajectory.dq])
    assert drift(robot, states) < DRIFT


def test_drift_measure_catches_a_missing_coriolis_term(rng):
    """Control: dropping the velocity terms of h (keeping gravity) breaks conservation."""
    robot = seed_arm()
    s = Structure.of(robot)
    f = functions(s)
    x = ca.SX.sym("x", 2 * s.n)
    p = ca.SX.sym("p", s.n_params)
    q, dq = x[:s.n], x[s.n:]
    wrong = ca.vertcat(dq, ca.solve(f["M"](q, p), -f["gravity"](q, p)))
    sim = ca.integrator("wrong", "cvodes", {"x": x, "p": p, "ode": wrong}, 0.0,
                        list(np.linspace(0.0, DURATION, OUTPUTS + 1)[1:]),
                        {"abstol": TOL, "reltol": TOL})
    q0, dq0 = random_state(rng, s.n)
    xf = np.array(sim(x0=np.r_[q0, dq0], p=parameters(robot, s))["xf"])
    assert drift(robot, np.vstack([np.r_[q0, dq0], xf.T])) > 1e3 * DRIFT
