"""Where a GET of a finished plan job spends its time.

The plan of `seed-arm-plan` is stored as a finished job in a fresh SQLite store, which the
service then serves in-process (FastAPI's TestClient). Timed, median of `--repeats` each:

- the whole GET of `/v1/plans/{id}`, from sending the request to the decoded body, and a
  GET of `/healthz` beside it (what any request costs);
- its parts: reading the job from the store (the row, and the decompression and decoding
  of the plan's JSON, `app.store.json_text`), the validation of the stored plan into the
  response model (`Job.of`), the serialisation of that model to JSON, and the client's
  decoding of the body.

    python -m bench plan_response [--repeats 50]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.main import create_app
from app.schemas import Job
from app.settings import Settings
from app.store.sqlite import SqliteJobStore
from bench import harness
from planner.examples import example
from planner.ocp import plan
from planner.scene import Scene

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Fetching a plan: GET /v1/plans/{id}"


def measure(stored: dict, repeats: int) -> list[dict]:
    """The GET of a job holding the plan `stored`, whole and by part, as rows."""
    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "jobs.sqlite3")
        store = SqliteJobStore(path)
        store.create("job", {}, "bench")
        store.claim("bench", "bench/0", time.time() + 60)
        store.finish("job", "succeeded", stored, None)
        record = store.get("job")
        assert record is not None
        job = Job.of(record)
        text = job.model_dump_json()
        parts = {
            "the whole GET": None,
            "reading the job from the store": lambda: store.get("job"),
            "validating the stored plan (Job.of)": lambda: Job.of(record),
            "writing the JSON": lambda: job.model_dump_json(),
            "the client decoding it": lambda: json.loads(text),
            "GET /healthz": None,
        }
        with TestClient(create_app(Settings(db_path=path, workers=1, instance="bench"))) as c:
            body = c.get("/v1/plans/job").json()
            if body["plan"] != stored:
                raise RuntimeError("the service returned another plan than the stored one")
            parts["the whole GET"] = lambda: c.get("/v1/plans/job").json()
            parts["GET /healthz"] = lambda: c.get("/healthz").json()
            rows = [{"part": name,
                     "ms": 1000 * harness.median(harness.timed(fn)[1] for _ in range(repeats))}
                    for name, fn in parts.items() if fn is not None]
        store.close()
    return rows


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench plan_response", description=__doc__)
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    stored = plan(Scene.model_validate(example("seed-arm-plan").request)).model_dump(mode="json")
    size = len(json.dumps(stored))
    rows = measure(stored, args.repeats)
    for row in rows:
        print(row)
    harness.write_csv(harness.RESULTS / "plan_response.csv", rows)
    text = "\n\n".join([
        f"The plan of `seed-arm-plan` ({size / 1000:.0f} kB of JSON) stored as a finished "
        "job and fetched through the service in-process (FastAPI's TestClient); median of "
        f"{args.repeats} of each. The parts are timed on their own, outside the request.",
        harness.table(rows, [("part", "part"), ("ms", "median [ms]")]),
        "Rows: `bench/results/plan_response.csv`. "
        + harness.manifest("plan_response", argv, started, note)])
    harness.write_section(DOC, SECTION, text)
    return 0
