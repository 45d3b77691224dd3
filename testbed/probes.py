"""Faults a live service must survive: hand-made bad bodies, a plan worker killed
mid-solve, clients that go away. Each fault case returns a row with `ok`."""

from __future__ import annotations

import json
import os
import signal
import socket
import time
from typing import Any

import httpx

from testbed.service import LiveServer, wait_final
from testbed.worker_watch import children

QUICK: dict[str, Any] = {"robot": {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3.0, "phase": 0.3}}], "gravity": 9.81},
    "task": {"duration": 2.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
             "final": {"q": [1.0, None], "dq": [0.0, 0.0]}},
    "transcription": {"intervals": 10}}
LONG: dict[str, Any] = {
    **QUICK, "task": {**QUICK["task"], "final": {"q": [None, None], "dq": [0.0, 0.0]},
                      "tip_target": {"x": 0.6, "y": 0.6}, "torque_limit": 0.02},
    "transcription": {"intervals": 80, "degree": 3},
    "solver": {"max_iter": 100000, "max_wall_time": 60}}
"""A tip within reach under a torque limit too small to get there: Ipopt iterates for many
seconds (about 900 iterations, 20 s) before the plan ends infeasible. (A tip beyond reach
is refused before any solve.)"""


def malformed_bodies() -> list[tuple[str, bytes, str]]:
    """(name, body, content type) of hand-made bad requests for POST /v1/plans."""
    good = json.dumps(QUICK)
    return [
        ("empty body", b"", "application/json"),
        ("truncated JSON", good[:40].encode(), "application/json"),
        ("JSON null", b"null", "application/json"),
        ("JSON array", b"[]", "application/json"),
        ("NaN literal", good.replace('"mass": 1.0', '"mass": NaN', 1).encode(), "application/json"),
        ("Infinity literal", good.replace('"duration": 2.0', '"duration": Infinity').encode(),
         "application/json"),
        ("number overflow 1e999", good.replace('"duration": 2.0', '"duration": 1e999').encode(),
         "application/json"),
        ("string for a number", good.replace('"duration": 2.0', '"duration": "two"').encode(),
         "application/json"),
        ("deep nesting (100000 [)", b"[" * 100_000 + b"]" * 100_000, "application/json"),
        ("invalid UTF-8", b'{"robot": "\xff\xfe"}', "application/json"),
        ("text/plain content type", good.encode(), "text/plain"),
        ("form content type", b"a=1&b=2", "application/x-www-form-urlencoded"),
        ("over the body limit (2 MB)", (good[:-1] + ', "pad": "' + "x" * 2_000_000 + '"}').encode(),
         "application/json"),
        ("unknown field", good.replace('"task"', '"tsk"').encode(), "application/json"),
        ("negative intervals", good.replace('"intervals": 10', '"intervals": -5').encode(),
         "application/json"),
        ("10^9 intervals", good.replace('"intervals": 10', '"intervals": 1000000000').encode(),
         "application/json"),
        ("10 links", json.dumps({**QUICK, "robot": {"links": QUICK["robot"]["links"] * 5}})
         .encode(), "application/json"),
        ("huge integer", good.replace('"intervals": 10', '"intervals": ' + "9" * 5000).encode(),
         "application/json"),
    ]


def worker_pids(server_pid: int) -> list[int]:
    """The plan workers of a server: its spawned children (not the resource tracker)."""
    return [pid for (pid, _), command in children(server_pid).items()
            if "spawn_main" in command and "resource_tracker" not in command]


def kill_worker_case(live: LiveServer, http: httpx.Client) -> dict:
    """SIGKILL the worker processes while a long plan runs; the job must be requeued (an
    infrastructure failure) and run again to the solver's own verdict (LONG's tip, out of
    its torque's reach: failed, never a dead letter), the server must stay healthy and plan
    the next scene."""
    job_id = http.post("/v1/plans", json=LONG).json()["id"]
    deadline = time.monotonic() + 60
    while http.get(f"/v1/plans/{job_id}").json()["progress"] is None:
        assert time.monotonic() < deadline, "the long plan reported no progress"
        time.sleep(0.05)
    assert live.proc is not None, "the server is not running"
    workers = worker_pids(live.proc.pid)
    killed_at = time.monotonic()
    for pid in workers:
        os.kill(pid, signal.SIGKILL)
    job = wait_final(http, job_id, timeout=120)
    noticed = time.monotonic() - killed_at
    health = http.get("/healthz").status_code
    after = http.post("/v1/plans?wait=30", json=QUICK).json()
    return {"fault": "plan workers SIGKILLed mid-solve", "workers killed": len(workers),
            "job status": job["status"], "job error": job["error"],
            "infrastructure failures": job["infra_failures"], "attempts": job["attempts"],
            "seconds to finish the job": round(noticed, 2), "healthz": health,
            "next plan": after["status"],
            "ok": (job["infra_failures"] >= 1 and job["attempts"] >= 2
                   and not job["dead_letter"] and health == 200
                   and after["status"] == "succeeded")}


def disconnect_cases(live: LiveServer, http: httpx.Client) -> list[dict]:
    """Clients that go away: mid-wait, mid-body, before reading the answer."""
    rows = []
    before = {j["id"] for j in http.get("/v1/plans?limit=100").json()["items"]}
    try:
        httpx.post(live.url + "/v1/plans?wait=30", json=LONG, timeout=0.5)
        gone = "client waited for its answer"
    except httpx.TimeoutException:
        gone = "client left after 0.5 s"
    new = [j["id"] for j in http.get("/v1/plans?limit=100").json()["items"]
           if j["id"] not in before]
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
    after = [j["id"] for j in http.get("/v1/plans?limit=100").json()["items"]
             if j["id"] not in before]
    rows.append({"fault": "client sends a third of the body and closes",
                 "jobs created": len(after) - len(new),
                 "healthz": http.get("/healthz").status_code, "ok": len(after) == len(new)})
    for _ in range(20):
        with socket.create_connection(("127.0.0.1", live.port), timeout=5) as sock:
            sock.sendall(b"GET /v1/examples HTTP/1.1\r\nHost: x\r\n\r\n")
    rows.append({"fault": "20 clients close before reading GET /v1/examples",
                 "healthz": http.get("/healthz").status_code,
                 "ok": http.get("/v1/examples").status_code == 200})
    return rows
