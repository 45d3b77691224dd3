"""A Python client generated from openapi/openapi.json (openapi-python-client) lists the
examples, plans the first plan example (a two-link scene while there is none) and fetches
its figures against a live server, with the API key; the generated code is used as
generated, and needs only the packages docs/api.md names (httpx, attrs)."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from service_fixtures import ROOT
from test_e2e_server import QUICK

from testbed.service import LiveServer

pytest.importorskip("openapi_python_client", reason="openapi-python-client is a test dependency")

KEY = "client-key"


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The generated package `undertow_client`, importable."""
    out = tmp_path_factory.mktemp("client")
    config = out / "config.yml"
    config.write_text("post_hooks: []\n")
    subprocess.run([sys.executable, "-m", "openapi_python_client", "generate",
                    "--path", str(ROOT / "openapi" / "openapi.json"), "--meta", "none",
                    "--output-path", str(out / "undertow_client"), "--config", str(config)],
                   cwd=out, check=True, capture_output=True, text=True, timeout=120)
    sys.path.insert(0, str(out))
    try:
        yield importlib.import_module("undertow_client")
    finally:
        sys.path.remove(str(out))


def test_the_generated_client_plans_an_example(generated, tmp_path):
    from undertow_client.api.examples import list_examples
    from undertow_client.api.plans import create_plan, get_plan, plan_plot_png, plan_plot_svg
    from undertow_client.models import Job, Problem, Scene
    from undertow_client.types import File

    with LiveServer(tmp_path / "jobs.sqlite3", UNDERTOW_API_KEY=KEY) as live:
        client = generated.AuthenticatedClient(base_url=live.url, token=KEY, prefix="",
                                               auth_header_name="X-API-Key", timeout=60)
        anonymous = generated.Client(base_url=live.url, timeout=60)
        with client, anonymous:
            listed = list_examples.sync(client=client)
            assert listed, "the client lists the examples"
            plans = [e.request.to_dict() for e in listed if e.kind == "plan"]
            scene = Scene.from_dict(plans[0] if plans else QUICK)
            refused = create_plan.sync_detailed(client=anonymous, body=scene)
            assert refused.status_code == 401 and isinstance(refused.parsed, Problem)
            job = create_plan.sync(client=client, body=scene, wait=30.0)
            deadline = time.monotonic() + 300
            while job.status in ("queued", "running") and time.monotonic() < deadline:
                time.sleep(0.5)
                job = get_plan.sync(client=client, job_id=job.id)
            assert isinstance(job, Job), job
            assert job.status == "succeeded" and job.plan.solver.success
            again = get_plan.sync(client=client, job_id=job.id)
            png = plan_plot_png.sync(client=client, job_id=job.id)
            svg = plan_plot_svg.sync(client=client, job_id=job.id)
            missing = plan_plot_png.sync(client=client, job_id="nope")
    assert isinstance(png, File) and png.payload.read().startswith(b"\x89PNG\r\n\x1a\n")
    assert isinstance(svg, File) and b"<svg" in svg.payload.read()
    assert isinstance(missing, Problem) and missing.status == 404
    assert again.plan.to_dict() == job.plan.to_dict()
    assert again.plan.q[0] == scene.task.initial.q


def _generate(tmp_path, *options: str) -> subprocess.CompletedProcess:
    """The generator as docs/api.md "Clients" runs it, in `tmp_path`, with no ruff in PATH."""
    path = os.pathsep.join(d for d in os.environ.get("PATH", "").split(os.pathsep)
                           if d and not (Path(d) / "ruff").exists())
    return subprocess.run([sys.executable, "-m", "openapi_python_client", "generate",
                           "--path", str(ROOT / "openapi" / "openapi.json"), "--meta", "none",
                           "--output-path", "undertow_client", *options],
                          cwd=tmp_path, env={**os.environ, "PATH": path}, capture_output=True,
                          text=True, timeout=120)


def test_without_ruff_the_generator_warns_as_docs_api_md_says_and_writes_the_client(tmp_path):
    docs = " ".join((ROOT / "docs" / "api.md").read_text().split())
    (tmp_path / "warned").mkdir()
    warned = _generate(tmp_path / "warned")
    output = warned.stdout + warned.stderr
    assert warned.returncode == 0
    assert (tmp_path / "warned" / "undertow_client" / "client.py").exists()
    for said in ("Warning(s) encountered while generating. Client was generated, but some "
                 "pieces may be missing", "Skipping Integration", "ruff is not in PATH"):
        assert said in " ".join(output.split()) and f'"{said}"' in docs
    (tmp_path / "quiet").mkdir()
    (tmp_path / "quiet" / "hooks.json").write_text('{"post_hooks": []}')
    assert '`{"post_hooks": []}`' in docs
    quiet = _generate(tmp_path / "quiet", "--config", "hooks.json")
    assert quiet.returncode == 0 and "Warning" not in quiet.stdout + quiet.stderr
