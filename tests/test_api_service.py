"""Service-wide behaviour: health, API key, body limit, request ids, JSON logs, metrics."""

from __future__ import annotations

import json
import logging
import re

import pytest
from service_fixtures import TWO_LINK, client

from app.logging import JsonFormatter

DYNAMICS = {"robot": TWO_LINK, "states": [{"q": [0.0, 0.0], "dq": [0.0, 0.0]}]}


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("service"), max_body_bytes=2048) as c:
        yield c


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    with client(tmp_path_factory.mktemp("keyed"), api_key="s3cret") as c:
        yield c


def test_healthz(api):
    r = api.get("/healthz")
    assert (r.status_code, r.json()) == (200, {"status": "ok"})


@pytest.mark.parametrize("method, path, body", [
    ("post", "/v1/dynamics", DYNAMICS), ("post", "/v1/plans", {}), ("get", "/v1/plans", None),
    ("get", "/v1/plans/x", None), ("delete", "/v1/plans/x", None), ("get", "/metrics", None),
    ("post", "/v1/simulate", {}), ("post", "/v1/coupling", {}),
    ("post", "/v1/inverse-dynamics", {})])
def test_every_endpoint_but_healthz_needs_the_key(keyed, method, path, body):
    kwargs = {"json": body} if body is not None else {}
    r = getattr(keyed, method)(path, **kwargs)
    assert r.status_code == 401 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["title"] == "Missing or wrong API key"
    wrong = getattr(keyed, method)(path, headers={"X-API-Key": "guess"}, **kwargs)
    assert wrong.status_code == 401
    right = getattr(keyed, method)(path, headers={"X-API-Key": "s3cret"}, **kwargs)
    assert right.status_code != 401
    assert keyed.get("/healthz").status_code == 200


@pytest.mark.parametrize("body, detail", [
    (b"not json", "Expecting value at character 0 of the body"),
    (b'{"robot": {"links": [}', "Expecting value at character 21 of the body"),
    (b'{"states": [],}', "Expecting property name enclosed in double quotes at character 14 "
                        "of the body"),
    (b"[" * 2_000, "There was an error parsing the body")])
def test_a_body_that_is_not_json_is_400(api, body, detail):
    r = api.post("/v1/dynamics", content=body, headers={"content-type": "application/json"})
    assert r.status_code == 400 and r.headers["content-type"] == "application/problem+json"
    problem = r.json()
    assert (problem["type"], problem["title"], problem["detail"]) == (
        "urn:undertow:problem:malformed-body", "The body is not valid JSON", detail)


@pytest.mark.parametrize("body", [b"not json", b'{"robot": 1}', b" " * 5_000_000])
def test_the_key_is_checked_before_the_body_is_read(keyed, body):
    r = keyed.post("/v1/dynamics", content=body, headers={"content-type": "application/json"})
    assert r.status_code == 401, r.text
    assert r.json()["type"] == "urn:undertow:problem:unauthorized"


def test_a_body_over_the_limit_is_413(api):
    big = {**DYNAMICS, "states": DYNAMICS["states"] * 100}
    r = api.post("/v1/dynamics", json=big)
    assert r.status_code == 413 and r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert (body["type"], body["status"], body["instance"]) == (
        "urn:undertow:problem:request-too-large", 413, "/v1/dynamics")
    assert "UNDERTOW_MAX_BODY_BYTES" in body["detail"]
    assert api.post("/v1/dynamics", json=DYNAMICS).status_code == 200


