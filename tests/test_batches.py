"""Batch sweeps over HTTP (the fake solver): members from overrides and from a grid, the
summary table, field-level 422s, the member bound, the queue's room, and `undertow sweep`."""

from __future__ import annotations

import io
import json
import time

import pytest
from service_fixtures import client, serving, two_link_scene

from app import cli, sweep_client
from app.main import create_app
from app.settings import Settings
from testbed.fake_solvers import fake_plan

GRID = {"duration": [1.0, 2.0], "final.q.0": [0.5, 0.7, 0.9]}


def finished(c, batch_id: str, timeout: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        batch = c.get(f"/v1/batches/{batch_id}").json()
        if batch["finished"] == batch["size"]:
            return batch
        time.sleep(0.05)
    raise AssertionError(f"batch {batch_id} did not end in {timeout} s")


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("batches"), solve=fake_plan, workers=1, max_queued=12,
                max_batch_members=8) as c:
        yield c


def test_a_grid_makes_one_job_per_combination_and_a_summary(api):
    answer = api.post("/v1/batches", json={"base": two_link_scene(), "grid": GRID})
    assert answer.status_code == 202
    assert answer.headers["location"] == f"/v1/batches/{answer.json()['id']}"
    batch = finished(api, answer.json()["id"])
    assert (batch["size"], batch["finished"], batch["verified"]) == (6, 6, 6)
    assert batch["counts"] == {"queued": 0, "running": 0, "succeeded": 6, "failed": 0,
                               "cancelled": 0}
    assert [m["parameters"] for m in batch["members"]] == [
        {"duration": d, "final.q.0": q} for d in GRID["duration"] for q in GRID["final.q.0"]]
    for member in batch["members"]:
        job = api.get(f"/v1/plans/{member['job_id']}").json()
        assert job["status"] == member["status"] == "succeeded"
        assert member["objective"] == job["plan"]["objective"]
        assert member["verified"] is True and member["time"] > 0
        # the member's scene is the base with its parameters set
        assert job["plan"]["duration"] == member["parameters"]["duration"]


def test_overrides_set_waves_and_angles_and_failures_show_in_the_table(api):
    overrides = [{"wave.1.amplitude": 0.02, "initial.q.1": 0.3}, {"duration": 1.5}]
    base = two_link_scene()
    failing = {**base, "solver": {**base["solver"], "tol": 0.6}}  # the fake solver fails
    answer = api.post("/v1/batches", json={"base": failing, "overrides": overrides})
    batch = finished(api, answer.json()["id"])
    assert [m["status"] for m in batch["members"]] == ["failed", "failed"]
    assert batch["verified"] == 0
    assert all(m["error"].startswith("Maximum_Iterations_Exceeded") for m in batch["members"])
    ok = finished(api, api.post("/v1/batches", json={"base": base, "overrides": overrides})
                  .json()["id"])
    first = api.get(f"/v1/plans/{ok['members'][0]['job_id']}").json()
    assert first["plan"]["q"][0] == [0.0, 0.3]  # initial.q.1 reached the member's scene


def test_invalid_members_are_422s_at_their_fields(api):
    stored = len(api.get("/v1/plans?limit=100").json()["items"])
    overrides = [{"duration": 1.0}, {"duration": -1.0}, {"wave.0.phase": 1.0},
                 {"final.q.7": 1.0}, {"speed": 2.0}]
    r = api.post("/v1/batches", json={"base": two_link_scene(), "overrides": overrides})
    assert r.status_code == 422
    assert r.headers["content-type"] == "application/problem+json"
    assert [e["loc"] for e in r.json()["errors"]] == [
        ["body", "overrides", 1, "task", "duration"], ["body", "overrides", 2, "wave.0.phase"],
        ["body", "overrides", 3, "final.q.7"], ["body", "overrides", 4, "speed"]]
    grid = api.post("/v1/batches", json={"base": two_link_scene(),
                                         "grid": {"duration": [1.0, -2.0]}}).json()
    assert grid["errors"][0]["loc"] == ["body", "grid", "task", "duration"]
    assert grid["errors"][0]["msg"].startswith("member 1 (duration=-2): ")
    both = api.post("/v1/batches", json={"base": two_link_scene(), "grid": GRID,
                                         "overrides": [{}]}).json()
    assert both["errors"] == [{"loc": ["body"], "msg": "give either overrides or grid",
                               "type": "value_error"}]
    nan = api.post("/v1/batches", content=json.dumps(
        {"base": two_link_scene(), "overrides": [{"duration": 1.0}]}).replace("1.0}]", "NaN}]"),
        headers={"content-type": "application/json"})
    assert nan.status_code in (400, 422)
    assert len(api.get("/v1/plans?limit=100").json()["items"]) == stored  # none stored


