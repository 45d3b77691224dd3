"""The memory bound of the synchronous computations (`app.sync_memory`): every estimate
covers what its computation was measured to take, a request estimated above
UNDERTOW_SYNC_MEMORY_MB is a 422 at its field, one that finds the budget held by those
running waits UNDERTOW_COMPUTE_WAIT and is a 503 with Retry-After, and the budget itself
lets a waiter in as soon as room comes free."""

from __future__ import annotations

import csv
import threading
import time
from pathlib import Path

import anyio
import pytest
from service_fixtures import TWO_LINK, client

from app.settings import Settings
from app.sync_memory import (
    PLAN_SAMPLE_MB,
    PLOT_MB,
    MemoryBudget,
    estimate,
    too_large,
)
from bench.sync_memory import request as bench_request
from planner import coupling, evaluation, inverse, simulate, waves
from testbed.robots import chain

ROOT = Path(__file__).resolve().parents[1]
MEASURED = ROOT / "bench" / "results" / "sync_memory.csv"
"""What `python -m bench sync_memory` measured: one row per computation."""
MODELS = {"dynamics": evaluation.DynamicsRequest, "coupling": coupling.CouplingRequest,
          "inverse-dynamics": inverse.InverseDynamicsRequest,
          "simulate": simulate.SimulationRequest, "waves-motion": waves.WaveDesignRequest,
          "waves-region": waves.WaveDesignRequest}
