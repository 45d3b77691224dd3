#!/usr/bin/env bash
# Smoke checks of a running undertow server (a container or any deployment).
#
#   docker/smoke.sh wait  URL [SECONDS]   wait until GET URL/healthz answers 200
#   docker/smoke.sh check URL             API key gate, dynamics of a 2-link arm and, when
#                                         SMOKE_PLAN=1, a plan of a built-in example; prints
#                                         the plan job id (if any) as the last stdout line
#   docker/smoke.sh fetch URL JOB_ID      the job is stored and succeeded (e.g. after restart)
#
# Environment: UNDERTOW_API_KEY (sent as X-API-Key, and its absence must give 401),
# SMOKE_PLAN (1: plan an example), SMOKE_PLAN_WAIT (seconds, default 120),
# SMOKE_PLAN_SCENE (a scene JSON file to plan instead of a built-in example).
# Exit status 0 when every check passes; each failure is printed as "smoke: FAIL ...".
set -euo pipefail
exec python3 - "$@" <<'PY'
import json
import math
import os
import sys
import time
import urllib.error
import urllib.request
from email.message import Message

API_KEY = os.environ.get("UNDERTOW_API_KEY") or None
PLAN = os.environ.get("SMOKE_PLAN", "0") == "1"
PLAN_WAIT = float(os.environ.get("SMOKE_PLAN_WAIT", "120"))
PLAN_SCENE = os.environ.get("SMOKE_PLAN_SCENE") or None

