"""Cases at undertow's numerical edges: near-singular configurations, badly scaled robots,
the dynamics invariants, and what a result must not hold (NaN, inf).

Each case returns a row (a dict) instead of raising: the tests assert on the rows, the
`stress` benchmark sweeps them and tabulates the rows.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.optimize import brentq

from planner import coupling_block
from planner.dynamics import Dynamics
from planner.examples import PLAN_ARM, VERTICAL_SEED_ARM
from planner.inverse import InverseDynamicsRequest, solve
from planner.model import Robot
from planner.ocp import plan
from planner.scene import Scene
from testbed.robots import chain

SIGMAS = (1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12)
"""sigma_min(M_pa) of the near-singular starts [kg m^2]."""


def non_finite(value: object, path: str = "") -> list[str]:
    """Paths of every NaN or infinite float inside nested dicts, lists and tuples."""
    if isinstance(value, float):
        return [] if math.isfinite(value) else [path or "."]
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in non_finite(v, f"{path}.{k}")]
    if isinstance(value, (list, tuple)):
        return [p for i, v in enumerate(value) for p in non_finite(v, f"{path}[{i}]")]
    return []


# ------------------------------------------------------------------ near-singular


def waveless_two_link() -> Robot:
    """The planner's two-link arm (planner.examples.PLAN_ARM: passive shoulder, g = 0)
    without waves and inertia: M_pa = m2 l1 l2 cos(q0 - q1)."""
    links = [{**link, "inertia": 0.0, "wave": None} for link in PLAN_ARM["links"]]
    return Robot.model_validate({**PLAN_ARM, "links": links})


def two_link_at(sigma: float) -> np.ndarray:
    """A configuration of `waveless_two_link` with sigma_min(M_pa) = sigma (closed form) [rad]."""
    first, second = PLAN_ARM["links"]
    l1, l2, m2 = first["length"], second["length"], second["mass"]
    return np.array([0.0, math.pi / 2 - math.asin(sigma / (m2 * l1 * l2))])


def waveless_seed() -> Robot:
    """The seed's 4-link arm (planner.examples.VERTICAL_SEED_ARM) without waves, g = 0."""
    return Robot.model_validate({**VERTICAL_SEED_ARM, "gravity": 0.0}).without_waves()


def seed_at(sigma: float, start: list[float], final: list[float]) -> np.ndarray:
    """A configuration of `waveless_seed` on the straight path from `start` to `final` [rad]
    with sigma_min(M_pa) = sigma: the path's first root of det M_pa, then the point between
    it and the nearest of 401 path points with a larger sigma_min where sigma_min equals
    `sigma`."""
    robot = waveless_seed()
    q0, q1 = np.array(start), np.array(final)
    def path(s: np.ndarray) -> np.ndarray:
        return q0 + np.outer(s, q1 - q0)

    def gap(s: float) -> float:
        found = coupling_block.at(robot, path(np.array([s]))[0]).sigma_min
        assert found is not None  # the seed arm has passive joints
        return found - sigma

    grid = np.linspace(0.0, 1.0, 401)
    roots = coupling_block.zeros_along(robot, path, grid)
    assert roots is not None  # its M_pa is square
    root = roots[0]
    sig = coupling_block.along(robot, path(grid)).sigma_min
    above = grid[sig > sigma]
    outer = above[np.argmin(np.abs(above - root))]
    lo, hi = sorted((float(outer), float(root)))
    s = brentq(gap, lo, hi, xtol=1e-18)
    return path(np.array([s]))[0]


def inverse_case(robot: Robot, q: np.ndarray, threshold: float, rate: float = 1.0) -> dict:
    """Classical inverse dynamics starting at q, the active joints turning at `rate` [rad/s]
    (so h_p != 0 and the active accelerations start near -h_p / sigma_min), the passive
    joints moving 0.2 rad in 1 s."""
    passive, active = robot.passive, robot.active
    request = InverseDynamicsRequest.model_validate({
        "robot": robot.model_dump(), "duration": 1.0, "samples": 51,
        "passive_motion": {"profile": "beta", "alpha": 3, "beta": 3,
                           "start": q[passive].tolist(), "end": (q[passive] + 0.2).tolist()},
        "active_initial": {"q": q[active].tolist(), "dq": [rate] * len(active)},
        "sigma_threshold": threshold})
    started = time.perf_counter()
    try:
        result = solve(request)
    except Exception as exc:  # noqa: BLE001 - recorded: solve must not raise
        return {"status": "raised", "message": f"{type(exc).__name__}: {exc}",
                "time": time.perf_counter() - started}
    stop = result.singularity
    return {"status": result.status, "message": result.message,
            "stop_time": stop.time if stop else None,
            "stop_sigma": stop.sigma_min if stop else None,
            "stop_q": stop.q if stop else None,
            "samples": len(result.t), "non_finite": len(non_finite(result.model_dump(mode="json"))),
            "max_tau": float(np.abs(result.tau).max()) if result.tau else None,
            "time": time.perf_counter() - started}


def plan_case(robot: dict, start: list[float], final: list[float], duration: float,
              margin: float | None, N: int = 30) -> dict:
    """Rest-to-rest plan from `start` [rad] to `final` in `duration` [s] (Legendre degree 3
    on N intervals), returned as a row."""
    task = {"duration": duration, "initial": {"q": start, "dq": [0.0] * len(start)},
            "final": {"q": final, "dq": [0.0] * len(start)}}
    if margin is not None:
        task["coupling_margin"] = margin
    scene = Scene.model_validate({"robot": robot, "task": task,
                                  "transcription": {"intervals": N, "degree": 3},
                                  "solver": {"max_wall_time": 60.0}})
    return plan_row(scene)


