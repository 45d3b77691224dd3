"""The seed paper's printed 4-link equations (28), (30), (31), transcribed term by term.

Joints are numbered 1..4 as in the paper; passive 1 and 3, waves on 2 and 4. These are
the cross-check, never used by the product. `printed_*` reproduce the print as it
stands (misprints included); `CORRECTED` holds the right form of each misprinted term,
written by hand from the Christoffel symbols of (30):
    coefficient of dq_j^2 in h_i = dM_ij/dq_j - 1/2 dM_jj/dq_i = dM_ij/dq_j,
since M_ij depends on q_i and q_j only and M_jj on q_j only (which also leaves h free of
products dq_i dq_j, i != j). The gravity part of h_i is dV/dq_i.

Angles q and rates dq are indexed 1..4 as printed (index 0 unused: pass np.r_[0, q]);
`mass_matrix` and `bias_vector` return 0-based numpy arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Arm:
    """Parameters of the paper's 4-link arm (index 0 unused so that 1..4 read as printed)."""

    l: tuple
    m: tuple
    I: tuple
    a: tuple
    n: tuple
    e: tuple
    g: float


def _waves(p: Arm, q):
    s = {i: np.sin(p.n[i] * q[i] + p.e[i]) for i in (1, 2, 3, 4)}
    c = {i: np.cos(p.n[i] * q[i] + p.e[i]) for i in (1, 2, 3, 4)}
    r = {i: p.l[i] + p.a[i] * s[i] for i in (1, 2, 3, 4)}
    return s, c, r


def printed_mass(p: Arm, q) -> dict[str, float]:
    """The entries of M* in (30), as printed."""
    l, m, I, a, n, e = p.l, p.m, p.I, p.a, p.n, p.e
    _, c, r = _waves(p, q)
    m234, m34 = m[2] + m[3] + m[4], m[3] + m[4]
    cos, sin = np.cos, np.sin
    return {
        "M11": I[1] + I[2] + I[3] + I[4] + (m[1] + m234) * l[1] ** 2,
        "M22": I[2] + I[3] + I[4] + m234 * (a[2] ** 2 * n[2] ** 2 * c[2] ** 2 + r[2] ** 2),
        "M33": I[3] + I[4] + m34 * l[3] ** 2,
        "M44": I[4] + m[4] * (a[4] ** 2 * n[4] ** 2 * c[4] ** 2 + r[4] ** 2),
        "M12": I[2] + I[3] + I[4] + m234 * (
            l[1] * (l[2] + a[2] * sin(n[1] * q[1] + e[1])) * cos(q[1] - q[2])
            + a[2] * n[2] * l[1] * c[2] * sin(q[2] - q[1])),
        "M13": I[3] + I[4] + m34 * l[1] * l[3] * cos(q[1] - q[3]),
        "M23": I[3] + I[4] + m34 * (
            l[3] * r[2] * cos(q[2] - q[3]) + a[2] * n[2] * l[3] * c[2] * sin(q[2] - q[3])),
        "M34": I[4] + m[4] * (
            l[3] * r[4] * cos(q[3] - q[4]) + a[4] * n[4] * l[3] * c[4] * sin(q[4] - q[3])),
        "M14": I[4] + m[4] * (
            l[1] * r[4] * cos(q[1] - q[4]) + a[4] * n[4] * l[1] * c[4] * sin(q[4] - q[1])),
        "M24": I[4] + m[4] * (
            r[2] * r[4] * cos(q[2] - q[4])
            + a[2] * n[2] * a[4] * n[4] * c[2] * c[4] * cos(q[2] - q[4])
            + a[2] * n[2] * r[4] * c[2] * sin(q[2] - q[4])
            + a[4] * n[4] * r[2] * c[4] * sin(q[4] - q[2])),
    }


def _h_block(p: Arm, q, i: int, j: int) -> float:
    """The recurring bracket of (31): coefficient of dq_j^2 in h_i for a waveless i, wavy j."""
    a, n, l = p.a, p.n, p.l
    s, c, r = _waves(p, q)
    return (2 * a[j] * n[j] * l[i] * c[j] * np.cos(q[i] - q[j])
            + l[i] * r[j] * np.sin(q[i] - q[j])
            - a[j] * n[j] ** 2 * l[i] * s[j] * np.sin(q[j] - q[i]))


