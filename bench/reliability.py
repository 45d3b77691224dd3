"""Reliability of the service under bad input and bounded requests.

Re-runs the bad-input and bounding probes of issue 15 against a live server: uvicorn
serving app.main:app as `make serve` does (the service's protocol, default limits, an API
key) on a free loopback port with a temporary job store. For every probe it records what
came back and how long it took:

1. bad input: oversize grids, torques near 1e300, unplannable tasks, strings and booleans
   for numbers, bodies that are not JSON, a missing key, wrong methods, oversize output
   and search: every answer must be a 4xx problem (or, for the torques, a failed
   simulation), none a 5xx;
2. read timeouts: connections that send no head, half a head, a head a line at a time,
   or half a body;
3. bounded requests: synchronous computations that ran for minutes before, each alone:
   every one must be answered within UNDERTOW_SYNC_WALL_TIME plus SLACK;
4. four such computations at once: /healthz and a one-state /v1/dynamics must stay
   responsive, a fifth computation gets 503 busy.

Writes the section "Reliability: bad input and bounded requests" of docs/stability.md and
bench/results/reliability.csv.

    python -m bench reliability
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import select
import socket
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

from app.server import PROTOCOL
from app.settings import Settings
from bench import harness
from bench.scenes import UNDERACTUATED, request
from planner.examples import example
from testbed.probes import malformed_bodies
from testbed.service import LiveServer

KEY = "bench-key"
SETTINGS = Settings(db_path="unused", instance="bench")  # the defaults the server runs with
BUDGET = SETTINGS.sync_wall_time
SLACK = 5.0
"""[s] Allowed beyond the budget: the answer's serialisation and transfer, and the last
check's unit of work (one CVODES output, one chunk of configurations, one Ipopt
iteration) on this shared 2-core machine."""
HEADERS = {"X-API-Key": KEY}


def arm(passive: tuple[int, ...], waves: bool = True) -> dict:
    """8 links of 0.3 m and 0.2 kg; the `passive` joints passive, the others active, with
    a wave when `waves`."""
    wave = {"amplitude": 0.05, "frequency": 6.0, "phase": 0.3}
    return {"gravity": 9.81, "links": [
        {"length": 0.3, "mass": 0.2, "inertia": 0.001,
         **({"joint": "passive"} if k in passive else
            {"joint": "active", **({"wave": wave} if waves else {})})} for k in range(8)]}


EIGHT = arm((0, 2, 4, 6))
WIDE = arm((0, 3, 6))
"""3 passive joints for 5 active: a wide coupling block, whose singular points are
minima of sigma_min refined one by one."""


# ------------------------------------------------------------------ probes


class Probes:
    """Requests against one live server; each probe appends one row."""

    def __init__(self, url: str, port: int):
        self.url, self.port = url, port
        self.http = httpx.Client(base_url=url, timeout=300, headers=HEADERS)
        self.rows: list[dict] = []

    def probe(self, group: str, name: str, expected: str,
              requests: list[Callable[[], httpx.Response]],
              ok: Callable[[httpx.Response], bool]) -> None:
        """Send each request in turn; the row counts statuses, 5xx and the slowest answer."""
        statuses: collections.Counter[int] = collections.Counter()
        good, slowest = 0, 0.0
        for send in requests:
            start = time.monotonic()
            response = send()
            slowest = max(slowest, time.monotonic() - start)
            statuses[response.status_code] += 1
            good += ok(response)
        self.rows.append({"group": group, "probe": name, "tried": len(requests),
                          "answers": ", ".join(f"{n} x {s}" for s, n in sorted(statuses.items())),
                          "5xx": sum(n for s, n in statuses.items() if s >= 500),
                          "expected": expected, "as expected": good,
                          "slowest [s]": round(slowest, 2)})

    def post(self, path: str, body=None, **kw) -> Callable[[], httpx.Response]:
        return lambda: self.http.post(path, json=body, **kw)

    def raw(self, method: str, path: str, content: bytes, ctype: str = "application/json",
            key: str | None = KEY) -> Callable[[], httpx.Response]:
        headers = {"Content-Type": ctype, **({"X-API-Key": key} if key else {})}
        return lambda: httpx.request(method, self.url + path, content=content,
                                     headers=headers, timeout=60)


def problem(status: int, kind: str) -> Callable[[httpx.Response], bool]:
    """The response is a problem of this status and type."""
    def check(r: httpx.Response) -> bool:
        return (r.status_code == status
                and r.headers.get("content-type") == "application/problem+json"
                and r.json().get("type") == f"urn:undertow:problem:{kind}")
    return check


def bad_input(p: Probes) -> None:
    group = "bad input"
    grids = [10**8, 10**10, 10**12, [10**9, 10**9]]
    p.probe(group, "coupling grid of 1e8 to 1e24 points", "422 at grid.points, at once",
            [p.post("/v1/coupling", {"robot": UNDERACTUATED, "grid": {
                "lower": [0, 0], "upper": [1, 1], "points": n}}) for n in grids],
            lambda r: problem(422, "validation")(r)
            and r.json()["errors"][0]["loc"][-1] == "points")
    p.probe(group, "torques of 1e300, one sample per interval", "200, status failed",
            [p.post("/v1/simulate", {"robot": UNDERACTUATED, "t": [0.0, 1.0], "tau": [[v], [v]],
                                     "initial": {"q": [0, 0], "dq": [0, 0]},
                                     "samples_per_interval": 1}) for v in (1e300, -1e300, 1.7e308)],
            lambda r: r.status_code == 200 and r.json()["status"] == "failed")
    tasks: list[dict[str, Any]] = [
        {"duration": 0}, {"duration": -1}, {"torque_limit": -1.0}, {"torque_limit": [-2.0]},
        {"position_bounds": {"lower": [0, 1], "upper": [1, 0]}},
        {"velocity_bounds": {"lower": [1, None], "upper": [-1, None]}}]
    p.probe(group, "task: duration 0 or -1, negative torque limit, lower > upper",
            "422 at the field", [p.post("/v1/plans", _task(change)) for change in tasks],
            problem(422, "validation"))
    numbers: list[tuple[str, dict[str, Any]]] = [
        ("/v1/dynamics", {"robot": UNDERACTUATED, "states": [{"q": v, "dq": [0, 0]}]})
        for v in (["0.1", "0.2"], [True, False])]
    numbers += [("/v1/coupling", {"robot": UNDERACTUATED, "configurations": [["0", "1"]]}),
                ("/v1/dynamics", {"robot": {**UNDERACTUATED, "gravity": False},
                                  "states": [{"q": [0, 0], "dq": [0, 0]}]}),
                ("/v1/simulate", {"robot": UNDERACTUATED, "t": [0, True], "tau": [[0], [0]],
                                  "initial": {"q": [0, 0], "dq": [0, 0]}}),
                ("/v1/plans", _task({"initial": {"q": ["0", "0"], "dq": [0, 0]}}))]
    p.probe(group, "strings and booleans for numbers", "422 at the field",
            [p.post(path, body) for path, body in numbers], problem(422, "validation"))
    bodies = malformed_bodies()
    p.probe(group, "hand-made bad bodies (testbed/probes.py) on /v1/plans and /v1/dynamics",
            "4xx problem", [p.raw("POST", path, body, ctype) for _, body, ctype in bodies
                            for path in ("/v1/plans", "/v1/dynamics")],
            lambda r: 400 <= r.status_code < 500
            and r.headers.get("content-type") == "application/problem+json")
    not_json = [b"not json", b'{"robot": ', b'{"states": [],}', b"[" * 2000, b"\xff\xfe"]
    p.probe(group, "bodies that are not JSON", "400 malformed-body",
            [p.raw("POST", "/v1/dynamics", body) for body in not_json],
            problem(400, "malformed-body"))
    p.probe(group, "no or wrong key, with a bad or oversize body", "401 before the body is read",
            [p.raw("POST", "/v1/dynamics", body, key=key)
             for body in (b"not json", b'{"robot": 1}', b" " * 2_000_000)
             for key in (None, "wrong")], problem(401, "unauthorized"))
    methods = [("GET", "/v1/dynamics", "POST"), ("GET", "/v1/simulate", "POST"),
               ("PUT", "/v1/plans/abc", "DELETE, GET"), ("PATCH", "/v1/plans", "GET, POST"),
               ("POST", "/healthz", "GET")]
    allowed = {path: allow for _, path, allow in methods}
    p.probe(group, "wrong methods", "405, Allow names every method",
            [p.raw(method, path, b"") for method, path, _ in methods],
            lambda r: problem(405, "method-not-allowed")(r)
            and r.headers["allow"] == allowed[r.request.url.path])
    oversize = [("/v1/simulate", {"robot": UNDERACTUATED, "t": [0.01 * k for k in range(20_000)],
                                  "tau": [[0.0]] * 20_000, "samples_per_interval": 100,
                                  "initial": {"q": [0, 0], "dq": [0, 0]}}),
                ("/v1/waves/design", {"robot": EIGHT, "amplitude_max": 0.05, "frequency_max": 6,
                                      "margin": 0.01, "region": {"lower": [0.0] * 8,
                                                                 "upper": [1.0] * 8}}),
                ("/v1/waves/design", {**example("seed-arm-wave-design").request,
                                      "frequency_max": 12})]
    p.probe(group, "20,000 times x 100 samples; oversize wave screenings", "422 at once",
            [p.post(path, body) for path, body in oversize], problem(422, "validation"))


def _task(change: dict) -> dict:
    """The under-2 plan request on 10 intervals with its task changed."""
    scene = request("under-2", N=10)
    scene["task"].update(change)
    return scene


def read_timeouts(p: Probes, rows: list[dict]) -> None:
    """Connections that are slow to send: seconds until the server closed or answered."""
    timeout = SETTINGS.read_timeout
    head = b"GET /healthz HTTP/1.1\r\nHost: x\r\n"
    body = json.dumps({"robot": UNDERACTUATED, "states": [{"q": [0, 0], "dq": [0, 0]}]}).encode()
    cases = [("connects and sends nothing", [b""], None),
             ("sends half a request head", [head], None),
             ("sends a head line every 3 s", [b"GET /healthz HTTP/1.1\r\n"] + [b"X-A: 1\r\n"] * 20,
              3.0),
             ("sends the head and half the body",
              [b"POST /v1/dynamics HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
               + f"X-API-Key: {KEY}\r\nContent-Length: {len(body)}\r\n\r\n".encode()
               + body[: len(body) // 2]], None)]
    for name, chunks, pause in cases:
        start = time.monotonic()
        with socket.create_connection(("127.0.0.1", p.port), timeout=120) as sock:
            for chunk in chunks:
                with contextlib.suppress(OSError):
                    sock.sendall(chunk)
                if pause and select.select([sock], [], [], pause)[0]:
                    break  # the server closed the connection (or answered)
            answer = b""
            with contextlib.suppress(OSError):
                while data := sock.recv(65536):
                    answer += data
        status = answer.split(b" ", 2)[1].decode() if answer.startswith(b"HTTP/1.1 ") else "–"
        elapsed = time.monotonic() - start
        rows.append({"client": name, "server": f"answered {status}" if answer else "closed",
                     "after [s]": round(elapsed, 1), "bound [s]": timeout,
                     "within": elapsed <= timeout + SLACK})


def long_requests() -> list[tuple[str, str, dict]]:
    """(name, path, body) of synchronous requests long enough to meet the budget."""
    seed_inverse = example("seed-arm-waves").request
    motion = {"passive_motion": {"profile": "beta", "alpha": 3, "beta": 3,
                                 "start": [0.0, 0.1, 0.2, 0.3], "end": [0.3, 0.4, 0.5, 0.6]},
              "duration": 2.0, "active_initial": {"q": [1.5, 1.6, 1.7, 1.8], "dq": [0.0] * 4}}
    fast = {**seed_inverse["active_initial"],
            "dq": [1e200] * len(seed_inverse["active_initial"]["dq"])}
    return [
        ("wave design of 8 links (4 active) along a motion, 8 starts, 20,000 samples",
         "/v1/waves/design",
         {"robot": arm((0, 2, 4, 6), waves=False), "amplitude_max": 0.05, "frequency_max": 3,
          "margin": 0.01, "starts": 8, "certification_points": 20_000, "motion": motion}),
        ("simulation of 8 links, 1,500 intervals x 10 samples over 200 s, tolerance 1e-13",
         "/v1/simulate", _simulation(EIGHT, 1_500, 10, 200.0, 1e-13)),
        ("simulation of 8 links, one interval x 100 samples, torques 100 N m, tolerance 1e-14",
         "/v1/simulate", _simulation(EIGHT, 1, 100, 10.0, 1e-14, 100.0)),
        ("inverse dynamics of the seed arm, active rates of 1e200 rad/s",
         "/v1/inverse-dynamics", {**seed_inverse, "active_initial": fast}),
        ("coupling of 8 links (3 passive) on a 15,552-point grid, threshold 10",
         "/v1/coupling", {"robot": WIDE, "threshold": 10.0, "grid": {
             "lower": [-3.0] * 8, "upper": [3.0] * 8, "points": [4] * 3 + [3] * 5}}),
        ("dynamics of 8 links at 5,000 states", "/v1/dynamics",
         {"robot": EIGHT, "states": [{"q": [round(0.001 * k, 3)] * 8, "dq": [0.1] * 8,
                                      "ddq": [0.0] * 8} for k in range(5_000)]}),
    ]


def _simulation(robot: dict, intervals: int, samples: int, duration: float, tol: float,
                torque: float = 1.0) -> dict:
    na = sum(link["joint"] == "active" for link in robot["links"])
    n = len(robot["links"])
    t = [duration * k / intervals for k in range(intervals + 1)]
    return {"robot": robot, "t": t, "tau": [[torque] * na for _ in t],
            "samples_per_interval": samples, "rtol": tol, "atol": tol,
            "initial": {"q": [0.1] * n, "dq": [0.0] * n}}


def bounded(p: Probes) -> None:
    """Each long request alone: answered (completed or budget-exceeded) in time."""
    for name, path, body in long_requests():
        p.probe("bounded", name, f"200 or 422 budget-exceeded within {BUDGET:g} + {SLACK:g} s",
                [p.post(path, body)],
                lambda r: r.status_code == 200 or problem(422, "budget-exceeded")(r))


def concurrent(p: Probes) -> dict:
    """Four long simulations at once, /healthz and a one-state /v1/dynamics polled meanwhile,
    and a fifth computation that finds no thread."""
    _, path, body = long_requests()[1]
    held: list[httpx.Response] = []
    threads = [threading.Thread(target=lambda: held.append(
        httpx.post(p.url + path, json=body, headers=HEADERS, timeout=300))) for _ in range(4)]
    for thread in threads:
        thread.start()
    time.sleep(1.0)
    fifth = httpx.post(p.url + path, json=body, headers=HEADERS, timeout=300)
    health, dynamics = [], []
    one = {"robot": UNDERACTUATED, "states": [{"q": [0.1, 0.2], "dq": [0.0, 0.0]}]}
    while any(thread.is_alive() for thread in threads):
        start = time.monotonic()
        ok = httpx.get(p.url + "/healthz", timeout=60).status_code == 200
        health.append((time.monotonic() - start, ok))
        start = time.monotonic()
        ok = httpx.post(p.url + "/v1/dynamics", json=one, headers=HEADERS,
                        timeout=60).status_code == 200
        dynamics.append((time.monotonic() - start, ok))
        time.sleep(0.2)
    for thread in threads:
        thread.join()
    return {"long": [r.status_code for r in held], "fifth": fifth.status_code,
            "fifth retry-after": fifth.headers.get("retry-after"),
            "health": health, "dynamics": dynamics}


# ------------------------------------------------------------------ report

DOC = harness.DOCS / "stability.md"
HEADING = "Reliability: bad input and bounded requests"


def report(rows: list[dict], reads: list[dict], load: dict) -> str:
    bad = [r for r in rows if r["group"] == "bad input"]
    long = [r for r in rows if r["group"] == "bounded"]
    health = [seconds for seconds, _ in load["health"]]
    quick = [seconds for seconds, _ in load["dynamics"]]
    tried = sum(r["tried"] for r in rows) + len(reads) + len(load["long"]) + 1 + 2 * len(health)
    quick_status = "all 200" if all(ok for _, ok in load["dynamics"]) else "NOT all 200"
    summary = [
        (f"- **{tried} requests tried, {sum(r['5xx'] for r in rows)} answered with a 5xx.** "
         f"Bad input: {sum(r['as expected'] for r in bad)} of {sum(r['tried'] for r in bad)} "
         "answers were the expected 4xx problem (the torques of 1e300: a `failed` "
         "simulation)."),
        (f"- **Synchronous requests bounded**: {sum(r['as expected'] for r in long)} of "
         f"{len(long)} long computations were answered within the budget "
         f"({BUDGET:g} s, `UNDERTOW_SYNC_WALL_TIME`) + {SLACK:g} s, the slowest in "
         f"{max(r['slowest [s]'] for r in long):.1f} s; "
         f"{sum('422' in r['answers'] for r in long)} of them ran into the budget and "
         "stopped there."),
        (f"- **While four long simulations held every compute thread**: /healthz answered "
         f"{len(health)} times, median {statistics.median(health) * 1e3:.0f} ms, worst "
         f"{max(health) * 1e3:.0f} ms; a one-state /v1/dynamics (a quick request, on its "
         f"own thread) {len(quick)} times, median {statistics.median(quick) * 1e3:.0f} ms, "
         f"worst {max(quick) * 1e3:.0f} ms, {quick_status}; a fifth simulation got "
         f"{load['fifth']} (Retry-After {load['fifth retry-after']}) after "
         f"`UNDERTOW_COMPUTE_WAIT` = {SETTINGS.compute_wait:g} s; the four got "
         f"{', '.join(map(str, load['long']))}."),
        (f"- **Read timeouts**: {sum(r['within'] for r in reads)} of {len(reads)} slow "
         f"clients were cut off within `UNDERTOW_READ_TIMEOUT` = {SETTINGS.read_timeout:g} "
         f"s + {SLACK:g} s."),
    ]
    setup = (f"A live uvicorn (`app.main:app --http {PROTOCOL}`, as `make serve` runs it) on "
             "127.0.0.1 with a temporary store, an API key and every other setting at its "
             f"default (`UNDERTOW_SYNC_WALL_TIME` {BUDGET:g} s, `UNDERTOW_COMPUTE_THREADS` "
             f"{SETTINGS.compute_threads}, `UNDERTOW_QUICK_THREADS` {SETTINGS.quick_threads}, "
             f"`UNDERTOW_COMPUTE_WAIT` {SETTINGS.compute_wait:g} s, `UNDERTOW_READ_TIMEOUT` "
             f"{SETTINGS.read_timeout:g} s). The probes re-run the bad-input and bounding "
             "findings of issue 15: grids validated by building them on the event loop, wave "
             "designs and simulations without a time bound, quick requests starved by four "
             "long ones, answers of millions of samples, torques of 1e300 answered as "
             "`completed` with zeros.")
    columns = [("probe", "probe"), ("tried", "tried"), ("answers", "answers"), ("5xx", "5xx"),
               ("expected", "expected"), ("as expected", "as expected"),
               ("slowest [s]", "slowest [s]")]
    reads_columns = [("client", "client"), ("server", "server"), ("after [s]", "after [s]"),
                     ("bound [s]", "bound [s]"), ("within", f"within bound + {SLACK:g} s")]
    return "\n\n".join([
        setup, "\n".join(summary),
        ("Bad input (`as expected` counts the answers that were the expected problem; "
         "`slowest`: the longest time to an answer):"),
        harness.table(bad, columns),
        "Long synchronous computations, each alone:",
        harness.table(long, columns),
        ("Slow clients (`after`: seconds from connecting until the server closed the "
         "connection or answered):"),
        harness.table(reads, reads_columns),
    ])


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench reliability", description=__doc__)
    parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    tmp = Path(tempfile.mkdtemp(prefix="undertow-reliability-"))
    env = {"UNDERTOW_API_KEY": KEY, "UNDERTOW_WORKERS": "1"}
    with LiveServer(tmp / "jobs.sqlite3", None, **env) as live:
        probes = Probes(live.url, live.port)
        bad_input(probes)
        print("bad input done", flush=True)
        reads: list[dict] = []
        read_timeouts(probes, reads)
        print("read timeouts done", flush=True)
        bounded(probes)
        print("bounded done", flush=True)
        load = concurrent(probes)
        print("concurrency done", flush=True)
    harness.write_csv(harness.RESULTS / "reliability.csv", probes.rows)
    harness.write_section(DOC, HEADING, "\n\n".join([
        report(probes.rows, reads, load),
        f"Rows: `bench/results/reliability.csv`. "
        f"{harness.manifest('reliability', argv, started, note)}"]))
    print(f"wrote {DOC} and bench/results/reliability.csv")
    return 0
