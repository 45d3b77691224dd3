"""Numerical and operational stress: what undertow does at its edges (the cases of
`testbed.edges` and `testbed.probes`, swept).

1. Near-singular configurations, sigma_min(M_pa) from 1e-2 down to 1e-12 (waveless 2-link
   arm in closed form, and the seed's waveless 4-link arm along the straight path of
   bench/scenes.py "seed-4"): the classical inverse dynamics must stop with its report,
   the planner must return finite numbers or a structured failure.
2. Badly scaled robots (mass ratios 1e-3..1e3, lengths 1e-2..10 m, wave frequency up to 20,
   up to 8 links, horizons up to 20 s), each planned once, fully actuated and
   underactuated: success rate, worst interval error, non-finite values anywhere in the
   returned models (`model_dump(mode="json")`, walked recursively).
3. Random robots (n 1..8, all scales above): symmetry and positive definiteness of M,
   T = dq'M dq / 2, and the power balance dq'(M ddq + h) = dE/dt with dE/dt from
   finite differences of the energy function; worst residuals over the draws.
4. The service on a live uvicorn: a worker killed mid-solve, clients that disconnect,
   malformed bodies (hand-made, and schemathesis' positive and negative cases).

Writes a section of docs/stability.md per part and bench/results/stress_*.csv.

    python -m bench stress [--parts singular,scaled,random,service] [--robots 1000]
        [--examples 25]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from bench import harness
from bench.scenes import SEED_TASK, UNDERACTUATED
from planner import coupling_block
from planner.model import Robot
from testbed.edges import (
    SIGMAS,
    invariants,
    inverse_case,
    plan_case,
    scaled_case,
    scaled_cases,
    seed_at,
    two_link_at,
    waveless_seed,
    waveless_two_link,
)
from testbed.probes import disconnect_cases, kill_worker_case, malformed_bodies
from testbed.service import LiveServer

# ------------------------------------------------------------------ near-singular


def seed_near(sigma: float) -> np.ndarray:
    """The waveless seed arm at sigma_min(M_pa) = sigma on the seed-4 task's straight path."""
    return seed_at(sigma, SEED_TASK["initial"]["q"], SEED_TASK["final"]["q"])


ARMS = {"2-link": (waveless_two_link, two_link_at), "seed 4-link": (waveless_seed, seed_near)}
INVERSE_TIMEOUT = 120.0  # [s] a classical inverse-dynamics case still running is recorded


def inverse_point(arm: str, sigma: float, threshold: float) -> dict:
    """`inverse_case` at the configuration of `arm` with sigma_min(M_pa) = sigma."""
    robot_of, at = ARMS[arm]
    robot, q = robot_of(), at(sigma)
    out = inverse_case(robot, q, threshold)
    out.pop("stop_q", None)
    return {"actual": coupling_block.at(robot, q).sigma_min, **out}


def singular_rows(sigmas: list[float]) -> list[dict]:
    """Inverse dynamics and plans from near-singular starts, each in a process of its own."""
    rows = []
    for arm in ARMS:
        for sigma in sigmas:
            for threshold in (1e-3, sigma / 10):
                started = time.perf_counter()
                out = harness.isolated("stress", inverse_point.__name__,
                               {"arm": arm, "sigma": sigma,
                                "threshold": threshold}, INVERSE_TIMEOUT)
                rows.append({"part": "inverse", "arm": arm, "sigma": sigma, "threshold": threshold,
                             "wall": time.perf_counter() - started, **out})
                print(json.dumps(rows[-1]), flush=True)
    wavy = {**UNDERACTUATED, "links": [{**link, "inertia": 0.0} for link in UNDERACTUATED["links"]]}
    for sigma in sigmas:
        q = two_link_at(sigma).tolist()
        final = [q[0] + 0.3, q[1] - 0.5]
        for robot_name, robot in (("waveless", waveless_two_link().model_dump()),
                                  ("with wave", wavy)):
            for margin in (None, 1e-3):
                out = harness.isolated("stress", plan_case.__name__,
                                       {"robot": robot, "start": q, "final": final,
                                        "duration": 2.0, "margin": margin}, 300)
                rows.append({"part": "plan", "arm": f"2-link {robot_name}", "sigma": sigma,
                             "margin": margin, **out})
                print(json.dumps(rows[-1]), flush=True)
    for sigma in [s for s in (1e-2, 1e-6, 1e-12) if s in sigmas]:
        out = harness.isolated("stress", plan_case.__name__,
                               {"robot": waveless_seed().model_dump(),
                                "start": seed_near(sigma).tolist(),
                                "final": SEED_TASK["final"]["q"], "duration": 4.0,
                                "margin": None}, 600)
        rows.append({"part": "plan", "arm": "seed 4-link waveless", "sigma": sigma,
                     "margin": None, **out})
        print(json.dumps(rows[-1]), flush=True)
    return rows