def _h_24(p: Arm, q) -> float:
    """The bracket of (31) multiplying m4 dq4^2 in h2 and m4 dq2^2 in h4."""
    a, n = p.a, p.n
    s, c, r = _waves(p, q)
    d = q[2] - q[4]
    return (2 * a[4] * n[4] * c[4] * r[2] * np.cos(d)
            + 2 * a[2] * n[2] * a[4] * n[4] * c[2] * c[4] * np.sin(d)
            + r[2] * r[4] * np.sin(d)
            - a[2] * n[2] * a[4] * n[4] ** 2 * s[4] * c[2] * np.cos(d)
            - a[2] * n[2] * r[4] * c[2] * np.cos(d)
            - a[4] * n[4] ** 2 * r[2] * s[4] * np.sin(-d))


def _self(p: Arm, q, j: int) -> float:
    """Bracket of (31) multiplying dq_j^2 in h_j for a wavy joint j."""
    a, n = p.a, p.n
    s, c, r = _waves(p, q)
    return a[j] * n[j] * c[j] * r[j] - a[j] ** 2 * n[j] ** 3 * s[j] * c[j]


def _grav(p: Arm, q, i: int) -> float:
    a, n = p.a, p.n
    _, c, r = _waves(p, q)
    return r[i] * np.sin(q[i]) - a[i] * n[i] * c[i] * np.cos(q[i])


def printed_bias(p: Arm, q) -> dict[str, float]:
    """Every term of h* in (31), as printed: 'h{i}.dq{j}^2' coefficients and 'h{i}.g'."""
    l, m, a, n, g = p.l, p.m, p.a, p.n, p.g
    _, c, r = _waves(p, q)
    m234, m34, mall = m[2] + m[3] + m[4], m[3] + m[4], m[1] + m[2] + m[3] + m[4]
    sin, cos = np.sin, np.cos
    return {
        "h1.dq2^2": m234 * _h_block(p, q, 1, 2),
        "h1.dq3^2": m34 * l[1] * l[3] * sin(q[1] - q[3]),
        "h1.dq4^2": m[4] * _h_block(p, q, 1, 4),
        "h1.g": mall * g * _grav(p, q, 1),
        "h2.dq1^2": m234 * _h_block(p, q, 1, 2),
        "h2.dq2^2": m234 * _self(p, q, 2),
        "h2.dq3^2": m34 * (l[3] * r[2] * sin(q[2] - q[3]) - a[2] * n[2] * l[3] * c[2] * cos(q[2] - q[3])),
        "h2.dq4^2": m[4] * _h_24(p, q),
        "h2.g": m234 * g * _grav(p, q, 2),
        "h3.dq1^2": m34 * l[1] * l[3] * sin(q[1] - q[3]),
        "h3.dq2^2": m34 * (l[3] * r[2] * sin(q[2] - q[3]) - a[2] * n[2] * l[3] * c[2] * cos(q[2] - q[3])),
        "h3.dq4^2": m[4] * _h_block(p, q, 3, 4),
        "h3.g": m34 * g * _grav(p, q, 3),
        "h4.dq1^2": m[4] * _h_block(p, q, 1, 4),
        "h4.dq2^2": m[4] * _h_24(p, q),
        "h4.dq3^2": m[4] * _h_block(p, q, 3, 4),
        "h4.dq4^2": m[4] * _self(p, q, 4),
        "h4.g": m[4] * g * _grav(p, q, 4),
    }


