"""M and h against derivations that share nothing with planner.dynamics.

1. A SymPy Lagrangian written here: tip positions, T, V, Euler-Lagrange equations by
   symbolic differentiation, lambdified (1 to 4 links by default, 5 to 8 under slow).
2. The closed form of a waveless chain (up to 8 links):
   M_ij = mu_max(i,j) l_i l_j cos(q_i - q_j) + rotational part,
   h_i = sum_j mu_max(i,j) l_i l_j sin(q_i - q_j) dq_j^2 + g mu_i l_i sin q_i.
3. d'Alembert's principle for wavy chains (conftest.point_mass_dynamics, up to 8 links).
Agreement to 1e-12 of the scale of M (kg m^2) and of h (N m).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
import sympy as sp
from conftest import point_mass_dynamics, rotational_mass

from planner.dynamics import Dynamics
from planner.model import Robot
from testbed.robots import random_robot, random_state

RTOL = 1e-12


@cache
def sympy_dynamics(n: int, rotational: str):
    """Lambdified (M, h)(q, dq, l, m, I, a, f, e, g) of an n-link chain with a wave on every
    joint."""
    q, dq = sp.symbols(f"q:{n}"), sp.symbols(f"dq:{n}")
    l, m, inertia = sp.symbols(f"l:{n}"), sp.symbols(f"m:{n}"), sp.symbols(f"I:{n}")
    a, f, e = sp.symbols(f"a:{n}"), sp.symbols(f"f:{n}"), sp.symbols(f"e:{n}")
    g = sp.Symbol("g")
    radius = [l[i] + a[i] * sp.sin(f[i] * q[i] + e[i]) for i in range(n)]
    tips, x, y = [], 0, 0
    for i in range(n):
        x, y = x + radius[i] * sp.cos(q[i]), y + radius[i] * sp.sin(q[i])
        tips.append((x, y))
    T = 0
    for k, (xk, yk) in enumerate(tips):
        vx = sum(sp.diff(xk, q[i]) * dq[i] for i in range(n))
        vy = sum(sp.diff(yk, q[i]) * dq[i] for i in range(n))
        T += m[k] * (vx**2 + vy**2) / 2
    for k in range(n):
        rate = sum(dq[: k + 1]) if rotational == "cumulative" else dq[k]
        T += inertia[k] * rate**2 / 2
    V = -g * sum(m[k] * tips[k][0] for k in range(n))
    momentum = [sp.diff(T, v) for v in dq]
    M = sp.Matrix(n, n, lambda i, j: sp.diff(momentum[i], dq[j]))
    h = sp.Matrix([sum(sp.diff(momentum[i], q[j]) * dq[j] for j in range(n))
                   - sp.diff(T, q[i]) + sp.diff(V, q[i]) for i in range(n)])
    return sp.lambdify([q, dq, l, m, inertia, a, f, e, g], [M, h], "numpy")


def sympy_mass_bias(robot: Robot, q, dq) -> tuple[np.ndarray, np.ndarray]:
    """M and h of a robot from the SymPy Lagrangian (a = f = e = 0 where there is no wave)."""
    links = robot.links
    waves = [(w.amplitude, w.frequency, w.phase) if (w := link.wave) else (0.0, 0.0, 0.0)
             for link in links]
    a, f, e = (list(col) for col in zip(*waves, strict=True))
    M, h = sympy_dynamics(robot.n, robot.rotational_inertia)(
        list(q), list(dq), [k.length for k in links], [k.mass for k in links],
        [k.inertia for k in links], a, f, e, robot.gravity)
    return np.array(M, dtype=float), np.array(h, dtype=float).ravel()


def waveless_mass_bias(robot: Robot, q, dq) -> tuple[np.ndarray, np.ndarray]:
    """The closed form of a waveless chain."""
    l = np.array([k.length for k in robot.links])
    mu = np.cumsum([k.mass for k in robot.links][::-1])[::-1]
    idx = np.arange(robot.n)
    beyond = mu[np.maximum.outer(idx, idx)]
    diff = np.subtract.outer(q, q)
    M = beyond * np.outer(l, l) * np.cos(diff) + rotational_mass(robot)
    h = ((beyond * np.outer(l, l) * np.sin(diff)) @ np.asarray(dq) ** 2
         + robot.gravity * mu * l * np.sin(q))
    return M, h


def assert_agree(robot: Robot, reference, rng: np.random.Generator, states: int = 5) -> None:
    dyn = Dynamics(robot)
    for _ in range(states):
        q, dq = random_state(rng, robot.n)
        M_ref, h_ref = reference(robot, q, dq)
        M, h = dyn.mass_matrix(q), dyn.bias(q, dq)
        m_scale = np.abs(M_ref).max()
        h_scale = max(np.abs(h_ref).max(), m_scale * np.max(dq**2))
        assert np.abs(M - M_ref).max() <= RTOL * m_scale
        assert np.abs(h - h_ref).max() <= RTOL * h_scale


ROTATIONAL = ["cumulative", "absolute"]


@pytest.mark.parametrize("rotational", ROTATIONAL)
@pytest.mark.parametrize("waves", [True, False], ids=["waves", "waveless"])
@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_agrees_with_sympy_lagrangian(rng, n, waves, rotational):
    for gravity in (0.0, 9.81):
        robot = random_robot(rng, n, waves=waves, gravity=gravity, rotational=rotational)
        assert_agree(robot, sympy_mass_bias, rng)


@pytest.mark.slow
@pytest.mark.parametrize("rotational", ROTATIONAL)
@pytest.mark.parametrize("n", [5, 6, 7, 8])
def test_agrees_with_sympy_lagrangian_long_chains(rng, n, rotational):
    for gravity in (0.0, 9.81):
        assert_agree(random_robot(rng, n, gravity=gravity, rotational=rotational), sympy_mass_bias,
                     rng)


def test_sympy_lagrangian_sees_every_wave_parameter(rng):
    """Control: the reference is not blind to the waves (moving a phase changes M and h)."""
    robot = random_robot(rng, 3, gravity=9.81)
    joint = robot.active[0]
    wave = robot.links[joint].wave
    moved = robot.with_waves({joint: wave.model_copy(update={"phase": wave.phase + 0.5})})
    q, dq = random_state(rng, 3)
    (M0, h0), (M1, h1) = sympy_mass_bias(robot, q, dq), sympy_mass_bias(moved, q, dq)
    assert np.abs(M1 - M0).max() > 1e-4 and np.abs(h1 - h0).max() > 1e-4


@pytest.mark.parametrize("rotational", ROTATIONAL)
@pytest.mark.parametrize("n", range(1, 9))
def test_waveless_agrees_with_closed_form(rng, n, rotational):
    for gravity in (0.0, 9.81):
        robot = random_robot(rng, n, waves=False, gravity=gravity, rotational=rotational)
        assert_agree(robot, waveless_mass_bias, rng)


@pytest.mark.parametrize("rotational", ROTATIONAL)
@pytest.mark.parametrize("n", range(1, 9))
def test_wavy_agrees_with_dalembert(rng, n, rotational):
    for gravity in (0.0, 9.81):
        robot = random_robot(rng, n, gravity=gravity, rotational=rotational)
        assert_agree(robot, point_mass_dynamics, rng)


def test_closed_form_and_dalembert_agree_on_waveless_arms(rng):
    """The two numpy references check each other where both apply."""
    for n in range(1, 9):
        robot = random_robot(rng, n, waves=False, gravity=9.81)
        q, dq = random_state(rng, n)
        for ref, other in zip(waveless_mass_bias(robot, q, dq), point_mass_dynamics(robot, q, dq),
                              strict=True):
            assert np.allclose(ref, other, rtol=1e-13, atol=1e-13)
