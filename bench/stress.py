"""Numerical and operational stress: what undertow does at its edges.

1. Near-singular configurations, sigma_min(M_pa) from 1e-2 down to 1e-12 (waveless 2-link
   arm in closed form, and the seed's waveless 4-link arm along its reference path): the
   classical inverse dynamics must stop with its report, the planner must return finite
   numbers or a structured failure.
2. Badly scaled robots (mass ratios 1e-3..1e3, lengths 1e-2..10 m, wave frequency up to 20,
   up to 8 links, horizons up to 20 s), each planned once, fully actuated and
   underactuated: success rate, worst re-simulation error, non-finite values anywhere in
   the returned models (`model_dump(mode="json")`, walked recursively).
3. Random robots (n 1..8, all scales above): symmetry and positive definiteness of M,
   T = dq'M dq / 2, and the power balance dq'(M ddq + h) = dE/dt with dE/dt from
   finite differences of the energy function; worst residuals over the draws.
4. The service on a live uvicorn: a worker killed mid-solve, clients that disconnect,
   malformed bodies (hand-made, and schemathesis' positive and negative cases).

Writes docs/stability.md and bench/results/stress_*.csv.

    .venv/bin/python bench/stress.py [--parts singular scaled random service]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (
    DOCS,
    RESULTS,
    ROOT,
    SEED_ARM,
    SEED_TASK,
    UNDERACTUATED,
    isolated,
    machine_note,
    table,
    write_csv,
    write_section,
)
from planner import coupling_block
from planner.dynamics import Dynamics
from planner.inverse import InverseDynamicsRequest, solve
from planner.model import Robot
from planner.ocp import plan
from planner.scene import Scene

SIGMAS = (1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12)


# ------------------------------------------------------------------ finiteness


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
    """tests/test_ocp.py UNDERACTUATED without waves and inertia: M_pa = m2 l1 l2 cos(q0 - q1)."""
    links = [{**link, "inertia": 0.0, "wave": None} for link in UNDERACTUATED["links"]]
    return Robot.model_validate({**UNDERACTUATED, "links": links})


def two_link_at(sigma: float) -> np.ndarray:
    """A configuration of `waveless_two_link` with sigma_min(M_pa) = sigma (closed form)."""
    l1, l2, m2 = (UNDERACTUATED["links"][0]["length"], UNDERACTUATED["links"][1]["length"],
                  UNDERACTUATED["links"][1]["mass"])
    return np.array([0.0, math.pi / 2 - math.asin(sigma / (m2 * l1 * l2))])


def waveless_seed() -> Robot:
    return Robot.model_validate({**SEED_ARM, "gravity": 0.0}).without_waves()


def seed_at(sigma: float) -> np.ndarray:
    """A configuration of the waveless seed arm on its reference straight path (start to
    final of bench.common.SEED_TASK) with sigma_min(M_pa) = sigma: the path's first root of
    det M_pa, then the point between it and the nearest of 401 path points with a larger
    sigma_min where sigma_min equals `sigma`."""
    robot = waveless_seed()
    q0, q1 = np.array(SEED_TASK["initial"]["q"]), np.array(SEED_TASK["final"]["q"])
    path = lambda s: q0 + np.outer(s, q1 - q0)
    grid = np.linspace(0.0, 1.0, 401)
    root = coupling_block.zeros_along(robot, path, grid)[0]
    sig = coupling_block.along(robot, path(grid)).sigma_min
    above = grid[sig > sigma]
    outer = above[np.argmin(np.abs(above - root))]
    s = brentq(lambda s: coupling_block.at(robot, path([s])[0]).sigma_min - sigma,
               *sorted((outer, root)), xtol=1e-18)
    return path([s])[0]


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
            "stop_time": stop.time if stop else None, "stop_sigma": stop.sigma_min if stop else None,
            "stop_q": stop.q if stop else None,
            "samples": len(result.t), "non_finite": len(non_finite(result.model_dump(mode="json"))),
            "max_tau": float(np.abs(result.tau).max()) if result.tau else None,
            "time": time.perf_counter() - started}


def plan_case(robot: dict, start: list[float], final: list[float], duration: float,
              margin: float | None, N: int = 30) -> dict:
    """Rest-to-rest plan from `start` (Legendre degree 3), returned as a row."""
    task = {"duration": duration, "initial": {"q": start, "dq": [0.0] * len(start)},
            "final": {"q": final, "dq": [0.0] * len(start)}}
    if margin is not None:
        task["coupling_margin"] = margin
    scene = Scene.model_validate({"robot": robot, "task": task,
                                  "transcription": {"intervals": N, "degree": 3},
                                  "solver": {"max_wall_time": 60.0}})
    return plan_row(scene)


def plan_row(scene: Scene) -> dict:
    """plan() a scene and summarise the result (exceptions are recorded, not raised)."""
    started = time.perf_counter()
    try:
        result = plan(scene)
    except Exception as exc:  # noqa: BLE001 - recorded: plan must not raise
        return {"status": "raised", "success": False,
                "message": f"{type(exc).__name__}: {exc}"[:300],
                "time": time.perf_counter() - started}
    v = result.verification
    return {"status": result.solver.status, "success": result.solver.success,
            "message": result.solver.message, "iterations": result.solver.iterations,
            "solve": result.solver.solve_time, "resim_error": v.resimulation_error,
            "resim_status": v.resimulation_status, "defect": v.defect,
            "min_sigma": v.min_sigma,
            "non_finite": len(non_finite(result.model_dump(mode="json"))),
            "time": time.perf_counter() - started}


ARMS = {"2-link": (waveless_two_link, two_link_at), "seed 4-link": (waveless_seed, seed_at)}
INVERSE_TIMEOUT = 120.0  # [s] a classical inverse-dynamics case still running is recorded


def inverse_point(arm: str, sigma: float, threshold: float) -> dict:
    """`inverse_case` at the configuration of `arm` with sigma_min(M_pa) = sigma."""
    robot_of, at = ARMS[arm]
    robot, q = robot_of(), at(sigma)
    out = inverse_case(robot, q, threshold)
    out.pop("stop_q", None)
    return {"actual": coupling_block.at(robot, q).sigma_min, **out}


def singular_rows() -> list[dict]:
    rows = []
    for arm in ARMS:
        for sigma in SIGMAS:
            for threshold in (1e-3, sigma / 10):
                started = time.perf_counter()
                out = isolated("stress", "inverse_point",
                               {"arm": arm, "sigma": sigma, "threshold": threshold}, INVERSE_TIMEOUT)
                rows.append({"part": "inverse", "arm": arm, "sigma": sigma, "threshold": threshold,
                             "wall": time.perf_counter() - started, **out})
                print(json.dumps(rows[-1]), flush=True)
    wavy = {**UNDERACTUATED, "links": [{**link, "inertia": 0.0} for link in UNDERACTUATED["links"]]}
    for sigma in SIGMAS:
        q = two_link_at(sigma).tolist()
        final = [q[0] + 0.3, q[1] - 0.5]
        for robot_name, robot in (("waveless", waveless_two_link().model_dump()), ("with wave", wavy)):
            for margin in (None, 1e-3):
                out = isolated("stress", "plan_case",
                               {"robot": robot, "start": q, "final": final, "duration": 2.0,
                                "margin": margin}, 300)
                rows.append({"part": "plan", "arm": f"2-link {robot_name}", "sigma": sigma,
                             "margin": margin, **out})
                print(json.dumps(rows[-1]), flush=True)
    for sigma in (1e-2, 1e-6, 1e-12):
        out = isolated("stress", "plan_case",
                       {"robot": waveless_seed().model_dump(), "start": seed_at(sigma).tolist(),
                        "final": SEED_TASK["final"]["q"], "duration": 4.0, "margin": None}, 600)
        rows.append({"part": "plan", "arm": "seed 4-link waveless", "sigma": sigma,
                     "margin": None, **out})
        print(json.dumps(rows[-1]), flush=True)
    return rows


# ------------------------------------------------------------------ badly scaled robots


def chain(n: int, under: bool, masses=None, lengths=None, frequency: float = 3.0,
          gravity: float = 9.81) -> dict:
    """n links (0.4 m, 1 kg, I = m l^2 / 50 unless given); under: even joints passive;
    active odd joints carry a wave of amplitude 0.1 l, `frequency`, phase 0.3."""
    masses = masses or [1.0] * n
    lengths = lengths or [0.4] * n
    links = []
    for k in range(n):
        active = (k % 2 == 1) or not under or n == 1
        link = {"length": lengths[k], "mass": masses[k],
                "inertia": masses[k] * lengths[k] ** 2 / 50, "joint": "active" if active else "passive"}
        if active and k % 2 == 1:
            link["wave"] = {"amplitude": 0.1 * lengths[k], "frequency": frequency, "phase": 0.3}
        links.append(link)
    return {"links": links, "gravity": gravity}


def scaled_cases() -> list[tuple[str, str, dict, float]]:
    """(sweep, value, robot, duration) of the badly scaled robots, 2 links unless varied."""
    cases = []
    for ratio in (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3):
        cases.append(("mass ratio m2/m1", f"{ratio:g}", {"masses": [1.0, ratio]}, 2.0))
    for l1, l2 in ((1e-2, 1e-2), (1e-1, 1e-1), (1.0, 1.0), (10.0, 10.0), (1e-2, 10.0), (10.0, 1e-2)):
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
    """Plan one badly scaled robot: active joints move +0.5 rad rest to rest; passive
    joints start at 0 and end free (any final angle and rate), so the task is feasible."""
    options = dict(options)
    n = options.pop("n", 2)
    robot = chain(n, under, **options)
    joints = [link["joint"] for link in robot["links"]]
    start = [0.1 * k for k in range(n)]
    final_q = [s + 0.5 if j == "active" else None for s, j in zip(start, joints)]
    final_dq = [0.0 if j == "active" else None for j in joints]
    scene = Scene.model_validate({
        "robot": robot, "solver": {"max_wall_time": 60.0}, "transcription": {"intervals": N, "degree": 3},
        "task": {"duration": duration, "initial": {"q": start, "dq": [0.0] * n},
                 "final": {"q": final_q, "dq": final_dq}}})
    return plan_row(scene)


def scaled_rows() -> list[dict]:
    rows = []
    for sweep, value, options, duration in scaled_cases():
        for under in (False, True):
            if under and options.get("n") == 1:
                continue
            out = isolated("stress", "scaled_case",
                           {"sweep": sweep, "value": value, "options": options,
                            "duration": duration, "under": under}, 300)
            rows.append({"sweep": sweep, "value": value,
                         "arm": "underactuated" if under else "fully actuated", **out})
            print(json.dumps(rows[-1]), flush=True)
    return rows


# ------------------------------------------------------------------ random robots


def random_robot(rng: np.random.Generator) -> Robot:
    """n 1..8; lengths 1e-2..10 m, masses 1e-3..1e3 kg (log-uniform), inertia 0 or up to
    m l^2; joints active with probability 1/2 (at least one); active joints carry a wave
    with probability 3/4, amplitude up to 0.9 l, frequency 0..20; g 0 or 0..20."""
    n = int(rng.integers(1, 9))
    active = rng.random(n) < 0.5
    active[rng.integers(n)] = True
    links = []
    for k in range(n):
        length, mass = 10 ** rng.uniform(-2, 1), 10 ** rng.uniform(-3, 3)
        link = {"length": length, "mass": mass,
                "inertia": 0.0 if rng.random() < 0.3 else mass * length**2 * rng.random(),
                "joint": "active" if active[k] else "passive"}
        if active[k] and rng.random() < 0.75:
            link["wave"] = {"amplitude": 0.9 * length * rng.random(),
                            "frequency": 20 * rng.random(), "phase": rng.uniform(-np.pi, np.pi)}
        links.append(link)
    return Robot.model_validate({"links": links,
                                 "gravity": 0.0 if rng.random() < 0.3 else 20 * rng.random(),
                                 "rotational_inertia": str(rng.choice(["cumulative", "absolute"]))})


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


def random_rows(count: int, seed: int = 20261122) -> tuple[list[dict], dict]:
    rng = np.random.default_rng(seed)
    rows, started = [], time.perf_counter()
    for k in range(count):
        robot = random_robot(rng)
        q, dq, ddq = rng.uniform(-np.pi, np.pi, robot.n), rng.uniform(-3, 3, robot.n), rng.uniform(-3, 3, robot.n)
        rows.append({"robot": k, "n": robot.n, **invariants(robot, q, dq, ddq)})
    summary = {"robots": count, "time": time.perf_counter() - started,
               **{f"worst {key}": (min if key == "definiteness" else max)(r[key] for r in rows)
                  for key in ("asymmetry", "definiteness", "kinetic", "power")}}
    return rows, summary


# ------------------------------------------------------------------ the service


QUICK = {"robot": {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3.0, "phase": 0.3}}], "gravity": 9.81},
    "task": {"duration": 2.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
             "final": {"q": [1.0, None], "dq": [0.0, 0.0]}},
    "transcription": {"intervals": 10}}
LONG = {**QUICK, "task": {**QUICK["task"], "final": {"q": [None, None], "dq": [0.0, 0.0]},
                          "tip_target": {"x": 5.0, "y": 5.0}, "torque_limit": 0.5},
        "transcription": {"intervals": 80, "degree": 3}, "solver": {"max_iter": 100000, "max_wall_time": 60}}
"""An unreachable tip under a torque limit: Ipopt iterates for many seconds."""


def malformed_bodies() -> list[tuple[str, bytes, str]]:
    """(name, body, content type) of hand-made bad requests for POST /v1/plans."""
    good = json.dumps(QUICK)
    return [
        ("empty body", b"", "application/json"),
        ("truncated JSON", good[:40].encode(), "application/json"),
        ("JSON null", b"null", "application/json"),
        ("JSON array", b"[]", "application/json"),
        ("NaN literal", good.replace('"mass": 1.0', '"mass": NaN', 1).encode(), "application/json"),
        ("Infinity literal", good.replace('"duration": 2.0', '"duration": Infinity').encode(), "application/json"),
        ("number overflow 1e999", good.replace('"duration": 2.0', '"duration": 1e999').encode(), "application/json"),
        ("string for a number", good.replace('"duration": 2.0', '"duration": "two"').encode(), "application/json"),
        ("deep nesting (100000 [)", b"[" * 100_000 + b"]" * 100_000, "application/json"),
        ("invalid UTF-8", b'{"robot": "\xff\xfe"}', "application/json"),
        ("text/plain content type", good.encode(), "text/plain"),
        ("form content type", b"a=1&b=2", "application/x-www-form-urlencoded"),
        ("over the body limit (2 MB)", (good[:-1] + ', "pad": "' + "x" * 2_000_000 + '"}').encode(), "application/json"),
        ("unknown field", good.replace('"task"', '"tsk"').encode(), "application/json"),
        ("negative intervals", good.replace('"intervals": 10', '"intervals": -5').encode(), "application/json"),
        ("10^9 intervals", good.replace('"intervals": 10', '"intervals": 1000000000').encode(), "application/json"),
        ("10 links", json.dumps({**QUICK, "robot": {"links": QUICK["robot"]["links"] * 5}}).encode(), "application/json"),
        ("huge integer", good.replace('"intervals": 10', '"intervals": ' + "9" * 5000).encode(), "application/json"),
    ]


def _children(pid: int) -> list[int]:
    """Process ids whose parent is pid (read from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError), open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
                if int(fields[1]) == pid:
                    out.append(int(entry))
    return out