# ------------------------------------------------------------------ badly scaled robots


def scaled_rows(sweeps: list[str] | None) -> list[dict]:
    """Every badly scaled robot of the named sweeps (all: None), each in a process of its own."""
    rows = []
    for sweep, value, options, duration in scaled_cases():
        if sweeps is not None and sweep not in sweeps:
            continue
        for under in (False, True):
            if under and options.get("n") == 1:
                continue
            out = harness.isolated("stress", scaled_case.__name__,
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
        link: dict[str, Any] = {"length": length, "mass": mass,
                "inertia": 0.0 if rng.random() < 0.3 else mass * length**2 * rng.random(),
                "joint": "active" if active[k] else "passive"}
        if active[k] and rng.random() < 0.75:
            link["wave"] = {"amplitude": 0.9 * length * rng.random(),
                            "frequency": 20 * rng.random(), "phase": rng.uniform(-np.pi, np.pi)}
        links.append(link)
    return Robot.model_validate({"links": links,
                                 "gravity": 0.0 if rng.random() < 0.3 else 20 * rng.random(),
                                 "rotational_inertia": str(rng.choice(["cumulative", "absolute"]))})


def random_rows(count: int, seed: int = 20261122) -> tuple[list[dict], dict]:
    rng = np.random.default_rng(seed)
    rows, started = [], time.perf_counter()
    for k in range(count):
        robot = random_robot(rng)
        q = rng.uniform(-np.pi, np.pi, robot.n)
        dq, ddq = rng.uniform(-3, 3, robot.n), rng.uniform(-3, 3, robot.n)
        rows.append({"robot": k, "n": robot.n, **invariants(robot, q, dq, ddq)})
    summary = {"robots": count, "time": time.perf_counter() - started,
               **{f"worst {key}": (min if key == "definiteness" else max)(r[key] for r in rows)
                  for key in ("asymmetry", "definiteness", "kinetic", "power")}}
    return rows, summary


# ------------------------------------------------------------------ the service


def malformed_rows(url: str) -> list[dict]:
    """Every hand-made bad body, POSTed to /v1/plans and /v1/dynamics: 4xx problem+json."""
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
                             and r.headers.get("content-type", "")
                             .startswith("application/problem+json")})
    return rows


def schemathesis_run(url: str, examples: int, workdir: Path) -> dict:
    """Schemathesis (positive and negative generation) against the committed OpenAPI."""
    checks = ("not_a_server_error,response_schema_conformance,status_code_conformance,"
              "content_type_conformance")
    started = time.perf_counter()
    run = subprocess.run(
        [sys.executable, "-m", "schemathesis.cli", "run",
         str(harness.ROOT / "openapi" / "openapi.json"),
         "--url", url, "--checks", checks, "--mode", "all", "--max-examples", str(examples),
         "--seed", "2", "--workers", "1", "--request-timeout", "30",
         "--generation-database", "none", "--no-color"],
        check=False, cwd=workdir, capture_output=True, text=True, timeout=1800)
    summary = run.stdout.split("SUMMARY")[-1]
    return {"examples per operation": examples, "exit code": run.returncode,
            "time [s]": round(time.perf_counter() - started), "summary": summary.strip()}


def service_rows(examples: int) -> tuple[list[dict], list[dict], dict]:
    """The faults of `testbed.probes`, the bad bodies and schemathesis against one live server."""
    tmp = Path(tempfile.mkdtemp(prefix="undertow-stress-"))
    limits = {"UNDERTOW_MAX_NODES": "400", "UNDERTOW_MAX_WALL_TIME": "60",
              "UNDERTOW_MAX_QUEUED": "4", "UNDERTOW_MAX_WAIT": "30"}
    with LiveServer(tmp / "jobs.sqlite3", None, **limits) as live, \
            httpx.Client(base_url=live.url, timeout=60) as http:
        faults = [kill_worker_case(live, http), *disconnect_cases(live, http)]
        bodies = malformed_rows(live.url)
        fuzz = schemathesis_run(live.url, examples, tmp)
        faults.append({"fault": "after all of the above",
                       "healthz": http.get("/healthz").status_code,
                       "ok": http.get("/healthz").status_code == 200})
    return faults, bodies, fuzz