def printed_kinetic(p: Arm, q, dq, literal: bool = False) -> float:
    """T of (28), term by term as printed.

    The rotational sum is printed as 1/2 sum_k I_k (sum_{i<=k} dq_k)^2; `literal` keeps
    that (= 1/2 sum_k I_k k^2 dq_k^2), otherwise it is read as sum_{i<=k} dq_i.
    """
    l, m, I, a, n = p.l, p.m, p.I, p.a, p.n
    _, c, r = _waves(p, q)
    m234, m34, mall = m[2] + m[3] + m[4], m[3] + m[4], m[1] + m[2] + m[3] + m[4]
    cos, sin = np.cos, np.sin
    terms = [
        0.5 * mall * l[1] ** 2 * dq[1] ** 2,
        0.5 * m34 * l[3] ** 2 * dq[3] ** 2,
        0.5 * m234 * dq[2] ** 2 * (a[2] ** 2 * n[2] ** 2 * c[2] ** 2 + r[2] ** 2),
        0.5 * m[4] * dq[4] ** 2 * (a[4] ** 2 * n[4] ** 2 * c[4] ** 2 + r[4] ** 2),
        m234 * dq[1] * dq[2] * (l[1] * r[2] * cos(q[1] - q[2]) + a[2] * n[2] * l[1] * c[2] * sin(q[2] - q[1])),
        m34 * dq[1] * dq[3] * l[1] * l[3] * cos(q[1] - q[3]),
        m34 * dq[2] * dq[3] * (l[3] * r[2] * cos(q[2] - q[3]) + a[2] * n[2] * l[3] * c[2] * sin(q[2] - q[3])),
        m[4] * dq[1] * dq[4] * (l[1] * r[4] * cos(q[1] - q[4]) + a[4] * n[4] * l[1] * c[4] * sin(q[4] - q[1])),
        m[4] * dq[2] * dq[4] * (
            r[2] * r[4] * cos(q[2] - q[4])
            + a[2] * n[2] * a[4] * n[4] * c[2] * c[4] * cos(q[2] - q[4])
            + a[2] * n[2] * r[4] * c[2] * sin(q[2] - q[4])
            + a[4] * n[4] * r[2] * c[4] * sin(q[4] - q[2])),
        m[4] * dq[3] * dq[4] * (l[3] * r[4] * cos(q[3] - q[4]) + a[4] * n[4] * l[3] * c[4] * sin(q[4] - q[3])),
    ]
    for k in (1, 2, 3, 4):
        rate = k * dq[k] if literal else sum(dq[i] for i in range(1, k + 1))
        terms.append(0.5 * I[k] * rate ** 2)
    return float(sum(terms))


def printed_potential(p: Arm, q) -> float:
    """V of (28): L carries + sum_k sum_{i<=k} m_k g r_i cos q_i, so V is its negative."""
    m, g = p.m, p.g
    _, _, r = _waves(p, q)
    return float(-sum(m[k] * g * r[i] * np.cos(q[i])
                      for k in (1, 2, 3, 4) for i in range(1, k + 1)))


def printed_lagrangian(p: Arm, q, dq, literal: bool = False) -> float:
    """L = T - V of (28), term by term (see `printed_kinetic` for `literal`)."""
    return printed_kinetic(p, q, dq, literal) - printed_potential(p, q)


def _corrected_m12(p: Arm, q) -> float:
    """M12 with the wave of joint 2, as (28) has it: r2 = l2 + a2 sin(n2 q2 + eps2)."""
    l, m, I, a, n = p.l, p.m, p.I, p.a, p.n
    _, c, r = _waves(p, q)
    return I[2] + I[3] + I[4] + (m[2] + m[3] + m[4]) * l[1] * (
        r[2] * np.cos(q[1] - q[2]) + a[2] * n[2] * c[2] * np.sin(q[2] - q[1]))


def _corrected_h2_dq1(p: Arm, q) -> float:
    """dM12/dq1 = (m2+m3+m4) l1 [r2 sin(q2 - q1) - a2 n2 cos(n2 q2 + eps2) cos(q2 - q1)]."""
    l, m, a, n = p.l, p.m, p.a, p.n
    _, c, r = _waves(p, q)
    return (m[2] + m[3] + m[4]) * l[1] * (
        r[2] * np.sin(q[2] - q[1]) - a[2] * n[2] * c[2] * np.cos(q[2] - q[1]))


def _corrected_h3_dq1(p: Arm, q) -> float:
    """dM13/dq1 = (m3+m4) l1 l3 sin(q3 - q1)."""
    l, m = p.l, p.m
    return (m[3] + m[4]) * l[1] * l[3] * np.sin(q[3] - q[1])


def _corrected_h3_dq2(p: Arm, q) -> float:
    """dM23/dq2 = (m3+m4) l3 [2 a2 n2 c2 cos(q2 - q3) + r2 sin(q3 - q2) - a2 n2^2 s2 sin(q2 - q3)]."""
    l, m, a, n = p.l, p.m, p.a, p.n
    s, c, r = _waves(p, q)
    return (m[3] + m[4]) * l[3] * (
        2 * a[2] * n[2] * c[2] * np.cos(q[2] - q[3])
        + r[2] * np.sin(q[3] - q[2])
        - a[2] * n[2] ** 2 * s[2] * np.sin(q[2] - q[3]))