def _cmdline(pid: int) -> str:
    with contextlib.suppress(OSError), open(f"/proc/{pid}/cmdline", "rb") as f:
        return f.read().replace(b"\0", b" ").decode(errors="replace")
    return ""


def worker_pids(server_pid: int) -> list[int]:
    """The plan workers of a server: its spawned children (not the resource tracker)."""
    return [p for p in _children(server_pid)
            if "spawn_main" in _cmdline(p) and "resource_tracker" not in _cmdline(p)]


def kill_worker_case(live, http) -> dict:
    """SIGKILL the worker processes while a long plan runs; the job must fail with the
    worker-died error, the server must stay healthy and plan the next scene."""
    from service_fixtures import wait_final

    job_id = http.post("/v1/plans", json=LONG).json()["id"]
    deadline = time.monotonic() + 60
    while http.get(f"/v1/plans/{job_id}").json()["progress"] is None:
        assert time.monotonic() < deadline, "the long plan reported no progress"
        time.sleep(0.05)
    workers = worker_pids(live.proc.pid)
    killed_at = time.monotonic()
    for pid in workers:
        os.kill(pid, signal.SIGKILL)
    job = wait_final(http, job_id, timeout=30)
    noticed = time.monotonic() - killed_at
    health = http.get("/healthz").status_code
    after = http.post("/v1/plans?wait=30", json=QUICK).json()
    return {"fault": "plan workers SIGKILLed mid-solve", "workers killed": len(workers),
            "job status": job["status"], "job error": job["error"],
            "seconds to fail the job": round(noticed, 2), "healthz": health,
            "next plan": after["status"],
            "ok": job["status"] == "failed" and health == 200 and after["status"] == "succeeded"}


