"""The up-front memory estimate against the measurements it was fitted to."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import pytest

from app.capacity import capacity_errors, estimate_mb
from app.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
MEASURED = ROOT / "bench" / "results" / "capacity.csv"
sys.path.insert(0, str(ROOT))

from bench.capacity import scene_of


def measured() -> list[dict]:
    with open(MEASURED) as f:
        return [row for row in csv.DictReader(f) if row["vm_solve"]]


@pytest.mark.parametrize("row", measured(), ids=lambda r: "-".join(
    r[k] for k in ("links", "method", "degree", "intervals", "integrator", "steps", "form",
                   "extra") if r[k]))
def test_no_measured_plan_needs_less_than_its_estimate(row):
    """The estimate refuses only plans that would certainly not fit."""
    scene = scene_of(int(row["links"]), row["method"], int(row["degree"]),
                     int(row["intervals"]), row["integrator"], int(row["steps"]), row["form"],
                     row["extra"])
    assert estimate_mb(scene) <= float(row["vm_solve"])


def test_the_limit_is_the_worker_memory_setting():
    scene = scene_of(8, "multiple-shooting", 3, 10, "rk4", 20, "implicit", "")
    needed = estimate_mb(scene)
    assert capacity_errors(scene, Settings(worker_memory_mb=int(needed) + 1)) == []
    [error] = capacity_errors(scene, Settings(worker_memory_mb=int(needed)))
    assert error.loc == ["body", "transcription", "steps"] and error.type == "limit"
    assert f"more than the {int(needed)} MB a solver worker may use" in error.msg
