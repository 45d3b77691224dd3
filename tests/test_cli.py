"""The `undertow` command: its outputs, progress, exit codes and error messages."""

from __future__ import annotations

import ast
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import get_args

import httpx
import numpy as np
import pytest
from service_fixtures import ROOT
from test_plots import CROSSING_SCENE

from planner import cli, inverse
from planner.errors import InputError
from planner.examples import Kind, example, examples
from planner.inverse import InverseDynamicsResult
from planner.ocp import Plan, plan
from planner.ocp.result import Progress
from planner.scene import Scene
from planner.waves import WaveDesignResult
from testbed.service import free_port

UNDERTOW = Path(sys.executable).with_name("undertow")
PNG = b"\x89PNG\r\n\x1a\n"


def write_json(path: Path, data) -> str:
    path.write_text(json.dumps(data))
    return str(path)


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_the_installed_command_documents_its_exit_codes():
    r = subprocess.run([str(UNDERTOW), "--help"], capture_output=True, text=True, timeout=60,
                       check=False)
    assert r.returncode == 0
    for code in ("0    success", "1    the computation ran", "2    bad input", "3    I/O error",
                 "130  interrupted"):
        assert code in r.stdout
    for command in ("serve", "examples", "plan", "design-wave", "inverse"):
        assert command in r.stdout


# --------------------------------------------------------------------------- examples


def test_examples_lists_every_example_and_filters_by_kind(capsys):
    assert set(cli._COMMANDS) == set(get_args(Kind))  # --kind offers every kind
    code, out, _ = run(capsys, "examples")
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()] == [e.name for e in examples()]
    code, out, _ = run(capsys, "examples", "--kind", "coupling")
    names = [line.split()[0] for line in out.splitlines()]
    assert code == 0 and names == [e.name for e in examples() if e.kind == "coupling"] != []


def test_examples_writes_a_request_body(capsys, tmp_path):
    target = tmp_path / "request.json"
    code, out, err = run(capsys, "examples", "--name", "two-link-waves", "-o", str(target))
    assert code == 0 and out == ""
    assert json.loads(target.read_text()) == example("two-link-waves").request
    assert f"undertow inverse {target} -o OUT.json" in err
    code, out, _ = run(capsys, "examples", "--name", "two-link-waves")
    assert code == 0 and json.loads(out) == example("two-link-waves").request


def test_an_unknown_example_is_bad_input_naming_the_known_ones(capsys):
    code, out, err = run(capsys, "examples", "--name", "nope")
    assert code == cli.BAD_INPUT and out == ""
    assert err.startswith("undertow examples: --name: no example called 'nope'; known: ")
    assert "two-link-waves" in err
    code, _, err = run(capsys, "examples", "--kind", "coupling", "--name", "two-link-waves")
    assert code == 2 and "'two-link-waves' is of kind 'inverse-dynamics', not 'coupling'" in err


# --------------------------------------------------------------------------- plan


def test_plan_writes_the_library_plan_a_figure_and_a_progress_line_per_iteration(
        capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "PROGRESS_PERIOD", 0.0)
    scene = write_json(tmp_path / "s.json", CROSSING_SCENE)
    out, figure = tmp_path / "p.json", tmp_path / "p.png"
    code, stdout, err = run(capsys, "plan", scene, "-o", str(out), "--plot", str(figure))
    assert code == 0 and stdout == ""
    written = Plan.model_validate_json(out.read_text())
    reference = plan(Scene.model_validate(CROSSING_SCENE))
    assert written.solver.success
    assert written.objective == pytest.approx(reference.objective, rel=1e-9)
    assert np.allclose(written.q, reference.q, rtol=0.0, atol=1e-9)
    assert figure.read_bytes().startswith(PNG)
    assert f"wrote the plan's figure to {figure}" in err.splitlines()
    iterations = [int(line.split("iteration")[1].split()[0])
                  for line in err.splitlines() if line.startswith("[mesh pass")]
    # every iteration of every solve is reported, counted as Ipopt counts them
    assert iterations[0] == 0 and iterations[-1] == written.solver.iterations
    assert np.all(np.diff(iterations) >= 0)
    assert (f"Solve_Succeeded: optimal solution found; {written.solver.iterations} iterations "
            f"in {len(written.mesh_passes)} solve(s) ({written.solver.strategy})") in err
    crossings = len(written.verification.waveless_singular_crossings)
    assert f"{crossings} waveless singular crossing(s)" in err


def test_quiet_plan_prints_nothing_and_a_solver_failure_exits_1_with_the_plan(capsys, tmp_path):
    failing = {**CROSSING_SCENE, "solver": {"max_iter": 3}}
    out = tmp_path / "plan.json"
    code, stdout, err = run(capsys, "plan", write_json(tmp_path / "s.json", failing),
                            "-o", str(out), "--quiet")
    assert code == cli.FAILED and stdout == "" and err == ""
    written = Plan.model_validate_json(out.read_text())
    assert written.solver.status == "Maximum_Iterations_Exceeded" and not written.solver.success