def disconnect_cases(live, http) -> list[dict]:
    """Clients that go away: mid-wait, mid-body, before reading the answer."""
    import httpx
    from service_fixtures import wait_final

    rows = []
    before = {j["id"] for j in http.get("/v1/plans?limit=100").json()["items"]}
    try:
        httpx.post(live.url + "/v1/plans?wait=30", json=LONG, timeout=0.5)
        gone = "client waited for its answer"
    except httpx.TimeoutException:
        gone = "client left after 0.5 s"
    new = [j["id"] for j in http.get("/v1/plans?limit=100").json()["items"] if j["id"] not in before]
    status = None
    if new:
        http.delete(f"/v1/plans/{new[0]}")
        status = wait_final(http, new[0], timeout=30)["status"]
    rows.append({"fault": "client disconnects during POST ?wait=30", "what": gone,
                 "jobs created": len(new), "job then": status,
                 "healthz": http.get("/healthz").status_code,
                 "ok": len(new) == 1 and status == "cancelled"})
    body = json.dumps(QUICK).encode()
    with socket.create_connection(("127.0.0.1", live.port), timeout=5) as sock:
        sock.sendall(b"POST /v1/plans HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                     + f"Content-Length: {len(body)}\r\n\r\n".encode() + body[: len(body) // 3])
    time.sleep(0.5)
    after = [j["id"] for j in http.get("/v1/plans?limit=100").json()["items"] if j["id"] not in before]
    rows.append({"fault": "client sends a third of the body and closes", "jobs created": len(after) - len(new),
                 "healthz": http.get("/healthz").status_code, "ok": len(after) == len(new)})
    for _ in range(20):
        with socket.create_connection(("127.0.0.1", live.port), timeout=5) as sock:
            sock.sendall(b"GET /v1/examples HTTP/1.1\r\nHost: x\r\n\r\n")
    rows.append({"fault": "20 clients close before reading GET /v1/examples",
                 "healthz": http.get("/healthz").status_code,
                 "ok": http.get("/v1/examples").status_code == 200})
    return rows


def malformed_rows(url: str) -> list[dict]:
    """Every hand-made bad body, POSTed to /v1/plans and /v1/dynamics: 4xx problem+json."""
    import httpx

    rows = []
    with httpx.Client(base_url=url, timeout=30) as http:
        for name, body, ctype in malformed_bodies():
            for path in ("/v1/plans", "/v1/dynamics"):
                r = http.post(path, content=body, headers={"Content-Type": ctype})
                detail = ""
                with contextlib.suppress(ValueError):
                    detail = str(r.json().get("detail", ""))[:90]
                rows.append({"body": name, "path": path, "status": r.status_code,
                             "type": r.headers.get("content-type", ""), "detail": detail,
                             "ok": 400 <= r.status_code < 500
                             and r.headers.get("content-type", "").startswith("application/problem+json")})
    return rows


def schemathesis_run(url: str, examples: int, workdir: Path) -> dict:
    """Schemathesis (positive and negative generation) against the committed OpenAPI."""
    checks = ("not_a_server_error,response_schema_conformance,status_code_conformance,"
              "content_type_conformance")
    started = time.perf_counter()
    run = subprocess.run(
        [sys.executable, "-m", "schemathesis.cli", "run", str(ROOT / "openapi" / "openapi.json"),
         "--url", url, "--checks", checks, "--mode", "all", "--max-examples", str(examples),
         "--seed", "2", "--workers", "1", "--request-timeout", "30",
         "--generation-database", "none", "--no-color"],
        check=False, cwd=workdir, capture_output=True, text=True, timeout=1800)
    summary = run.stdout.split("SUMMARY")[-1]
    return {"examples per operation": examples, "exit code": run.returncode,
            "time [s]": round(time.perf_counter() - started), "summary": summary.strip()}


def service_rows(examples: int) -> tuple[list[dict], list[dict], dict]:
    import httpx
    from service_fixtures import LiveServer

    tmp = Path(tempfile.mkdtemp(prefix="undertow-stress-"))
    limits = {"UNDERTOW_MAX_NODES": "400", "UNDERTOW_MAX_WALL_TIME": "60",
              "UNDERTOW_MAX_QUEUED": "4", "UNDERTOW_MAX_WAIT": "30"}
    with LiveServer(tmp / "jobs.sqlite3", **limits) as live, \
            httpx.Client(base_url=live.url, timeout=60) as http:
        faults = [kill_worker_case(live, http), *disconnect_cases(live, http)]
        bodies = malformed_rows(live.url)
        fuzz = schemathesis_run(live.url, examples, tmp)
        faults.append({"fault": "after all of the above", "healthz": http.get("/healthz").status_code,
                       "ok": http.get("/healthz").status_code == 200})
    return faults, bodies, fuzz


# ------------------------------------------------------------------ report

DOC = DOCS / "stability.md"


def singular_text(rows: list[dict]) -> str:
    inverse = [r for r in rows if r["part"] == "inverse"]
    plans = [r for r in rows if r["part"] == "plan"]
    return "\n\n".join([
        ("Classical inverse dynamics (`planner.inverse.solve`) started at a configuration with "
        "the given sigma_min(M_pa), the active joints turning at 1 rad/s (so the passive rows "
        "ask for active accelerations near -h_p / sigma_min), the passive joints moving 0.2 rad "
        "in 1 s; once with the default threshold 1e-3, once with a threshold ten times below "
        f"the start's sigma_min. Each case in its own process, stopped after {INVERSE_TIMEOUT:g} s. "
        "A threshold below the resolution floor (`planner.inverse.RESOLUTION` = 1e-8 of the "
        "largest diagonal entry of M: 4.5e-9 on the 2-link arm, 7.3e-9 on the seed arm) stops "
        "at the floor, or at once when the start lies below it: closer to the singularity, "
        "rounding in M_pa, divided by sigma_min, becomes noise larger than the integration "
        "tolerance and DOP853's steps collapse."),
        table(inverse, [("arm", "arm"), ("sigma", "sigma_min target"), ("actual", "sigma_min at q"),
                        ("threshold", "threshold"), ("status", "status"), ("stop_time", "stop t [s]"),
                        ("stop_sigma", "sigma_min at stop"), ("max_tau", "max abs tau [N m]"),
                        ("non_finite", "non-finite values"), ("time", "time [s]"),
                        ("failure", "failure")]),
        ("The planner from the same near-singular start (rest to rest, Legendre degree 3, N = 30; "
        "2-link: 2 s to (q0 + 0.3, q1 - 0.5); seed arm: 4 s to the reference final "
        "configuration), without and with a coupling margin of 1e-3 (which the start violates "
        "for sigma_min < 1e-3 on the waveless arm):"),
        table(plans, [("arm", "arm"), ("sigma", "sigma_min at start"), ("margin", "margin"),
                      ("status", "status"), ("success", "success"), ("iterations", "iterations"),
                      ("resim_error", "re-sim. error [rad]"), ("min_sigma", "min sigma_min"),
                      ("non_finite", "non-finite values"), ("time", "time [s]"),
                      ("message", "message")]),
    ])


def scaled_text(rows: list[dict]) -> str:
    summary = []
    for sweep in dict.fromkeys(r["sweep"] for r in rows):
        mine = [r for r in rows if r["sweep"] == sweep]
        ok = [r for r in mine if r.get("success")]
        errors = [r["resim_error"] for r in ok if r.get("resim_error") is not None]
        summary.append({"sweep": sweep, "plans": len(mine), "succeeded": len(ok),
                        "rate": len(ok) / len(mine),
                        "worst": max(errors) if errors else None,
                        "non_finite": sum(r.get("non_finite") or 0 for r in mine),
                        "raised": sum(r.get("status") in ("raised", "crashed") or "failure" in r
                                      for r in mine)})
    return "\n\n".join([
        ("One plan per robot and arm type (Legendre degree 3, N = 30, 60 s wall-time cap): "
        "active joints move +0.5 rad rest to rest; passive joints start at rest and end free, "
        "so every task is feasible and a failure is the solver's. Base robot: 2 links of "
        "0.4 m, 1 kg, I = m l^2 / 50, g = 9.81, a wave (0.1 l, frequency 3, phase 0.3) on "
        "odd joints; underactuated: even joints passive. Each plan in its own process."),
        table(summary, [("sweep", "sweep"), ("plans", "plans"), ("succeeded", "succeeded"),
                        ("rate", "success rate"), ("worst", "worst re-sim. error [rad]"),
                        ("non_finite", "non-finite values"), ("raised", "raised or crashed")]),
        table(rows, [("sweep", "sweep"), ("value", "value"), ("arm", "arm"), ("status", "status"),
                     ("iterations", "iterations"), ("solve", "solve [s]"),
                     ("resim_error", "re-sim. error [rad]"), ("defect", "defect [N m s]"),
                     ("non_finite", "non-finite values"), ("message", "message")]),
    ])


def random_text(summary: dict) -> str:
    return "\n\n".join([
        (f"{summary['robots']} random robots (`random_robot`: 1 to 8 links, lengths 1e-2..10 m "
        "and masses 1e-3..1e3 kg log-uniform, inertias 0 or up to m l^2, random joint types, "
        "waves of amplitude up to 0.9 l and frequency up to 20, g 0 or up to 20, both "
        "rotational conventions), one random state each (q in [-pi, pi], dq and ddq in [-3, 3]). "
        f"Took {summary['time']:.0f} s. Worst over all robots:"),
        table([{"check": "asymmetry max abs(M - M') / max abs(M)", "worst": summary["worst asymmetry"],
                "bound": "0 (exact)"},
               {"check": "definiteness lambda_min / lambda_max of M", "worst": summary["worst definiteness"],
                "bound": "> 0"},
               {"check": "kinetic abs(T - dq'M dq / 2) / T", "worst": summary["worst kinetic"],
                "bound": "~1e-15"},
               {"check": "power abs(dq'(M ddq + h) - dE/dt) / scale", "worst": summary["worst power"],
                "bound": "~1e-9 (finite differences)"}],
              [("check", "invariant"), ("worst", "worst value"), ("bound", "expected")]),
        ("The same invariants run under hypothesis in tests/test_stress.py "
        "(`test_random_robots_keep_the_dynamics_invariants`, 1000 examples, slow)."),
    ])


def service_text(faults: list[dict], bodies: list[dict], fuzz: dict) -> str:
    keys = list(dict.fromkeys(k for r in faults for k in r))
    return "\n\n".join([
        ("A live uvicorn (`app.main:app`, 2 worker processes, tests/service_fixtures.py "
        "`LiveServer`) on 127.0.0.1 with a temporary store."),
        table(faults, [(k, k) for k in keys]),
        ("Hand-made malformed bodies, each POSTed to /v1/plans and /v1/dynamics; `ok` means a "
        "4xx answer with an application/problem+json body:"),
        table(bodies, [("body", "body"), ("path", "path"), ("status", "status"), ("ok", "ok"),
                       ("detail", "detail")]),
        (f"Schemathesis {_schemathesis_version()} against the committed openapi/openapi.json, "
        f"positive and negative generation (`--mode all`), {fuzz['examples per operation']} "
        "examples per operation, checks not_a_server_error, response_schema_conformance, "
        f"status_code_conformance, content_type_conformance; exit code {fuzz['exit code']}, "
        f"{fuzz['time [s]']} s:"),
        "```\n" + fuzz["summary"] + "\n```",
    ])


def _schemathesis_version() -> str:
    try:
        import schemathesis
    except ImportError:
        return "(not installed)"
    return schemathesis.__version__


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", default=["singular", "scaled", "random", "service"])
    parser.add_argument("--robots", type=int, default=1000)
    parser.add_argument("--examples", type=int, default=25, help="schemathesis, per operation")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "tests"))
    note = machine_note()
    command = ".venv/bin/python bench/stress.py " + " ".join(sys.argv[1:])
    stamp = f"Generated by `{command.strip()}` on {note}."
    if "singular" in args.parts:
        rows = singular_rows()
        write_csv(RESULTS / "stress_singular.csv", _flat(rows))
        write_section(DOC, "Near-singular configurations", stamp + "\n\n" + singular_text(rows))
    if "scaled" in args.parts:
        rows = scaled_rows()
        write_csv(RESULTS / "stress_scaled.csv", _flat(rows))
        write_section(DOC, "Badly scaled robots", stamp + "\n\n" + scaled_text(rows))
    if "random" in args.parts:
        rows, summary = random_rows(args.robots)
        write_csv(RESULTS / "stress_random.csv", rows)
        write_section(DOC, "Random robots: dynamics invariants", stamp + "\n\n" + random_text(summary))
    if "service" in args.parts:
        faults, bodies, fuzz = service_rows(args.examples)
        write_csv(RESULTS / "stress_service.csv", _flat(faults + bodies))
        write_section(DOC, "The service under faults",
                      stamp + "\n\n" + service_text(faults, bodies, fuzz))


def _flat(rows: list[dict]) -> list[dict]:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    return [{k: r.get(k) for k in keys} for r in rows]


if __name__ == "__main__":
    main()