# ------------------------------------------------------------------ report

DOC = harness.DOCS / "stability.md"


PLAN_COLUMNS = [("status", "status"), ("success", "success"), ("verified", "verified"),
                ("iterations", "iterations"), ("solves", "solves"),
                ("interval_error", "interval error [rad]"),
                ("replay_error", "open-loop replay [rad]")]
"""Columns of `testbed.edges.plan_row` shared by the planner's tables."""


def singular_text(rows: list[dict]) -> str:
    inverse = [r for r in rows if r["part"] == "inverse"]
    plans = [r for r in rows if r["part"] == "plan"]
    return "\n\n".join([
        ("Classical inverse dynamics (`planner.inverse.solve`) started at a configuration with "
         "the given sigma_min(M_pa), the active joints turning at 1 rad/s (so the passive rows "
         "ask for active accelerations near -h_p / sigma_min), the passive joints moving 0.2 "
         "rad in 1 s; once with the default threshold 1e-3, once with a threshold ten times "
         "below the start's sigma_min. Each case in its own process, stopped after "
         f"{INVERSE_TIMEOUT:g} s. A threshold below the resolution floor "
         "(`planner.inverse.RESOLUTION` = 1e-8 of the largest diagonal entry of M: 4.5e-9 on "
         "the 2-link arm, 7.3e-9 on the seed arm) stops at the floor, or at once when the "
         "start lies below it: closer to the singularity, rounding in M_pa, divided by "
         "sigma_min, becomes noise larger than the integration tolerance and DOP853's steps "
         "collapse."),
        harness.table(inverse, [("arm", "arm"), ("sigma", "sigma_min target"),
                                ("actual", "sigma_min at q"), ("threshold", "threshold"),
                                ("status", "status"), ("stop_time", "stop t [s]"),
                                ("stop_sigma", "sigma_min at stop"),
                                ("max_tau", "max abs tau [N m]"),
                                ("non_finite", "non-finite values"), ("time", "time [s]"),
                                ("failure", "failure")]),
        ("The planner with its defaults (mesh refinement and retries on, 60 s a plan) from the "
         "same near-singular start (rest to rest, Legendre degree 3, N = 30 on the first mesh; "
         "2-link: 2 s to (q0 + 0.3, q1 - 0.5); seed arm: 4 s to the seed-4 task's final "
         "configuration), without and with a coupling margin of 1e-3 (which the start "
         "violates for sigma_min < 1e-3 on the waveless arm):"),
        harness.table(plans, [("arm", "arm"), ("sigma", "sigma_min at start"),
                              ("margin", "margin"), *PLAN_COLUMNS,
                              ("min_sigma", "min sigma_min"),
                              ("non_finite", "non-finite values"), ("time", "time [s]"),
                              ("message", "message")]),
    ])


def scaled_text(rows: list[dict]) -> str:
    summary = []
    for sweep in dict.fromkeys(r["sweep"] for r in rows):
        mine = [r for r in rows if r["sweep"] == sweep]
        ok = [r for r in mine if r.get("success")]
        errors = [r["interval_error"] for r in ok if r.get("interval_error") is not None]
        summary.append({"sweep": sweep, "plans": len(mine), "succeeded": len(ok),
                        "verified": sum(bool(r.get("verified")) for r in mine),
                        "rate": len(ok) / len(mine),
                        "worst": max(errors) if errors else None,
                        "non_finite": sum(r.get("non_finite") or 0 for r in mine),
                        "raised": sum(r.get("status") in ("raised", "crashed") or "failure" in r
                                      for r in mine)})
    return "\n\n".join([
        ("One plan per robot and arm type with the planner's defaults (mesh refinement and "
         "retries on; Legendre degree 3, N = 30 on the first mesh, 60 s a plan): active "
         "joints move +0.5 rad rest to rest; passive joints start at rest and end free, so "
         "every task is feasible and a failure is the solver's. Base robot "
         "(`testbed.robots.chain`): 2 links of 0.4 m, 1 kg, I = m l^2 / 50, g = 9.81, a wave "
         "(0.1 l, frequency 3, phase 0.3) on odd joints; underactuated: even joints passive. "
         "Each plan in its own process."),
        harness.table(summary, [("sweep", "sweep"), ("plans", "plans"),
                                ("succeeded", "succeeded"), ("verified", "verified"),
                                ("rate", "success rate"),
                                ("worst", "worst interval error [rad]"),
                                ("non_finite", "non-finite values"),
                                ("raised", "raised or crashed")]),
        harness.table(rows, [("sweep", "sweep"), ("value", "value"), ("arm", "arm"),
                             *PLAN_COLUMNS, ("solve", "solve [s]"),
                             ("defect", "defect [N m s]"), ("non_finite", "non-finite values"),
                             ("message", "message")]),
    ])