def test_a_streamed_body_without_length_is_limited_too(api):
    chunks = (b" " * 1024 for _ in range(4))
    r = api.post("/v1/dynamics", content=chunks, headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_request_ids_are_echoed_or_made(api):
    r = api.get("/healthz", headers={"X-Request-ID": "abc-123"})
    assert r.headers["x-request-id"] == "abc-123"
    made = api.get("/healthz").headers["x-request-id"]
    assert len(made) == 32 and made != api.get("/healthz").headers["x-request-id"]
    hostile = api.get("/healthz", headers={"X-Request-ID": "a b\tc"}).headers["x-request-id"]
    assert hostile != "a b\tc" and len(hostile) == 32
    problem = api.get("/v1/plans/x", headers={"X-Request-ID": "trace-7"}).json()
    assert problem["request_id"] == "trace-7"


def test_unknown_routes_and_methods_are_problems(api):
    r = api.get("/v1/nothing")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    r = api.put("/v1/dynamics", json={})
    assert r.status_code == 405 and r.json()["type"] == "urn:undertow:problem:method-not-allowed"


@pytest.mark.parametrize("method, path, allow", [
    ("GET", "/v1/dynamics", "POST"), ("DELETE", "/v1/simulate", "POST"),
    ("PUT", "/v1/plans/abc", "DELETE, GET"), ("PATCH", "/v1/plans", "GET, POST"),
    ("POST", "/healthz", "GET"), ("POST", "/", "GET, HEAD"), ("PUT", "/viewer.js", "GET, HEAD")])
def test_a_wrong_method_is_405_naming_every_allowed_method(api, method, path, allow):
    r = api.request(method, path)
    assert (r.status_code, r.headers["allow"]) == (405, allow)
    assert r.json()["type"] == "urn:undertow:problem:method-not-allowed"


@pytest.mark.parametrize("path", ["/", "/index.html", "/viewer.js", "/viewer.css"])
def test_the_viewer_is_served_at_the_root(api, path):
    assert api.get(path).status_code == 200


def test_the_viewer_gets_the_figures_palette(api):
    from planner.plots import PALETTE

    r = api.get("/palette.js")
    assert r.headers["content-type"].startswith("text/javascript")
    prefix = "window.UNDERTOW_PALETTE = "
    assert r.text.startswith(prefix) and json.loads(r.text[len(prefix):].rstrip(";\n")) == PALETTE


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_the_api_pages_load_everything_from_this_server(api, page):
    html = api.get(page).text
    assets = re.findall(r'(?:src|href)="([^"]+)"', html)
    assert assets and not [a for a in assets if "://" in a or a.startswith("//")]
    for asset in assets:
        if asset != "/openapi.json":
            r = api.get(asset)
            assert r.status_code == 200 and len(r.content) > 1000, asset
    assert api.post(assets[0]).headers["allow"] == "GET, HEAD"


def test_logs_are_json_lines_with_the_request_id(api, caplog):
    with caplog.at_level(logging.INFO, logger="undertow.access"):
        api.get("/healthz", headers={"X-Request-ID": "log-me"})
    record = next(r for r in caplog.records if r.name == "undertow.access")
    line = json.loads(JsonFormatter().format(record))
    assert line["request_id"] == "log-me"
    assert (line["method"], line["path"], line["status"]) == ("GET", "/healthz", 200)
    assert line["level"] == "INFO" and line["duration_ms"] >= 0


def metric(text: str, prefix: str) -> float:
    values = [float(line.rsplit(" ", 1)[1]) for line in text.splitlines()
              if line.startswith(prefix)]
    assert values, f"no sample {prefix}"
    return sum(values)


def test_metrics_count_requests_by_route_template_and_status(api):
    before = api.get("/metrics").text
    for job_id in ("a", "b", "c"):
        api.get(f"/v1/plans/{job_id}")
    text = api.get("/metrics").text
    assert text.startswith("# HELP")
    sample = 'undertow_http_requests_total{method="GET",route="/v1/plans/{job_id}",status="404"}'
    old = metric(before, sample) if sample in before else 0.0
    assert metric(text, sample) == old + 3
    assert metric(text, 'undertow_http_request_duration_seconds_count{method="GET",'
                        'route="/v1/plans/{job_id}"}') >= 3
    assert 'undertow_jobs{state="queued"} 0.0' in text


def test_metrics_name_the_api_description_by_its_path(api):
    for path in ("/openapi.json", "/docs", "/nowhere"):
        api.get(path)
    text = api.get("/metrics").text
    for route, status in (("/openapi.json", 200), ("/docs", 200), ("unmatched", 404)):
        assert metric(text, f'undertow_http_requests_total{{method="GET",route="{route}",'
                            f'status="{status}"}}') >= 1


def test_settings_come_from_undertow_environment_variables(monkeypatch):
    from pydantic import ValidationError

    from app.settings import Settings

    monkeypatch.setenv("UNDERTOW_WORKERS", "3")
    monkeypatch.setenv("UNDERTOW_API_KEY", "k")
    monkeypatch.setenv("UNDERTOW_MAX_HORIZON", "12.5")
    settings = Settings()
    assert (settings.workers, settings.api_key, settings.max_horizon) == (3, "k", 12.5)
    monkeypatch.setenv("UNDERTOW_MAX_LINKS", "9")
    with pytest.raises(ValidationError, match="max_links"):
        Settings()


def test_the_removed_queue_setting_stops_the_start_instead_of_being_ignored(monkeypatch):
    from app.settings import get_settings

    get_settings.cache_clear()
    monkeypatch.setenv("UNDERTOW_QUEUE", "own")
    with pytest.raises(ValueError, match=r"UNDERTOW_QUEUE is set but no longer read: .* "
                                         "always queued by procrastinate"):
        get_settings()


def test_the_default_store_lives_in_an_ignored_data_directory():
    import subprocess

    from service_fixtures import ROOT

    from app.settings import Settings

    path = Settings().db_path
    assert path == "var/undertow-jobs.sqlite3"
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    for name in (path, path + "-wal", path + "-shm"):
        ignored = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "-q", name])
        assert ignored.returncode == 0, f"{name} is not ignored by git"


def test_the_connection_pools_warnings_are_json_lines_too(capsys):
    from app.logging import configure

    configure("INFO")
    logging.getLogger("psycopg.pool").warning("error connecting in 'undertow-jobs': refused")
    logging.getLogger("psycopg.pool").info("not logged: below WARNING")
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    line = json.loads(lines[0])
    assert (line["logger"], line["level"]) == ("psycopg.pool", "WARNING")
    assert line["message"] == "error connecting in 'undertow-jobs': refused"
