"""The seed paper's printed 4-link equations (28), (30), (31), transcribed term by term.

Joints are numbered 1..4 as in the paper; passive 1 and 3, waves on 2 and 4. These are
the cross-check, never used by the product. `printed_*` reproduce the print as it
stands (misprints included); `CORRECTED` holds the right form of each misprinted term.
"""

from __future__ import annotations

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
    s, c, r = _waves(p, q)
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
    s, c, r = _waves(p, q)
    return r[i] * np.sin(q[i]) - a[i] * n[i] * c[i] * np.cos(q[i])


def printed_bias(p: Arm, q) -> dict[str, float]:
    """Every term of h* in (31), as printed: 'h{i}.dq{j}^2' coefficients and 'h{i}.g'."""
    l, m, a, n, g = p.l, p.m, p.a, p.n, p.g
    s, c, r = _waves(p, q)
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


def printed_lagrangian(p: Arm, q, dq) -> float:
    """L of (28), reading the rotational sum as sum_k I_k (sum_{i<=k} dq_i)^2."""
    M = printed_mass(p, q)
    full = np.zeros((5, 5))
    for key, value in M.items():
        i, j = int(key[1]), int(key[2])
        full[i, j] = full[j, i] = value
    kinetic = 0.5 * dq @ full[1:, 1:] @ dq
    l, m, g = p.l, p.m, p.g
    s, c, r = _waves(p, q)
    potential = -sum(m[k] * g * r[i] * np.cos(q[i]) for k in (1, 2, 3, 4) for i in range(1, k + 1))
    return kinetic - potential