def test_the_member_bound_and_the_queue_room_are_enforced(tmp_path):
    with client(tmp_path, solve=fake_plan, workers=1, max_queued=4, max_batch_members=8) as c:
        big = {"duration": [1.0, 1.5, 2.0], "final.q.0": [0.5, 0.7, 0.9]}
        r = c.post("/v1/batches", json={"base": two_link_scene(), "grid": big})
        assert r.status_code == 422
        assert r.json()["errors"][0]["loc"] == ["body", "grid"]
        assert "limit of 8 (UNDERTOW_MAX_BATCH_MEMBERS)" in r.json()["errors"][0]["msg"]
        slow = two_link_scene(iterations=500)
        assert c.post("/v1/plans", json=slow).status_code == 202
        # a batch may take the server max_batch_members beyond its 5 places: 1 + 8 fit
        eight = {"duration": [1.0, 2.0], "final.q.0": [0.5, 0.6, 0.7, 0.9]}
        first = c.post("/v1/batches", json={"base": slow, "grid": eight})
        assert first.status_code == 202, first.text
        six = {"duration": [1.0, 2.0], "final.q.0": [0.5, 0.7, 0.9]}
        full = c.post("/v1/batches", json={"base": slow, "grid": six})
        assert full.status_code == 429 and full.headers["retry-after"]
        assert len(c.get("/v1/plans?limit=100").json()["items"]) == 9  # all or none
        assert c.get("/v1/batches/nope").status_code == 404
        assert c.delete(f"/v1/batches/{first.json()['id']}").status_code == 200


def test_undertow_sweep_submits_follows_and_prints_the_table(tmp_path, capsys):
    config = Settings(db_path=str(tmp_path / "jobs.sqlite3"), workers=1, instance="sweep")
    request = tmp_path / "batch.json"
    request.write_text(json.dumps({"base": two_link_scene(), "grid": {"duration": [1.0, 2.0]}}))
    with serving(create_app(config, solve=fake_plan)) as port:
        url = f"http://127.0.0.1:{port}"
        code = cli.main(["sweep", str(request), "--url", url, "-o", str(tmp_path / "out.json")])
        _, err = capsys.readouterr()
        assert code == 0, err
        summary = json.loads((tmp_path / "out.json").read_text())
        assert summary["counts"]["succeeded"] == 2
        assert "2 members (2 succeeded); 2 verified" in err
        assert "duration=2" in err
        request.write_text(json.dumps({"base": two_link_scene(), "grid": {"duration": [-1.0]}}))
        assert cli.main(["sweep", str(request), "--url", url]) == 2
        assert "grid.task.duration: member 0 (duration=-1)" in capsys.readouterr().err
    assert cli.main(["sweep", str(request), "--url", url]) == 3  # no server any more


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_sweep_progress_on_a_file_is_a_line_per_change_and_on_a_terminal_one_line():
    looks = [(0, 0), (0, 0), (0, 0), (1, 1), (1, 1), (2, 1), (2, 1)]
    batches = [{"finished": f, "verified": v, "size": 3} for f, v in looks]
    logged = io.StringIO()
    follow = sweep_client.Follow(logged)
    for k, batch in enumerate(batches):
        follow.show(batch, float(k))
    follow.close()
    assert logged.getvalue().splitlines() == ["  0/3 finished, 0 verified",
                                              "  1/3 finished, 1 verified",
                                              "  2/3 finished, 1 verified"]
    terminal = _Terminal()
    follow = sweep_client.Follow(terminal)
    for k, batch in enumerate(batches):
        follow.show(batch, float(k))
    follow.close()
    assert terminal.getvalue().count("\n") == 1 and terminal.getvalue().endswith("\n")
    assert terminal.getvalue().split("\r")[-1] == "  2/3 finished, 1 verified      6 s\n"


def test_a_200_member_batch_is_accepted_progresses_is_cancelled_and_downloads_as_csv(tmp_path):
    with client(tmp_path, solve=fake_plan, workers=1) as c:  # the default limits
        grid = {"duration": [1.0 + 0.1 * k for k in range(20)],
                "final.q.0": [0.5 + 0.05 * k for k in range(10)]}
        answer = c.post("/v1/batches", json={"base": two_link_scene(iterations=5),
                                             "grid": grid})
        assert answer.status_code == 202, answer.text
        batch_id = answer.json()["id"]
        assert answer.json()["size"] == 200
        deadline = time.monotonic() + 60
        while (batch := c.get(f"/v1/batches/{batch_id}").json())["finished"] < 3:
            assert time.monotonic() < deadline, batch["counts"]
            time.sleep(0.1)
        cancelled = c.delete(f"/v1/batches/{batch_id}")
        assert cancelled.status_code == 200
        counts = cancelled.json()["counts"]
        assert counts["queued"] == 0 and counts["cancelled"] >= 190, counts
        batch = finished(c, batch_id)
        assert batch["counts"]["succeeded"] + batch["counts"]["cancelled"] == 200
        assert c.delete("/v1/batches/nope").status_code == 404
        for r in (c.get(f"/v1/batches/{batch_id}/results.csv"),
                  c.get(f"/v1/batches/{batch_id}", headers={"accept": "text/csv"})):
            assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
            lines = r.text.splitlines()
            assert lines[0] == ("index,job_id,duration,final.q.0,status,verified,objective,"
                                "time,error")
            assert len(lines) == 201
            first = lines[1].split(",")
            assert (first[0], first[1], first[2], first[3], first[4], first[5]) == (
                "0", f"{batch_id}-0000", "1.0", "0.5", "succeeded", "true")
            assert lines[-1].split(",")[4] == "cancelled"
            assert lines[-1].endswith(",cancelled on request")
        assert c.get(f"/v1/batches/{batch_id}").headers["content-type"] == "application/json"
