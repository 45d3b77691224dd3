"""The inertial coupling block M_pa(q): its batched evaluation, its measures, and where
its determinant vanishes along a path. Every caller of the library asks here.

M_pa(q) is the block of the mass matrix with the passive joints' rows and the active
joints' columns [kg m^2], r x c with r passive and c active joints. One CasADi
`Function.map` evaluates it at a chunk of configurations, numpy takes the determinants
and singular values of the whole batch. Zeros of det M_pa (square blocks) along a path
are its sign changes between neighbouring samples, refined by a bracketing root finder
(Chandrupatla's method, which like Brent's keeps the bracket and converges
superlinearly; all brackets at once) to machine precision.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
from scipy.optimize.elementwise import find_root

from planner import budget, buffered
from planner.dynamics import derive, vector
from planner.model import Robot, Structure, parameters

CHUNK = 4096
"""Configurations per mapped CasADi call."""

Path = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""path(u, k): the configurations (m, n) [rad] at the path parameters u (m,) of the
brackets k (m,) (int indices, for paths that differ per bracket)."""


# --------------------------------------------------------------------------- evaluation


@lru_cache(maxsize=64)
def _functions(s: Structure) -> dict[str, ca.Function]:
    """Mpa(q, p) -> r x c, and dMpa(q, p) -> (r c) x n, d vec(M_pa) / dq (column-major vec)."""
    sym = derive(s)
    mpa = sym.mass[s.passive_idx, s.active_idx] if s.passive_idx else ca.SX(0, len(s.active_idx))
    return {"Mpa": ca.Function("Mpa", [sym.q, sym.p], [mpa], ["q", "p"], ["Mpa"]),
            "dMpa": ca.Function("dMpa", [sym.q, sym.p], [ca.jacobian(ca.vec(mpa), sym.q)],
                                ["q", "p"], ["dMpa"])}


def block_function(s: Structure) -> ca.Function:
    """The SX function Mpa(q, p) -> r x c [kg m^2] of a structure."""
    return _functions(s)["Mpa"]


def block_jacobian(s: Structure) -> ca.Function:
    """The SX function dMpa(q, p) -> (r c) x n, d vec(M_pa) / dq (column-major vec)."""
    return _functions(s)["dMpa"]


@lru_cache(maxsize=128)
def _mapped(s: Structure, size: int) -> ca.Function:
    """Mpa mapped over `size` columns of q; a one-column p is shared."""
    return _functions(s)["Mpa"].map(size)


def evaluate(s: Structure, configurations, p, deadline: float | None = None) -> np.ndarray:
    """M_pa (K, r, c) [kg m^2] at every configuration.

    configurations: (K, n) [rad]; p: one parameter vector (n_params,) or one per row
    (K, n_params). Past `deadline` (`time.monotonic()`, checked between chunks) it raises
    BudgetExceeded.
    """
    Q = np.atleast_2d(np.asarray(configurations, dtype=float))
    P = np.asarray(p, dtype=float)
    K = Q.shape[0]
    size = min(CHUNK, max(K, 1))
    f = _mapped(s, size)
    rows, cols = f.size_out(0)
    cols //= size
    out = np.empty((K, rows, cols))
    for part in budget.chunks(K, size, deadline, "the evaluation of Mpa", "configuration"):
        args = [_pad(Q[part], size).T, P if P.ndim == 1 else _pad(P[part], size).T]
        (flat,) = buffered.call(f, *args)  # (rows, cols * size): the outputs side by side
        stacked = flat.reshape(rows, cols, size, order="F").transpose(2, 0, 1)
        out[part] = stacked[:part.stop - part.start]
    return out


def _pad(rows: np.ndarray, size: int) -> np.ndarray:
    """Repeat the last row up to `size` rows."""
    missing = size - len(rows)
    return np.vstack([rows, np.repeat(rows[-1:], missing, axis=0)]) if missing else rows


def blocks(robot: Robot, configurations, structure: Structure | None = None,
           deadline: float | None = None) -> np.ndarray:
    """M_pa at every configuration: (K, r, c) [kg m^2] for q of shape (K, n) [rad]."""
    s = structure or Structure.of(robot)
    return evaluate(s, configurations, parameters(robot, s), deadline)


# --------------------------------------------------------------------------- measures


@dataclass(frozen=True)
class Measures:
    """Measures of K coupling blocks (K, r, c), each an array (K,) [kg m^2].

    det: determinant, square blocks only (else None). sigma_min: the r-th singular value,
    the distance to losing full row rank, which prescribing the passive motion needs (0
    when r > c: never full row rank). least: the smallest singular value, the min(r, c)-th
    (what a plan's coupling margin bounds; equal to sigma_min when r <= c). sigma_max: the
    largest. A block without rows (no passive joint) has no singularity to measure: NaN
    throughout.
    """

    det: np.ndarray | None
    sigma_min: np.ndarray
    least: np.ndarray
    sigma_max: np.ndarray