def plan_row(scene: Scene) -> dict:
    """plan() a scene and summarise the result (exceptions are recorded, not raised):
    `interval_error` is what `verified` judges, `replay_error` the open-loop replay."""
    started = time.perf_counter()
    try:
        result = plan(scene)
    except Exception as exc:  # noqa: BLE001 - recorded: plan must not raise
        return {"status": "raised", "success": False,
                "message": f"{type(exc).__name__}: {exc}"[:300],
                "time": time.perf_counter() - started}
    v = result.verification
    return {"status": result.solver.status, "success": result.solver.success,
            "verified": bool(result.solver.success and v.verified),
            "message": result.solver.message, "iterations": result.solver.iterations,
            "solves": len(result.mesh_passes), "solve": result.solver.solve_time,
            "interval_error": v.local_error, "replay_error": v.resimulation_error,
            "replay_status": v.resimulation_status, "defect": v.defect,
            "min_sigma": v.min_sigma,
            "non_finite": len(non_finite(result.model_dump(mode="json"))),
            "time": time.perf_counter() - started}


# ------------------------------------------------------------------ badly scaled robots


def scaled_cases() -> list[tuple[str, str, dict, float]]:
    """(sweep, value, chain options, duration [s]) of the badly scaled robots, 2 links
    unless varied."""
    cases: list[tuple[str, str, dict, float]] = []
    for ratio in (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3):
        cases.append(("mass ratio m2/m1", f"{ratio:g}", {"masses": [1.0, ratio]}, 2.0))
    for l1, l2 in ((1e-2, 1e-2), (1e-1, 1e-1), (1.0, 1.0), (10.0, 10.0), (1e-2, 10.0),
                   (10.0, 1e-2)):
        cases.append(("lengths l1, l2 [m]", f"{l1:g}, {l2:g}", {"lengths": [l1, l2]}, 2.0))
    for freq in (1.0, 5.0, 10.0, 20.0):
        cases.append(("wave frequency", f"{freq:g}", {"frequency": freq}, 2.0))
    for n in (1, 4, 6, 8):
        cases.append(("links", str(n), {"n": n}, 2.0))
    for T in (0.2, 5.0, 10.0, 20.0):
        cases.append(("horizon [s]", f"{T:g}", {}, T))
    return cases


def scaled_case(sweep: str, value: str, options: dict, duration: float, under: bool,
                N: int = 30) -> dict:
    """Plan one badly scaled robot (`testbed.robots.chain` with `options`): active joints
    move +0.5 rad rest to rest; passive joints start at 0 and end free (any final angle and
    rate), so the task is feasible. `sweep` and `value` name the case."""
    options = dict(options)
    n = options.pop("n", 2)
    robot = chain(n, under, **options)
    joints = [link["joint"] for link in robot["links"]]
    start = [0.1 * k for k in range(n)]
    final_q = [s + 0.5 if j == "active" else None for s, j in zip(start, joints, strict=True)]
    final_dq = [0.0 if j == "active" else None for j in joints]
    scene = Scene.model_validate({
        "robot": robot, "solver": {"max_wall_time": 60.0},
        "transcription": {"intervals": N, "degree": 3},
        "task": {"duration": duration, "initial": {"q": start, "dq": [0.0] * n},
                 "final": {"q": final_q, "dq": final_dq}}})
    return plan_row(scene)


# ------------------------------------------------------------------ dynamics invariants


def invariants(robot: Robot, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict[str, float]:
    """Residuals of the dynamics invariants at one state (each should be ~ 0, except
    `definiteness` = lambda_min / lambda_max of M, which must be > 0).

    asymmetry: max |M - M'| / max |M|; kinetic: |T - dq'M dq / 2| / T;
    power: |dq'(M ddq + h) - dE/dt| over its scale, dE/dt of E = T + V along
    (q, dq) -> (dq, ddq) by a 4th-order central difference of the energy function; the
    scale adds the largest |T| + |V| of the stencil times the largest rate, the power's
    natural size.
    """
    dyn = Dynamics(robot)
    M = dyn.mass_matrix(q)
    eig = np.linalg.eigvalsh((M + M.T) / 2)
    T, _ = dyn.energy(q, dq)
    quad = 0.5 * dq @ M @ dq
    step = 1e-4 / max(1.0, float(np.abs(dq).max()), float(np.abs(ddq).max()))
    stencil = [dyn.energy(q + s * dq + 0.5 * s * s * ddq, dq + s * ddq)
               for s in (2 * step, step, -step, -2 * step)]
    E = [t + v for t, v in stencil]
    dE = (-E[0] + 8 * E[1] - 8 * E[2] + E[3]) / (12 * step)
    Q = dyn.inverse(q, dq, ddq)
    power = float(dq @ Q)
    rate = max(1.0, float(np.abs(dq).max()), float(np.abs(ddq).max()))  # [1/s]
    size = max(abs(t) + abs(v) for t, v in stencil)  # [J]
    scale = float(np.abs(dq) @ np.abs(Q)) + abs(dE) + size * rate
    return {"asymmetry": float(np.abs(M - M.T).max() / np.abs(M).max()),
            "definiteness": float(eig.min() / eig.max()),
            "kinetic": abs(T - quad) / T if T > 0 else abs(quad),
            "power": abs(power - dE) / scale if scale > 0 else abs(power - dE)}