def random_text(summary: dict) -> str:
    return "\n\n".join([
        (f"{summary['robots']} random robots (`random_robot`: 1 to 8 links, lengths 1e-2..10 m "
         "and masses 1e-3..1e3 kg log-uniform, inertias 0 or up to m l^2, random joint types, "
         "waves of amplitude up to 0.9 l and frequency up to 20, g 0 or up to 20, both "
         "rotational conventions), one random state each (q in [-pi, pi], dq and ddq in "
         f"[-3, 3]). Took {summary['time']:.0f} s. Worst over all robots:"),
        harness.table([{"check": "asymmetry max abs(M - M') / max abs(M)",
                        "worst": summary["worst asymmetry"], "bound": "0 (exact)"},
                       {"check": "definiteness lambda_min / lambda_max of M",
                        "worst": summary["worst definiteness"], "bound": "> 0"},
                       {"check": "kinetic abs(T - dq'M dq / 2) / T",
                        "worst": summary["worst kinetic"], "bound": "~1e-15"},
                       {"check": "power abs(dq'(M ddq + h) - dE/dt) / scale",
                        "worst": summary["worst power"], "bound": "~1e-9 (finite differences)"}],
                      [("check", "invariant"), ("worst", "worst value"), ("bound", "expected")]),
        ("The same invariants run under hypothesis in tests/test_stress.py "
         "(`test_random_robots_keep_the_dynamics_invariants`, 1000 examples, slow)."),
    ])


def service_text(faults: list[dict], bodies: list[dict], fuzz: dict) -> str:
    keys = list(dict.fromkeys(k for r in faults for k in r))
    return "\n\n".join([
        ("A live uvicorn (`app.main:app`, 2 worker processes, `testbed.service.LiveServer`) on "
         "127.0.0.1 with a temporary store; the faults of `testbed.probes`."),
        harness.table(faults, [(k, k) for k in keys]),
        ("Hand-made malformed bodies, each POSTed to /v1/plans and /v1/dynamics; `ok` means a "
         "4xx answer with an application/problem+json body:"),
        harness.table(bodies, [("body", "body"), ("path", "path"), ("status", "status"),
                               ("ok", "ok"), ("detail", "detail")]),
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


def _flat(rows: list[dict]) -> list[dict]:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    return [{k: r.get(k) for k in keys} for r in rows]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench stress", description=__doc__)
    parser.add_argument("--parts", default="singular,scaled,random,service")
    parser.add_argument("--sigmas", default=",".join(f"{s:g}" for s in SIGMAS),
                        help="the near-singular starts' sigma_min(M_pa) [kg m^2]")
    parser.add_argument("--sweeps", default=None,
                        help="the badly scaled sweeps to run, ';'-separated (default: all)")
    parser.add_argument("--robots", type=int, default=1000)
    parser.add_argument("--examples", type=int, default=25, help="schemathesis, per operation")
    args = parser.parse_args(argv)
    parts = args.parts.split(",")
    started, note = time.perf_counter(), harness.machine_note()

    def write(csv: str, rows: list[dict], heading: str, text: str) -> None:
        harness.write_csv(harness.RESULTS / csv, rows)
        harness.write_section(DOC, heading, "\n\n".join([
            text, f"Rows: `bench/results/{csv}`. "
                  f"{harness.manifest('stress', argv, started, note)}"]))

    if "singular" in parts:
        rows = singular_rows([float(s) for s in args.sigmas.split(",")])
        write("stress_singular.csv", _flat(rows), "Near-singular configurations",
              singular_text(rows))
    if "scaled" in parts:
        rows = scaled_rows(args.sweeps.split(";") if args.sweeps else None)
        write("stress_scaled.csv", _flat(rows), "Badly scaled robots", scaled_text(rows))
    if "random" in parts:
        rows, summary = random_rows(args.robots)
        write("stress_random.csv", rows, "Random robots: dynamics invariants",
              random_text(summary))
    if "service" in parts:
        faults, bodies, fuzz = service_rows(args.examples)
        write("stress_service.csv", _flat(faults + bodies), "The service under faults",
              service_text(faults, bodies, fuzz))
    return 0