def _corrected_h4_dq1(p: Arm, q) -> float:
    """dM14/dq1 = m4 l1 [r4 sin(q4 - q1) - a4 n4 c4 cos(q4 - q1)]."""
    l, m, a, n = p.l, p.m, p.a, p.n
    _, c, r = _waves(p, q)
    return m[4] * l[1] * (r[4] * np.sin(q[4] - q[1]) - a[4] * n[4] * c[4] * np.cos(q[4] - q[1]))


def _corrected_h4_dq2(p: Arm, q) -> float:
    """dM24/dq2: the bracket of h2.dq4^2 with joints 2 and 4 exchanged."""
    m, a, n = p.m, p.a, p.n
    s, c, r = _waves(p, q)
    d = q[2] - q[4]
    return m[4] * (
        2 * a[2] * n[2] * c[2] * r[4] * np.cos(d)
        - 2 * a[2] * n[2] * a[4] * n[4] * c[2] * c[4] * np.sin(d)
        - r[2] * r[4] * np.sin(d)
        - a[2] * n[2] ** 2 * a[4] * n[4] * s[2] * c[4] * np.cos(d)
        - a[4] * n[4] * r[2] * c[4] * np.cos(d)
        - a[2] * n[2] ** 2 * r[4] * s[2] * np.sin(d))


def _corrected_h4_dq3(p: Arm, q) -> float:
    """dM34/dq3 = m4 l3 [r4 sin(q4 - q3) - a4 n4 c4 cos(q4 - q3)]."""
    l, m, a, n = p.l, p.m, p.a, p.n
    _, c, r = _waves(p, q)
    return m[4] * l[3] * (r[4] * np.sin(q[4] - q[3]) - a[4] * n[4] * c[4] * np.cos(q[4] - q[3]))


CORRECTED: dict[str, Callable[[Arm, np.ndarray], float]] = {
    "M12": _corrected_m12,
    "h2.dq1^2": _corrected_h2_dq1,
    "h3.dq1^2": _corrected_h3_dq1,
    "h3.dq2^2": _corrected_h3_dq2,
    "h4.dq1^2": _corrected_h4_dq1,
    "h4.dq2^2": _corrected_h4_dq2,
    "h4.dq3^2": _corrected_h4_dq3,
}
"""The right closed form of every term of (30)-(31) that is misprinted."""


def corrected_mass(p: Arm, q) -> dict[str, float]:
    """The entries of M* in (30) with every misprint replaced by its corrected form."""
    return {**printed_mass(p, q), **{k: f(p, q) for k, f in CORRECTED.items() if k[0] == "M"}}


def corrected_bias(p: Arm, q) -> dict[str, float]:
    """The terms of h* in (31) with every misprint replaced by its corrected form."""
    return {**printed_bias(p, q), **{k: f(p, q) for k, f in CORRECTED.items() if k[0] == "h"}}


def mass_matrix(entries: dict[str, float]) -> np.ndarray:
    """The symmetric 4 x 4 matrix (0-based) from entries 'Mij' of the upper triangle."""
    M = np.zeros((4, 4))
    for key, value in entries.items():
        i, j = int(key[1]) - 1, int(key[2]) - 1
        M[i, j] = M[j, i] = value
    return M


def bias_vector(terms: dict[str, float], dq) -> np.ndarray:
    """h (0-based) from the terms 'h{i}.dq{j}^2' and 'h{i}.g' at rates dq (1-based)."""
    h = np.zeros(4)
    for key, value in terms.items():
        i = int(key[1]) - 1
        h[i] += value if key.endswith(".g") else value * dq[int(key[5])] ** 2
    return h


def arm_of(robot) -> Arm:
    """The `Arm` (1-based) of a 4-link `planner.model.Robot`; joints without wave get a = n = eps = 0."""
    links = robot.links
    waves = [(w.amplitude, w.frequency, w.phase) if (w := link.wave) else (0.0, 0.0, 0.0)
             for link in links]
    return Arm(l=(0.0, *(link.length for link in links)), m=(0.0, *(link.mass for link in links)),
               I=(0.0, *(link.inertia for link in links)), a=(0.0, *(w[0] for w in waves)),
               n=(0.0, *(w[1] for w in waves)), e=(0.0, *(w[2] for w in waves)), g=robot.gravity)