def test_an_optimal_plan_that_fails_its_resimulation_check_exits_1_and_says_why(capsys, tmp_path):
    strict = {**CROSSING_SCENE, "solver": {"resimulation_tolerance": 1e-9, "retries": 0},
              "transcription": {**CROSSING_SCENE["transcription"],
                                "refinement": {"max_passes": 1}}}
    out = tmp_path / "plan.json"
    code, _, err = run(capsys, "plan", write_json(tmp_path / "s.json", strict), "-o", str(out))
    written = Plan.model_validate_json(out.read_text())
    v = written.verification
    assert code == cli.FAILED and written.solver.success and v.verified is False
    assert len(written.mesh_passes) == 2
    assert (f"unverified: re-integrated interval by interval, the delivered torque departs "
            f"from the plan by {v.local_error:.3g} rad (tolerance 1e-09 rad)") in err


def test_plan_to_stdout(capsys, tmp_path):
    code, stdout, _ = run(capsys, "plan", write_json(tmp_path / "s.json", CROSSING_SCENE),
                          "-o", "-", "-q")
    assert code == 0 and Plan.model_validate_json(stdout).solver.success


def test_invalid_fields_are_each_named(capsys, tmp_path):
    bad = json.loads(json.dumps(CROSSING_SCENE))
    bad["robot"]["links"][1]["wave"]["amplitude"] = 0.5
    bad["transcription"]["intervals"] = 0
    path = write_json(tmp_path / "bad.json", bad)
    code, _, err = run(capsys, "plan", path, "-o", str(tmp_path / "p.json"))
    assert code == cli.BAD_INPUT and not (tmp_path / "p.json").exists()
    assert err.splitlines() == [
        f"undertow plan: {path}: 2 invalid field(s)",
        "  robot.links[1].wave.amplitude: must be smaller than the link length (0.5 >= 0.4)",
        "  transcription.intervals: Input should be greater than or equal to 1"]

    short = json.loads(json.dumps(CROSSING_SCENE))
    short["task"]["initial"]["q"] = [0.0]
    code, _, err = run(capsys, "plan", write_json(tmp_path / "short.json", short), "-o", "-")
    assert code == 2 and err.splitlines()[1] == "  task.initial.q: needs 2 entries, one per joint"


def test_unreadable_json_and_a_bad_plot_name_are_bad_input(capsys, tmp_path):
    broken = tmp_path / "broken.json"
    broken.write_text('{"robot": [1, 2,]}')
    code, _, err = run(capsys, "plan", str(broken), "-o", "-")
    assert code == 2
    assert err == f"undertow plan: {broken}: not valid JSON (line 1, column 17: Expecting value)\n"
    scene = write_json(tmp_path / "s.json", CROSSING_SCENE)
    code, _, err = run(capsys, "plan", scene, "-o", "-", "--plot", "plan.jpg")
    assert code == 2 and "plot: the file name must end in .png or .svg" in err


def test_files_that_cannot_be_read_or_written_are_io_errors(capsys, tmp_path):
    code, _, err = run(capsys, "plan", str(tmp_path / "missing.json"), "-o", "-")
    assert code == cli.IO_ERROR
    missing = tmp_path / "missing.json"
    assert err == f"undertow plan: cannot read {missing}: No such file or directory\n"
    request = write_json(tmp_path / "r.json", example("two-link-waves").request)
    target = tmp_path / "no" / "such" / "dir" / "out.json"
    code, _, err = run(capsys, "inverse", request, "-o", str(target))
    assert code == 3 and err.startswith(f"undertow inverse: cannot write {target}: ")
    assert list(tmp_path.iterdir()) == [tmp_path / "r.json"]  # nothing half-written


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["plan", "scene.json"])
    assert stop.value.code == 2
    assert "the following arguments are required: -o/--output" in capsys.readouterr().err


# --------------------------------------------------------------------------- inverse, design


def test_inverse_completes_or_stops_singular_with_exit_codes_0_and_1(capsys, tmp_path):
    out, figure = tmp_path / "out.json", tmp_path / "out.svg"
    request = write_json(tmp_path / "waves.json", example("two-link-waves").request)
    code, _, err = run(capsys, "inverse", request, "-o", str(out), "--plot", str(figure))
    assert code == 0 and err == f"wrote the figure to {figure}\ncompleted: completed\n"
    assert InverseDynamicsResult.model_validate_json(out.read_text()).status == "completed"
    assert figure.read_bytes().startswith(b"<?xml")

    request = write_json(tmp_path / "plain.json", example("two-link-waveless").request)
    code, _, err = run(capsys, "inverse", request, "-o", str(out))
    result = InverseDynamicsResult.model_validate_json(out.read_text())
    assert code == cli.FAILED and result.status == "singular"
    assert err == f"singular: {result.message}\n"


