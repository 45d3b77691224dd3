"""Replanning through a service session: the closed loop of `bench.closed_loop` driven over
HTTP, and the round trip of each update.

The scene's plan is made once in this process with its compiled kernels built (so that
the server finds them in the shared cache, `planner.compiled`), then submitted to a
uvicorn server in a subprocess (`testbed.service.LiveServer`, one solver worker, SQLite).
A session on its plan job (`clients.session.Session`, one kept-alive connection) then
drives the arm of `bench.closed_loop` (every mass `--mass` heavier, the passive joint
pushed at a third of the motion) through the same servo loop, each update a real-time
update from the state measured then. Reported per update that solved (not those held in
the final stretch): the round trip (from the request's send to its answer, this process),
the library's own wall time of the update (the answer's `wall_time`), and their
difference (HTTP, JSON, validation, the thread hop); medians and 99th percentiles; and
the closed loop's final error beside the library's own (`bench.closed_loop`, the same
run) and the LQR feedback alone.

    python -m bench session [--scene seed-arm-plan] [--N 50] [--updates 200]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench import closed_loop, harness
from clients.session import Session
from planner import compiled
from planner.ocp import plan
from planner.ocp.robustness import models
from planner.scene import Scene, Uncertainty
from testbed.service import LiveServer

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Replanning through a service session"
PUSH, MASS = 0.2, 0.1
"""[rad/s] the push on the first passive joint; the arm's masses' relative error."""


class OverHttp:
    """Real-time updates through a service session, each timed from this side."""

    def __init__(self, session: Session, wall: float):
        self.session, self.wall = session, wall
        self.trips: list[float] = []
        self.reports: list[dict] = []

    def update(self, k: int, t: float, x: np.ndarray) -> Session:
        n = x.size // 2
        started = time.perf_counter()
        report = self.session.update(t, list(x[:n]), list(x[n:]), wall_time=self.wall)
        self.trips.append(time.perf_counter() - started)
        self.reports.append(report)
        return self.session


def run(name: str, N: int, updates: int, wall: float) -> list[dict]:
    request = closed_loop.request(name, N)
    scene = Scene.model_validate(request)
    plan(scene)
    compiled.wait()  # the server loads these libraries from the shared cache
    nominal = plan(scene)
    arm = dict(models(scene.robot, Uncertainty(mass=MASS)))["mass+"]
    x0, T = np.concatenate([nominal.q[0], nominal.dq[0]]), nominal.duration
    with tempfile.TemporaryDirectory() as tmp, \
            LiveServer(Path(tmp) / "jobs.sqlite3", None, UNDERTOW_WORKERS="1") as live, \
            httpx.Client(base_url=live.url, timeout=60.0) as client:
        job = client.post("/v1/plans?wait=30", json=request).json()
        assert job["status"] == "succeeded", job
        session = Session(client, job["id"])
        over = OverHttp(session, wall)
        try:
            service = closed_loop.drive(arm, x0, T, updates, PUSH, over)
        finally:
            session.close()
    library = closed_loop.Replanning(scene, nominal, wall)
    local = closed_loop.drive(arm, x0, T, updates, PUSH, library)
    lqr = closed_loop.drive(arm, x0, T, updates, PUSH, closed_loop.LqrAlone(nominal))
    solved = [(trip, r) for trip, r in zip(over.trips, over.reports, strict=True)
              if r["status"] != "Final_Stretch"]
    trips = [1e3 * trip for trip, _ in solved]
    inside = [1e3 * r["wall_time"] for _, r in solved]
    overhead = [a - b for a, b in zip(trips, inside, strict=True)]
    row = {"scene": name, "N": N, "updates": updates, "solved": len(solved),
           "median_round_trip_ms": harness.median(trips),
           "p99_round_trip_ms": float(np.percentile(trips, 99)),
           "median_library_ms": harness.median(inside),
           "p99_library_ms": float(np.percentile(inside, 99)),
           "median_overhead_ms": harness.median(overhead),
           "p99_overhead_ms": float(np.percentile(overhead, 99)),
           "fallbacks": sum(r["fallback"] for _, r in solved),
           "final_error_service": closed_loop.final_error(service["final"], scene),
           "final_error_library": closed_loop.final_error(local["final"], scene),
           "final_error_lqr": closed_loop.final_error(lqr["final"], scene)}
    print(row, flush=True)
    return [row]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench session", description=__doc__)
    parser.add_argument("--scene", default="seed-arm-plan")
    parser.add_argument("--N", type=int, default=50)
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--wall", type=float, default=0.2,
                        help="[s] the most each solve of an update may take")
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    rows = run(args.scene, args.N, args.updates, args.wall)
    harness.write_csv(harness.RESULTS / "session.csv", rows)
    text = "\n\n".join([
        f"`{args.scene}` at N = {args.N}: {args.updates} real-time updates at a fixed rate "
        f"through one session of a uvicorn server on this machine (one kept-alive "
        f"connection), driving the arm of the closed loop above (every mass "
        f"{100 * MASS:g} % heavier, a push of {PUSH:g} rad/s on the first passive joint at a "
        f"third of the motion; each solve within {args.wall:g} s). Round trip: the client's "
        f"time from sending an update to its answer; library: the update's own wall time in "
        f"the server; overhead: their difference. Over the updates that solved (not those "
        f"held in the final stretch). Final error [rad, rad/s] of the same loop driven "
        f"through the service, by the library in this process, and by the LQR feedback "
        f"alone.",
        harness.table(rows, [("scene", "scene"), ("solved", "updates solved"),
                             ("median_round_trip_ms", "median round trip [ms]"),
                             ("p99_round_trip_ms", "99th pct round trip [ms]"),
                             ("median_library_ms", "median library [ms]"),
                             ("p99_library_ms", "99th pct library [ms]"),
                             ("median_overhead_ms", "median overhead [ms]"),
                             ("p99_overhead_ms", "99th pct overhead [ms]"),
                             ("fallbacks", "fallbacks"),
                             ("final_error_service", "final error, service"),
                             ("final_error_library", "final error, library"),
                             ("final_error_lqr", "final error, LQR alone")]),
        f"Rows: `bench/results/session.csv`. {harness.manifest('session', argv, started, note)}"])
    harness.write_section(DOC, SECTION, text)
    return 0
