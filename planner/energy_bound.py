"""How far torque limits let the arm's energy change in a given time: a proof, before any
solve, that a task asking more is infeasible.

The actuators' power is P = sum_j tau_j dq_j over the active joints (the generalised forces
B tau act on the absolute angles), so |P| <= sum_j L_j |dq_j| under limits L. The point
masses bound every rate by the kinetic energy K: with w_k the velocity of the point mass
at tip k, v_j dq_j = w_j - w_{j-1} and |v_j| = |d(r_j e(q_j))/dq_j| >= r_j >= l_j - |a_j|,
while K >= m_k |w_k|^2 / 2 for every k, so |dq_j| <= c_j sqrt(2 K) with
c_j = (1 / sqrt(m_j) + 1 / sqrt(m_{j-1})) / (l_j - |a_j|) (no second term for j = 0).
Hence dE/dt <= C sqrt(2 (E - V_min)), C = sum_j L_j c_j, V_min the least potential energy
any configuration has (every link along gravity at its largest radius), and with
u = E - V_min: |d sqrt(u) / dt| <= C / sqrt(2). In a time T the energy stays within
V_min + (sqrt(u_0) -/+ C T / sqrt(2))^2 (the lower end 0 where negative). Rigorous and
loose: the kinetic energy of the rotational inertias and the actual potential along the
motion would tighten it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.dynamics import Dynamics
from planner.model import Robot


@dataclass(frozen=True)
class EnergyReach:
    """The energies [J] the arm can have at the end of a motion of T seconds from its
    initial state, whose energy is `start`: at least `lowest`, at most `highest`; `power`
    [W / sqrt(J)] is C."""

    start: float
    lowest: float
    highest: float
    power: float


def radii_least(robot: Robot, amplitude_max: float | None = None) -> list[float]:
    """[m] Every link's least radius l - |a| (a co-designed active joint's amplitude up to
    `amplitude_max`)."""
    out = []
    for joint, link in enumerate(robot.links):
        a = abs(link.wave.amplitude) if link.wave is not None else 0.0
        if amplitude_max is not None and joint in robot.active:
            a = max(a, min(amplitude_max, 0.95 * link.length))
        out.append(link.length - a)
    return out


def lowest_potential(robot: Robot, amplitude_max: float | None = None) -> float:
    """[J] A lower bound of the potential energy over all configurations: each link along
    gravity at its largest radius, every mass beyond it carried that far down."""
    g = robot.gravity
    total = 0.0
    for joint, link in enumerate(robot.links):
        a = abs(link.wave.amplitude) if link.wave is not None else 0.0
        if amplitude_max is not None and joint in robot.active:
            a = max(a, min(amplitude_max, 0.95 * link.length))
        below = sum(other.mass for other in robot.links[joint:])
        total += (link.length + a) * below
    return -g * total


def rate_factors(robot: Robot, amplitude_max: float | None = None) -> np.ndarray:
    """c_j (n,) [1 / (m sqrt(kg))]: |dq_j| <= c_j sqrt(2 K) for every joint j."""
    masses = [link.mass for link in robot.links]
    least = radii_least(robot, amplitude_max)
    out = np.empty(robot.n)
    for j in range(robot.n):
        reach = 1.0 / math.sqrt(masses[j]) + (1.0 / math.sqrt(masses[j - 1]) if j else 0.0)
        out[j] = reach / least[j]
    return out


def energy_reach(robot: Robot, q0: list[float], dq0: list[float], limit: np.ndarray,
                 T: float, amplitude_max: float | None = None) -> EnergyReach:
    """The energies [J] reachable at time T [s] from the state (q0, dq0) under the torque
    limits `limit` (n_active,) [N m] (see the module)."""
    kinetic, potential = Dynamics(robot).energy(q0, dq0)
    v_min = lowest_potential(robot, amplitude_max)
    C = float(np.dot(limit, rate_factors(robot, amplitude_max)[list(robot.active)]))
    root = math.sqrt(max(kinetic + potential - v_min, 0.0))
    step = C * T / math.sqrt(2.0)
    return EnergyReach(start=kinetic + potential, lowest=v_min + max(root - step, 0.0) ** 2,
                       highest=v_min + (root + step) ** 2, power=C)