def test_what_the_library_refuses_is_bad_input_and_a_bug_is_not(capsys, tmp_path, monkeypatch):
    request = write_json(tmp_path / "r.json", example("two-link-waves").request)
    out = str(tmp_path / "out.json")

    def refuse(*args, **kwargs):
        raise InputError("samples: refused by the library")
    monkeypatch.setattr(inverse, "solve", refuse)
    assert run(capsys, "inverse", request, "-o", out) == (
        cli.BAD_INPUT, "", "undertow inverse: samples: refused by the library\n")

    def bug(*args, **kwargs):
        raise ValueError("samples: a bug, not the input's fault")
    monkeypatch.setattr(inverse, "solve", bug)
    with pytest.raises(ValueError, match="a bug"):  # a traceback, not "bad input"
        cli.main(["inverse", request, "-o", out])


def test_design_wave_certifies_the_two_link_example(capsys, tmp_path):
    out = tmp_path / "waves.json"
    request = write_json(tmp_path / "r.json", example("two-link-wave-design").request)
    code, _, err = run(capsys, "design-wave", request, "-o", str(out), "-q")
    result = WaveDesignResult.model_validate_json(out.read_text())
    assert code == 0 and err == ""
    assert result.status == "certified" and result.certified_sigma_min >= 0.02


# --------------------------------------------------------------------------- processes


def test_serve_runs_the_service_and_the_viewer(tmp_path):
    port = free_port()
    env = {**os.environ, "UNDERTOW_DB_PATH": str(tmp_path / "jobs.sqlite3"),
           "UNDERTOW_INSTANCE": "cli-test", "UNDERTOW_LOG_LEVEL": "WARNING"}
    proc = subprocess.Popen([str(UNDERTOW), "serve", "--port", str(port), "--workers", "1"],
                            env=env, cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read().decode()
            try:
                if httpx.get(base + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.1)
        page = httpx.get(base + "/")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert '<script src="viewer.js"></script>' in page.text
        assert httpx.get(base + "/viewer.js").status_code == 200
        assert httpx.get(base + "/v1/examples").json()[0]["name"] == examples()[0].name
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)


def test_the_library_knows_nothing_of_http():
    """`serve` and every URL live in app/: planner/ imports no web framework or server,
    names no endpoint, and its command line runs without the service."""
    for path in sorted((ROOT / "planner").rglob("*.py")):
        text = path.read_text()
        imported = {alias.name.split(".")[0] for node in ast.walk(ast.parse(text))
                    if isinstance(node, (ast.Import, ast.ImportFrom))
                    for alias in (node.names if isinstance(node, ast.Import)
                                  else [ast.alias(node.module or "")])}
        assert not imported & {"app", "fastapi", "starlette", "uvicorn", "httpx"}, path
        assert "/v1/" not in text, path
    assert "serve" not in cli.parser().format_help()


SLOW_SCENE = {  # the seed arm rest-to-rest across a waveless singularity: many iterations
    "robot": example("seed-arm-waves").request["robot"],
    "task": {"duration": 2.0, "initial": {"q": [0.1, 0.6, -0.7, -2.6], "dq": [0.0] * 4},
             "final": {"q": [0.3, 1.0, -0.5, -2.0], "dq": [0.0] * 4}},
    "transcription": {"method": "legendre", "intervals": 20},
    "solver": {"max_iter": 3000, "tol": 1e-12, "max_wall_time": 120},
}


def test_the_first_ctrl_c_stops_the_solve_and_still_writes_the_plan(tmp_path):
    out = tmp_path / "plan.json"
    scene = write_json(tmp_path / "s.json", SLOW_SCENE)
    proc = subprocess.Popen([str(UNDERTOW), "plan", scene, "-o", str(out)], cwd=tmp_path,
                            stderr=subprocess.PIPE, text=True)
    lines = []
    for line in proc.stderr:  # non-terminal stderr: a progress line at once, then each second
        lines.append(line)
        if line.startswith("["):
            proc.send_signal(signal.SIGINT)
            break
    rest = proc.communicate(timeout=120)[1]
    assert proc.returncode == cli.INTERRUPTED, "".join(lines) + rest
    written = Plan.model_validate_json(out.read_text())
    assert written.solver.status == "User_Requested_Stop"
    assert "stopping at the next iteration (Ctrl-C again to abort)" in rest


def test_the_progress_bar_beats_until_the_first_iteration(monkeypatch):
    monkeypatch.setattr(cli, "PROGRESS_PERIOD", 0.05)
    stream = io.StringIO()
    bar = cli.ProgressBar(stream)
    with bar.waiting("building the NLP"):
        time.sleep(0.4)
        bar(Progress(iteration=0, objective=1.0, inf_pr=0.1, inf_du=0.1, elapsed=0.0))
        time.sleep(0.3)  # no beat once an iteration has arrived
    lines = stream.getvalue().splitlines()
    beats = [line for line in lines if line.startswith("building the NLP  ")]
    assert len(beats) >= 3 and lines[len(beats)].startswith("[")
    assert lines[len(beats) + 1:] == []
    elapsed = [float(line.split()[-2]) for line in beats]
    assert elapsed == sorted(elapsed) and elapsed[0] >= 0.05
