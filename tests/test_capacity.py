"""The up-front memory estimate against the measurements it was fitted to."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from app.capacity import capacity_errors, estimate_mb
from app.settings import Settings
from planner.scene import Scene
from testbed.robots import chain_scene

ROOT = Path(__file__).resolve().parents[1]
MEASURED = ROOT / "bench" / "results" / "capacity.csv"
"""What `python -m bench capacity` measured: one row per scene of `testbed.robots.chain_scene`."""


def scene_of(row: dict) -> Scene:
    """The scene a row of the measurements was measured on."""
    return chain_scene(int(row["links"]), extra=row["extra"], method=row["method"],
                       degree=int(row["degree"]), intervals=int(row["intervals"]),
                       integrator=row["integrator"], steps=int(row["steps"]), form=row["form"])


def measured() -> list[dict]:
    with open(MEASURED) as f:
        return [row for row in csv.DictReader(f) if row["vm_solve"]]


@pytest.mark.parametrize("row", measured(), ids=lambda r: "-".join(
    r[k] for k in ("links", "method", "degree", "intervals", "integrator", "steps", "form",
                   "extra") if r[k]))
def test_no_measured_plan_needs_less_than_its_estimate(row):
    """The estimate refuses only plans that would certainly not fit."""
    assert estimate_mb(scene_of(row)) <= float(row["vm_solve"])


def test_the_limit_is_the_worker_memory_setting():
    scene = chain_scene(8, method="multiple-shooting", intervals=10, steps=20)
    needed = estimate_mb(scene)
    assert capacity_errors(scene, Settings(worker_memory_mb=int(needed) + 1)) == []
    [error] = capacity_errors(scene, Settings(worker_memory_mb=int(needed)))
    assert error.loc == ["body", "transcription", "steps"] and error.type == "limit"
    assert f"more than the {int(needed)} MB a solver worker may use" in error.msg
