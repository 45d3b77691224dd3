"""What the region and the motion NLPs share: the waves as decision variables, the smooth
lower bound on sigma_min(M_pa) they maximise, and reading a solution back.

With the frequencies fixed, each NLP maximises s over the amplitudes and phases subject
to lambda_min(M_pa M_pa^T) >= s^2 at every sample, as smooth dimensionless constraints
(see `bound`).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from planner.model import Robot, Structure, wave_slots
from planner.waves.screening import Candidate, wrap

WHAT = "the wave design"
"""How budget messages name the design."""
IPOPT: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                         "ipopt.max_iter": 250, "ipopt.tol": 1e-9, "ipopt.acceptable_tol": 1e-6}
"""Ipopt settings. The motion NLP is also expanded to SX (builds once per ladder size,
then evaluates ten times faster); the region NLP, rebuilt at every exchange, is not."""


def wave_structure(robot: Robot) -> Structure:
    """The robot's structure with wave terms on every active joint."""
    return Structure.of(robot, wavy=tuple(link.joint == "active" for link in robot.links))


def with_waves(s: Structure, base, amplitude, frequency, phase) -> ca.MX:
    """The parameter vector `base` with the active joints' (a, n, eps) put in their slots."""
    entries = [base[i] for i in range(s.n_params)]
    for k, slot in enumerate(sorted(wave_slots(s).values())):  # active joints in order
        entries[slot:slot + 3] = [amplitude[k], frequency[k], phase[k]]
    return ca.vertcat(*entries)


def bound(G, s2, c):
    """Smooth constraints, all >= 0, for lambda_min(G) >= s2 (G symmetric r x r), each
    made dimensionless by the normalisers c (see `normalisers`), so that Ipopt's
    tolerances mean the same relative accuracy for every r and every arm.

    r = 1: G - s2. r = 2: the closed-form smaller eigenvalue minus s2. r >= 3: the leading
    principal minors of G - s2 I (for k < r these only exclude indefinite matrices).
    """
    r = G.shape[0]
    if r == 1:
        return (G - s2) / c[0]
    if r == 2:
        half_trace, half_gap = (G[0, 0] + G[1, 1]) / 2, (G[0, 0] - G[1, 1]) / 2
        spread = ca.sqrt(half_gap**2 + G[0, 1] ** 2 + (1e-12 * half_trace) ** 2)
        return (half_trace - spread - s2) / c[0]
    D = G - s2 * ca.SX.eye(r)
    return ca.vertcat(*[ca.det(D[:k, :k]) / c[k - 1] for k in range(1, r + 1)])


def normalisers(mpa: np.ndarray) -> np.ndarray:
    """Scales of the constraints of `bound` at each block of a batch (K, r, c) -> (K, r).

    With G = M_pa M_pa^T and g its largest eigenvalue over the batch: c[k-1] = g times the
    product of the k - 1 largest eigenvalues of G's leading k x k block, so that the k-th
    minor of G - s2 I divided by c[k-1] is about (its smallest eigenvalue - s2) / g.
    """
    G = mpa @ mpa.transpose(0, 2, 1)
    K, r = G.shape[:2]
    scale = max(float(np.linalg.eigvalsh(G)[:, -1].max()), 1e-300)
    c = np.full((K, r), scale)
    for k in range(2, r + 1):
        eig = np.linalg.eigvalsh(G[:, :k, :k])[:, 1:]  # the k - 1 largest
        c[:, k - 1] *= np.maximum(eig.prod(axis=1), (1e-12 * scale) ** (k - 1))
    return c


def decision(na: int):
    return ca.MX.sym("a", na), ca.MX.sym("eps", na), ca.MX.sym("s")


def lbx(upper: np.ndarray, extra: int = 0) -> np.ndarray:
    na = len(upper)
    return np.concatenate([np.zeros(na), -np.inf * np.ones(na), [0.0], -np.inf * np.ones(extra)])


def ubx(upper: np.ndarray, extra: int = 0) -> np.ndarray:
    na = len(upper)
    return np.concatenate([upper, np.inf * np.ones(na), [np.inf], np.inf * np.ones(extra)])


def candidate_from(stats: dict, x: np.ndarray, start: Candidate,
                    upper: np.ndarray, guess: np.ndarray | None = None) -> Candidate:
    """The NLP's waves (amplitudes clipped to their bounds, phases wrapped); the start,
    marked unsolved, when the NLP returned a non-finite point."""
    na = len(start.frequency)
    if not np.all(np.isfinite(x)):
        return Candidate(start.amplitude, start.frequency, start.phase, start.bound, False)
    solved = stats["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    return Candidate(np.clip(x[:na], 0.0, upper), start.frequency.copy(), wrap(x[na:2 * na]),
                     float(x[2 * na]), solved, guess)
