"""Footprint of the container image: its size and the memory a running container holds.

Needs the image `.ci/docker` builds (UNDERTOW_IMAGE, default undertow:ci) and a running
docker daemon; run `bash .ci/docker` first, which leaves both. Starts one container with
2 solver workers on a loopback port, then records its memory (`docker stats`) when idle
and after each of `len(PLANS)` plans of the built-in examples, one at a time: the
memory a user sees grows as each worker builds and caches the NLPs of the plans it ran.
Writes the section "Measured footprint" of docs/deploy.md and bench/results/container.csv.

    python -m bench container [--plans 4]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import time

import httpx

from bench import harness
from testbed.service import free_port

SECTION = "Measured footprint"
IMAGE = os.environ.get("UNDERTOW_IMAGE", "undertow:ci")
SETTLE = 10.0  # [s] after /healthz answers, before the idle reading
PLANS = ("two-link-plan", "seed-arm-plan", "two-link-plan", "seed-arm-plan")
COLUMNS = [("moment", "moment"), ("memory", "container memory [MiB]"), ("example", "example"),
           ("plan", "plan")]


def docker(*args: str) -> str:
    """Output of a docker command (raises when it fails)."""
    return subprocess.run(["docker", *args], check=True, capture_output=True,
                          text=True).stdout.strip()


def memory_mib(container: str) -> float:
    """The container's memory use [MiB], as `docker stats` reports it ("84.1MiB / 23GiB")."""
    usage = docker("stats", "--no-stream", "--format", "{{.MemUsage}}", container)
    match = re.match(r"\s*([\d.]+)\s*([KMG]i?B)", usage)
    if match is None:
        raise ValueError(f"docker stats: no memory use in {usage!r}")
    number, unit = match.groups()
    return float(number) * {"KiB": 1 / 1024, "MiB": 1.0, "GiB": 1024.0, "kB": 1e3 / 2**20,
                            "MB": 1e6 / 2**20, "GB": 1e9 / 2**20}[unit]


def measure(plans: tuple[str, ...]) -> tuple[dict, list[dict]]:
    """Image facts and the memory readings of one container's life, idle and after each of
    `plans` (built-in examples)."""
    image = json.loads(docker("image", "inspect", IMAGE))[0]
    port = free_port()
    container = docker("run", "-d", "--rm", "-p", f"127.0.0.1:{port}:8000",
                       "-e", "UNDERTOW_WORKERS=2", IMAGE)
    rows = []
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120) as http:
            deadline = time.monotonic() + 90
            while True:
                try:
                    if http.get("/healthz").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                if time.monotonic() > deadline:
                    raise RuntimeError("the container's /healthz did not answer within 90 s")
                time.sleep(0.5)
            time.sleep(SETTLE)
            rows.append({"moment": "idle", "memory": memory_mib(container), "example": "–",
                         "plan": "–"})
            for k, name in enumerate(plans, 1):
                scene = http.get(f"/v1/examples/{name}").json()["request"]
                job = http.post("/v1/plans?wait=30", json=scene).json()
                while job.get("status") in ("queued", "running"):
                    time.sleep(0.5)
                    job = http.get(f"/v1/plans/{job['id']}").json()
                rows.append({"moment": f"after plan {k}", "memory": memory_mib(container),
                             "example": name, "plan": job["status"]})
    finally:
        subprocess.run(["docker", "rm", "-f", container], check=False, capture_output=True)
    facts = {"image": IMAGE, "size_mb": image["Size"] / 1e6, "created": image["Created"][:19]}
    return facts, rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench container", description=__doc__)
    parser.add_argument("--plans", type=int, default=len(PLANS),
                        help="plan the first this many of the examples")
    args = parser.parse_args(argv)
    plans = PLANS[:args.plans]
    started, note = time.perf_counter(), harness.machine_note()
    facts, rows = measure(plans)
    text = "\n\n".join([
        (f"Image `{facts['image']}` built by `.ci/docker` ({facts['created']} UTC): "
         f"{facts['size_mb']:.0f} MB. One container with `UNDERTOW_WORKERS=2` (default "
         "`UNDERTOW_WORKER_MEMORY_MB`); memory as `docker stats` reports it, "
         f"{SETTLE:g} s after /healthz first answers and after each of {len(plans)} plans of "
         "the built-in examples (`POST /v1/plans`, each to its end before the next). The "
         "idle figure is the server alone: its workers start with the first plan and each "
         "loads CasADi; each plan then adds the NLP its worker builds and keeps for the next "
         "plan of the same structure, so the figure after a few plans is the one to size a "
         f"container by. Load average at the end: {harness.load()}."),
        harness.table(rows, COLUMNS),
        f"Rows: `bench/results/container.csv`. "
        f"{harness.manifest('container', argv, started, note)}"])
    print(text)
    harness.write_csv(harness.RESULTS / "container.csv", [{**facts, **row} for row in rows])
    harness.write_section(harness.DOCS / "deploy.md", SECTION, text)
    return 0