SIMULATION = {"robot": TWO_LINK, "t": [0.0, 0.5, 1.0], "tau": [[0.0], [0.1], [0.0]],
              "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]}}


def measured() -> list[dict]:
    with open(MEASURED) as f:
        return [row for row in csv.DictReader(f) if row["peak"]]


def estimated(row: dict) -> float:
    """The estimate of the computation a row measured."""
    kind = row["kind"]
    if kind == "plot":
        return PLOT_MB
    if kind == "sample":
        return PLAN_SAMPLE_MB
    body = bench_request(kind, int(row["links"]), int(row["size"]), int(row["option"]))
    return estimate(MODELS[kind].model_validate(body)).mb


@pytest.mark.parametrize("row", measured(), ids=lambda r: "-".join(
    r[k] for k in ("kind", "links", "size", "option")))
def test_no_measured_computation_takes_more_than_its_estimate(row):
    """What a computation reserves covers what it takes, so the reservations bound it."""
    assert float(row["peak"]) <= estimated(row)
    assert float(row["estimate"]) == pytest.approx(estimated(row), rel=1e-4), "re-run the bench"


def wave_design(links: int) -> dict:
    """A motion design of `chain(links)` without waves (as the bench measures it)."""
    return bench_request("waves-motion", links, 2001, 2)


def test_a_computation_larger_than_the_budget_is_refused_at_its_field():
    settings = Settings(sync_memory_mb=64)
    design = waves.WaveDesignRequest.model_validate(wave_design(8))
    need = estimate(design)
    [error] = too_large(need, settings)
    assert (error.loc, error.type) == (["body", "robot", "links"], "limit")
    assert error.msg == (f"this computation needs about {need.mb:.0f} MB, more than the 64 MB "
                         "the synchronous computations may use on this server "
                         "(UNDERTOW_SYNC_MEMORY_MB): ask for fewer links")
    assert too_large(need, Settings(sync_memory_mb=int(need.mb) + 1)) == []
    region = waves.WaveDesignRequest.model_validate(bench_request("waves-region", 8, 2000, 1))
    assert estimate(region).loc == ("robot", "links")
    many = evaluation.DynamicsRequest.model_validate(bench_request("dynamics", 8, 6000, 0))
    assert estimate(many).loc == ("states",)


def test_the_service_answers_422_for_a_request_beyond_the_budget(tmp_path):
    with client(tmp_path, workers=0, sync_memory_mb=64) as api:
        r = api.post("/v1/dynamics", json=bench_request("dynamics", 8, 6000, 0))
        small = api.post("/v1/waves/design", json=wave_design(2))
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["errors"] == [{
        "loc": ["body", "states"], "type": "limit",
        "msg": "this computation needs about 66 MB, more than the 64 MB the synchronous "
               "computations may use on this server (UNDERTOW_SYNC_MEMORY_MB): ask for "
               "fewer states"}]
    assert small.status_code == 200, small.text


def test_a_full_budget_answers_503_with_retry_after_and_quick_requests_pass(tmp_path):
    with client(tmp_path, workers=0, sync_memory_mb=100, compute_wait=0.2) as api:
        budget: MemoryBudget = api.app.state.sync_memory  # type: ignore[attr-defined]
        assert api.portal.call(budget.reserve, 98.0, 1.0)  # type: ignore[union-attr]
        busy = api.post("/v1/simulate", json=SIMULATION)
        plot = api.get("/v1/plans/none/plot.png")
        one_state = api.post("/v1/dynamics", json={  # quick: reserves nothing
            "robot": TWO_LINK, "states": [{"q": [0.1, 0.2], "dq": [0.0, 0.0]}]})
        assert "undertow_sync_memory_reserved_megabytes 98.0" in api.get("/metrics").text
        api.portal.call(budget.release, 98.0)  # type: ignore[union-attr]
        after = api.post("/v1/simulate", json=SIMULATION)
        assert budget.used == 0.0
    need = estimate(simulate.SimulationRequest.model_validate(SIMULATION)).mb
    assert busy.status_code == 503 and busy.headers["retry-after"] == "5"
    assert busy.headers["content-type"] == "application/problem+json"
    problem = busy.json()
    assert (problem["type"], problem["title"]) == (
        "urn:undertow:problem:busy", "The synchronous computations are at their memory bound")
    assert problem["detail"] == (
        f"the synchronous computations running hold 98 MB of the 100 MB this server gives "
        f"them (UNDERTOW_SYNC_MEMORY_MB) and this one needs about {need:.0f} MB; no room came "
        "free within 0.2 s (UNDERTOW_COMPUTE_WAIT); retry in 5 s")
    assert plot.status_code == 503 and plot.json()["type"] == "urn:undertow:problem:busy"
    assert one_state.status_code == 200
    assert after.status_code == 200


def test_a_waiting_request_runs_as_soon_as_room_comes_free(tmp_path):
    with client(tmp_path, workers=0, sync_memory_mb=100, compute_wait=20.0) as api:
        budget: MemoryBudget = api.app.state.sync_memory  # type: ignore[attr-defined]
        assert api.portal.call(budget.reserve, 95.0, 1.0)  # type: ignore[union-attr]
        out: list = []
        thread = threading.Thread(target=lambda: out.append(
            api.post("/v1/simulate", json=SIMULATION)))
        thread.start()
        time.sleep(0.5)
        assert not out, "the request waits while the budget is held"
        freed = time.monotonic()
        api.portal.call(budget.release, 95.0)  # type: ignore[union-attr]
        thread.join(30)
        assert out[0].status_code == 200 and time.monotonic() - freed < 5.0


def test_the_budget_reserves_within_its_total_and_wakes_waiters():
    async def scenario() -> list[str]:
        budget, events = MemoryBudget(100), []
        assert await budget.reserve(60, 0.0)
        assert not await budget.reserve(50, 0.05)  # 110 > 100: no room within the wait
        assert budget.used == 60

        async def waiter(name: str, mb: float) -> None:
            if await budget.reserve(mb, 5.0):
                events.append(name)

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(waiter, "forty", 40.0)  # fits at once
            tasks.start_soon(waiter, "fifty", 50.0)  # waits for room
            await anyio.sleep(0.05)
            assert events == ["forty"] and budget.used == 100
            await budget.release(60)
        assert budget.used == 90
        return events

    assert anyio.run(scenario) == ["forty", "fifty"]


def test_every_synchronous_route_is_bounded(tmp_path):
    """Each compute route reserves memory (or is quick): with the budget held, each is a
    503, none runs."""
    robot = chain(2, True)
    bodies = {"/v1/dynamics": bench_request("dynamics", 2, 100, 0),
              "/v1/coupling": bench_request("coupling", 2, 441, 0),
              "/v1/inverse-dynamics": bench_request("inverse-dynamics", 2, 401, 0),
              "/v1/simulate": {**SIMULATION, "robot": robot},
              "/v1/waves/design": wave_design(2)}
    with client(tmp_path, workers=0, sync_memory_mb=1000, compute_wait=0.1) as api:
        budget: MemoryBudget = api.app.state.sync_memory  # type: ignore[attr-defined]
        assert api.portal.call(budget.reserve, 1000.0, 1.0)  # type: ignore[union-attr]
        answers = {path: api.post(path, json=body).status_code for path, body in bodies.items()}
        answers["/v1/plans/{id}/sample"] = api.get("/v1/plans/none/sample?t=0").status_code
    assert answers == dict.fromkeys(answers, 503)