# Two links, the design's example arm; the passive first link has no wave, so its tip is
# l0 (cos q0, sin q0) exactly.
ROBOT = {
    "links": [
        {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
         "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}},
    ],
    "gravity": 9.81,
    "rotational_inertia": "cumulative",
}
STATE = {"q": [0.1, 0.5], "dq": [1.0, -0.5]}


class Failure(Exception):
    pass


def log(message: str) -> None:
    print(f"smoke: {message}", file=sys.stderr, flush=True)


def request(base: str, method: str, path: str, body: object = None, key: bool = True,
            timeout: float = 30.0) -> tuple[int, Message, object]:
    """(status, headers (case-insensitive), decoded JSON body or text) of one request."""
    headers = {"Accept": "application/json"}
    data = None
    if body is not None:
        data = json.dumps(body).encode()
        headers["Content-Type"] = "application/json"
    if key and API_KEY:
        headers["X-API-Key"] = API_KEY
    req = urllib.request.Request(base + path, data=data, method=method, headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            status, head, raw = resp.status, resp.headers, resp.read()
    except urllib.error.HTTPError as err:
        status, head, raw = err.code, err.headers, err.read()
    text = raw.decode(errors="replace")
    try:
        return status, head, json.loads(text)
    except json.JSONDecodeError:
        return status, head, text


def expect(condition: bool, message: str) -> None:
    if not condition:
        raise Failure(message)


def wait(base: str, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    last = "no answer"
    while time.monotonic() < deadline:
        try:
            status, _, _ = request(base, "GET", "/healthz", key=False, timeout=3)
            if status == 200:
                log(f"/healthz answered 200 after {seconds - (deadline - time.monotonic()):.1f} s")
                return
            last = f"HTTP {status}"
        except OSError as err:
            last = str(err)
        time.sleep(0.5)
    raise Failure(f"/healthz did not answer 200 within {seconds:g} s (last: {last})")


def check_auth(base: str) -> None:
    if not API_KEY:
        log("no UNDERTOW_API_KEY: API key gate not checked")
        return
    status, _, _ = request(base, "GET", "/healthz", key=False)
    expect(status == 200, f"/healthz without the key: expected 200, got {status}")
    status, head, body = request(base, "POST", "/v1/dynamics",
                                 {"robot": ROBOT, "states": [STATE]}, key=False)
    expect(status == 401, f"/v1/dynamics without the key: expected 401, got {status}")
    expect(head.get("Content-Type", "").startswith("application/problem+json"),
           f"401 must be problem+json, got {head.get('Content-Type')!r}")
    log("API key gate: /healthz open, /v1/dynamics 401 without the key")


def check_dynamics(base: str) -> None:
    status, _, body = request(base, "POST", "/v1/dynamics", {"robot": ROBOT, "states": [STATE]})
    expect(status == 200, f"/v1/dynamics: expected 200, got {status}: {body}")
    result = body["results"][0]
    m, dq = result["M"], STATE["dq"]
    expect(len(m) == 2 and all(len(row) == 2 for row in m), f"M must be 2x2, got {m}")
    expect(all(math.isfinite(v) for row in m for v in row), f"M not finite: {m}")
    expect(abs(m[0][1] - m[1][0]) <= 1e-12 * (1 + abs(m[0][1])), f"M not symmetric: {m}")
    expect(m[0][0] > 0 and m[0][0] * m[1][1] - m[0][1] ** 2 > 0, f"M not positive definite: {m}")
    kinetic = 0.5 * sum(dq[i] * m[i][j] * dq[j] for i in range(2) for j in range(2))
    expect(math.isclose(result["kinetic_energy"], kinetic, rel_tol=1e-9),
           f"kinetic energy {result['kinetic_energy']} != dq.M.dq/2 = {kinetic}")
    tip = [0.5 * math.cos(STATE["q"][0]), 0.5 * math.sin(STATE["q"][0])]
    expect(all(math.isclose(a, b, rel_tol=1e-9) for a, b in zip(result["tips"][0], tip)),
           f"tip of link 0 {result['tips'][0]} != {tip}")
    log("POST /v1/dynamics: M symmetric positive definite, T = dq.M.dq/2, tip 0 exact")


def plan_example(base: str) -> tuple[str, dict]:
    """(name, scene) of SMOKE_PLAN_SCENE or else the first built-in example of kind "plan"."""
    if PLAN_SCENE:
        with open(PLAN_SCENE, encoding="utf-8") as file:
            return PLAN_SCENE, json.load(file)
    status, _, body = request(base, "GET", "/v1/examples")
    expect(status == 200, f"/v1/examples: expected 200, got {status}: {body}")
    for item in body:
        if item["kind"] == "plan":
            return item["name"], item["request"]
    raise Failure("/v1/examples offers no example of kind 'plan'")


def finished(base: str, job_id: str, deadline: float) -> dict:
    """The job once it has ended (polled until `deadline`, a monotonic time)."""
    while True:
        status, _, job = request(base, "GET", f"/v1/plans/{job_id}")
        expect(status == 200, f"GET /v1/plans/{job_id}: expected 200, got {status}: {job}")
        if job["status"] not in ("queued", "running"):
            return job
        expect(time.monotonic() < deadline, f"plan {job_id} still {job['status']} at the deadline")
        time.sleep(1.0)


def check_plan(base: str) -> str:
    name, scene = plan_example(base)
    started = time.monotonic()
    status, head, job = request(base, "POST", f"/v1/plans?wait={PLAN_WAIT:g}", scene,
                                timeout=PLAN_WAIT + 30)
    expect(status in (200, 202), f"POST /v1/plans ({name}): expected 200/202, got {status}: {job}")
    if status == 202:
        job = finished(base, job["id"], started + PLAN_WAIT)
    expect(job["status"] == "succeeded",
           f"plan {name}: status {job['status']}: {json.dumps(job)[:2000]}")
    plan = job["plan"]
    expect(len(plan["t"]) == len(plan["q"]) == len(plan["tau"]) > 1,
           f"plan {name}: t, q and tau must have one row per node")
    log(f"POST /v1/plans ({name}): succeeded in {time.monotonic() - started:.1f} s, "
        f"{len(plan['t'])} nodes, solver {plan['solver']['status']}")
    return job["id"]


def check_fetch(base: str, job_id: str) -> None:
    status, _, job = request(base, "GET", f"/v1/plans/{job_id}")
    expect(status == 200, f"GET /v1/plans/{job_id}: expected 200, got {status}: {job}")
    expect(job["status"] == "succeeded", f"plan {job_id}: status {job['status']}")
    log(f"GET /v1/plans/{job_id}: still stored and succeeded")


def main(argv: list[str]) -> int:
    usage = "usage: smoke.sh wait URL [SECONDS] | check URL | fetch URL JOB_ID"
    if len(argv) < 2:
        print(usage, file=sys.stderr)
        return 2
    command, base = argv[0], argv[1].rstrip("/")
    try:
        if command == "wait":
            wait(base, float(argv[2]) if len(argv) > 2 else 60.0)
        elif command == "check":
            check_auth(base)
            check_dynamics(base)
            if PLAN:
                print(check_plan(base))
            else:
                log("SMOKE_PLAN=0: plan check off")
        elif command == "fetch" and len(argv) == 3:
            check_fetch(base, argv[2])
        else:
            print(usage, file=sys.stderr)
            return 2
    except (Failure, KeyError, TypeError, IndexError, ValueError, OSError) as err:
        log(f"FAIL {command}: {type(err).__name__}: {err}")
        return 1
    return 0


sys.exit(main(sys.argv[1:]))
PY