def measures(mpa: np.ndarray) -> Measures:
    """det, sigma_min, least and sigma_max of a batch of blocks (K, r, c) (see Measures)."""
    K, rows, cols = mpa.shape
    if rows == 0:
        nan = np.full(K, np.nan)
        return Measures(det=None, sigma_min=nan, least=nan, sigma_max=nan)
    if rows == 1:  # one passive joint: the row's one singular value is its length
        length = np.linalg.norm(mpa[:, 0, :], axis=1)
        return Measures(det=determinants(mpa), sigma_min=length, least=length,
                        sigma_max=length)
    sv = np.linalg.svd(mpa, compute_uv=False)  # (K, min(r, c)), descending
    return Measures(det=determinants(mpa),
                    sigma_min=sv[:, rows - 1] if rows <= cols else np.zeros(K),
                    least=sv[:, -1], sigma_max=sv[:, 0])


def determinants(mpa: np.ndarray) -> np.ndarray | None:
    """det (K,) of a batch of square blocks (K, r, r) [kg^r m^2r]; None for blocks that
    are not square."""
    K, rows, cols = mpa.shape
    if rows != cols:
        return None
    return mpa[:, 0, 0].copy() if rows == 1 else np.linalg.det(mpa)


def condition(sigma_min: np.ndarray, sigma_max: np.ndarray) -> list[float | None]:
    """sigma_max / sigma_min per block; None where it is not a finite number (sigma_min
    zero, or so small that the ratio overflows), 1.0 for a block without rows (NaN
    measures: trivially well conditioned)."""
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        ratio = sigma_max / sigma_min
    return [1.0 if math.isnan(a) else float(c) if a > 0.0 and math.isfinite(c) else None
            for a, c in zip(sigma_min, ratio, strict=True)]


def along(robot: Robot, configurations, structure: Structure | None = None,
          deadline: float | None = None) -> Measures:
    """The measures of M_pa at every configuration (K, n) [rad]."""
    return measures(blocks(robot, configurations, structure, deadline))


@dataclass(frozen=True)
class Coupling:
    """Measures of M_pa at one configuration [kg m^2] (see Measures): det (square M_pa
    only, else None), sigma_min, sigma_max, and condition = sigma_max / sigma_min (None
    where sigma_min is 0 or the ratio overflows). A robot without passive joints has no
    coupling block: det, sigma_min and sigma_max are None and condition is 1.0. Every
    value is finite or None."""

    det: float | None
    sigma_min: float | None
    sigma_max: float | None
    condition: float | None


def at(robot: Robot, q, structure: Structure | None = None) -> Coupling:
    """The measures of M_pa(q) at one configuration q (n,) [rad]; InputError naming q
    unless it holds one finite number per joint."""
    m = along(robot, vector("q", q, robot.n, "joint")[None, :], structure)

    def scalar(a: np.ndarray | None) -> float | None:
        return None if a is None or not math.isfinite(a[0]) else float(a[0])
    return Coupling(det=scalar(m.det), sigma_min=scalar(m.sigma_min),
                    sigma_max=scalar(m.sigma_max),
                    condition=condition(m.sigma_min, m.sigma_max)[0])


# --------------------------------------------------------------------------- zeros of det


def refine(s: Structure, p: np.ndarray, path: Path, lo: np.ndarray, hi: np.ndarray,
           deadline: float | None = None) -> np.ndarray:
    """The zero of det M_pa(path(u, k)) in every bracket [lo_k, hi_k] (m,) across which it
    changes sign, all brackets at once, to machine precision (Chandrupatla's method,
    scipy.optimize.elementwise.find_root)."""
    if len(lo) == 0:
        return np.empty(0)

    def det_at(u: np.ndarray, k: np.ndarray) -> np.ndarray:
        q = path(u.ravel(), k.ravel().astype(int))
        det = determinants(evaluate(s, q, p, deadline))
        if det is None:
            raise ValueError("det M_pa needs a square coupling block")
        return det.reshape(u.shape)

    res = find_root(det_at, (np.asarray(lo, float), np.asarray(hi, float)),
                    args=(np.arange(len(lo)),), tolerances={"xatol": 1e-16, "xrtol": 1e-15})
    return res.x


def sweep(q, joint: int) -> Callable[[np.ndarray], np.ndarray]:
    """The path through the configuration q (n,) [rad] along one joint's angle:
    u (m,) -> q with q[joint] = u, (m, n)."""
    base = np.asarray(q, dtype=float)

    def path(u: np.ndarray) -> np.ndarray:
        out = np.tile(base, (len(u), 1))
        out[:, joint] = u
        return out
    return path


def zeros_along(robot: Robot, path: Callable[[np.ndarray], np.ndarray], u: np.ndarray,
                structure: Structure | None = None, deadline: float | None = None,
                det: np.ndarray | None = None) -> np.ndarray | None:
    """Where det M_pa(path(u)) = 0 between the samples u (K,) of a path's parameter
    (increasing): the samples where it is exactly 0 and every sign change between
    neighbouring samples, refined (see `refine`); sorted. path: u (m,) -> configurations
    (m, n) [rad]; det: det M_pa at path(u) (K,) where known already. None for a
    non-square block, which has no determinant."""
    s = structure or Structure.of(robot)
    p = parameters(robot, s)
    if det is None:
        det = determinants(evaluate(s, path(u), p, deadline))
    if det is None:
        return None
    k = np.flatnonzero(np.sign(det[:-1]) * np.sign(det[1:]) < 0.0)
    roots = refine(s, p, lambda x, _k: path(x), u[k], u[k + 1], deadline)
    return np.sort(np.concatenate([u[det == 0.0], roots]))
