"""solver.jit: the first plans of a structure run interpreted while its kernels are compiled
in the background; later plans run compiled and agree with the interpreted ones."""

from __future__ import annotations

import numpy as np
import pytest

from planner import compiled, prebuild
from planner.ocp import plan
from planner.scene import Scene

TWO_LINK = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.02, "joint": "passive"},
                      {"length": 0.4, "mass": 0.7, "inertia": 0.01, "joint": "active"}],
            "gravity": 9.81}


def _scene(goal: float) -> Scene:
    return Scene.model_validate({
        "robot": TWO_LINK,
        "task": {"duration": 1.2, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                 "final": {"q": [goal, 0.4], "dq": [0.0, 0.0]},
                 "objective": {"effort": 1.0}},
        "transcription": {"method": "trapezoidal", "intervals": 12},
        "solver": {"jit": True, "retries": 0}})


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("UNDERTOW_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("UNDERTOW_BUILDS", "background")
    return tmp_path


def test_a_new_structure_plans_at_once_and_compiles_in_the_background(cache):
    first = plan(_scene(0.3))
    assert first.solver.success and not first.solver.compiled
    assert compiled.building()  # the stages' kernels, the flow and the linearisation's
    # Jacobians, each in a process of its own
    compiled.wait(300)
    assert not compiled.building()
    assert sorted(p.name.split("_")[0] for p in cache.glob("*.so")) == ["flow", "jacobians",
                                                                      "stages"]
    assert not [p for p in cache.iterdir() if p.is_dir()]  # the build folders are gone

    again = plan(_scene(0.3))
    assert again.solver.compiled
    assert again.objective == pytest.approx(first.objective, rel=1e-9)
    assert np.allclose(again.tau, first.tau, atol=1e-9)
    assert again.verification.local_error == pytest.approx(first.verification.local_error,
                                                           rel=1e-6, abs=1e-12)


def test_plans_are_compiled_by_default_and_interpreted_while_builds_are_off(cache,
                                                                            monkeypatch):
    scene = Scene.model_validate({**_scene(0.3).model_dump(exclude_unset=True),
                                  "solver": {"retries": 0}})
    assert scene.solver.jit
    monkeypatch.setenv("UNDERTOW_BUILDS", "off")
    off = plan(scene)
    assert off.solver.success and not off.solver.compiled and not compiled.building()
    assert not list(cache.glob("*.so"))


def test_an_unwritable_cache_leaves_plans_interpreted(tmp_path, monkeypatch):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    monkeypatch.setenv("UNDERTOW_CACHE_DIR", str(blocked / "kernels"))
    monkeypatch.setenv("UNDERTOW_BUILDS", "background")
    result = plan(_scene(0.31))
    assert result.solver.success and not result.solver.compiled and not compiled.building()


def test_the_examples_libraries_are_built_ahead(cache, monkeypatch):
    """One small example stands for the built-in ones (each build takes gcc a while)."""
    data = _scene(0.32).model_dump(exclude_unset=True)
    example = Scene.model_validate({**data, "robot": {**data["robot"], "gravity": 0.0}})
    monkeypatch.setattr(prebuild, "examples", lambda: [_Example(example)])
    built = prebuild.build()
    assert not compiled.building()
    names = {p.stem for p in cache.glob("*.so")}
    assert {name.split("_")[0] for name in names} == {"flow", "jacobians", "stages"}
    assert names <= set(built)
    assert prebuild.scenes()[0].solver.max_iter == 1
    assert plan(example).solver.compiled


class _Example:
    kind = "plan"

    def __init__(self, scene: Scene):
        self.request = scene.model_dump(exclude_unset=True)


def test_background_builds_of_one_folder_run_one_at_a_time(cache):
    """While another build holds the folder's lock, a background build waits for it; once
    the lock is released it builds. (Without the lock every structure a service meets at
    once would start a compiler of its own.)"""
    import fcntl
    import time

    import casadi as ca

    x = ca.SX.sym("x")
    functions = [ca.Function("waiting_f", [x], [ca.sin(x) * x])]
    with open(cache / compiled.BUILD_LOCK, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        assert compiled.library("waiting", functions, background=True) is None
        time.sleep(3.0)  # far longer than this library takes gcc when it may build
        assert compiled.building() and not (cache / "waiting.so").exists()
        assert compiled.wait(0.5) == ["waiting"]  # a wait that runs out names what builds
    compiled.wait(120)
    loaded = compiled.library("waiting", functions)
    assert loaded is not None and float(loaded["waiting_f"](2.0)) == pytest.approx(2 * np.sin(2))


def _builder_processes() -> int:
    """This process's children that run `python -m planner.compiled`."""
    import os

    from testbed.worker_watch import children

    return sum("planner.compiled" in command for command in children(os.getpid()).values())


def test_a_process_runs_one_builder_at_a_time(cache):
    """Structures met at once are built by one builder process, one after the other, not
    by a Python process each waiting on the folder's lock."""
    import fcntl
    import time

    import casadi as ca

    x = ca.SX.sym("x")
    libraries = {f"queued{k}": [ca.Function(f"queued{k}_f", [x], [ca.sin(x) * x + k])]
                 for k in range(3)}
    with open(cache / compiled.BUILD_LOCK, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for name, functions in libraries.items():
            assert compiled.library(name, functions, background=True) is None
        time.sleep(1.0)
        assert _builder_processes() == 1 and set(libraries) <= set(compiled.building())
    assert compiled.wait(120) == []
    for k, (name, functions) in enumerate(libraries.items()):
        loaded = compiled.library(name, functions)
        assert loaded is not None
        assert float(loaded[f"{name}_f"](2.0)) == pytest.approx(2 * np.sin(2) + k)


def test_a_forked_child_asks_the_builder_of_its_parent(cache):
    """A plan's companion is a forked child: what it asks for is built by the builder of
    the process it was forked from, and it starts none of its own (each would outlive its
    companion while it waited its turn: one more process for every plan)."""
    import os
    import time

    import casadi as ca

    x = ca.SX.sym("x")
    assert compiled.library("parent", [ca.Function("parent_f", [x], [x + 1])],
                            background=True) is None
    pid = os.fork()
    if pid == 0:  # the child: ask, and say whether it started a builder of its own
        try:
            compiled.library("child", [ca.Function("child_f", [x], [x + 2])], background=True)
            time.sleep(1.0)
            os._exit(3 if _builder_processes() else 0)
        finally:
            os._exit(1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert compiled.wait(120) == []  # the child's build too, asked before the wait
    assert (cache / "child.so").exists(), sorted(p.name for p in cache.iterdir())
    assert _builder_processes() == 1
    loaded = compiled.library("child", [ca.Function("child_f", [x], [x + 2])])
    assert loaded is not None and float(loaded["child_f"](2.0)) == 4.0


def test_asking_never_waits_for_a_builder_that_does_not_read(cache):
    """A plan asks for libraries while its builder is busy; were the requests written
    waiting, a builder that does not read (here stopped) would hold the plan once its pipe
    is full. A request that finds the pipe full is asked again at a later call."""
    import os
    import signal
    import threading

    import casadi as ca

    x = ca.SX.sym("x")
    assert compiled.library("first", [ca.Function("first_f", [x], [x])], background=True) is None
    builder = compiled._BUILDER
    assert isinstance(builder, compiled._Builder)
    os.kill(builder.process.pid, signal.SIGSTOP)
    try:
        asked = threading.Thread(target=lambda: [
            compiled.library(f"many{k}", [ca.Function(f"many{k}_f", [x], [x + k])],
                             background=True) for k in range(600)], daemon=True)
        asked.start()
        asked.join(120)  # written waiting, the calls stop at the full pipe for good
        assert not asked.is_alive()
        unasked = 600 - sum(f"many{k}" in compiled.started() for k in range(600))
        assert unasked > 0  # the pipe was full: those were not recorded as asked
    finally:
        os.kill(builder.process.pid, signal.SIGKILL)


def test_the_builder_finishes_what_it_was_asked_after_the_process_has_gone(cache):
    """A command-line plan exits at once; the libraries its plan asked for are built all
    the same, for the next one."""
    import subprocess
    import sys
    import time

    script = ("import casadi as ca\n"
              "from planner import compiled\n"
              "x = ca.SX.sym('x')\n"
              "for k in range(2):\n"
              "    compiled.library(f'left{k}', [ca.Function(f'left{k}_f', [x], [x + k])],\n"
              "                     background=True)\n")
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)
    deadline = time.monotonic() + 120
    while not all((cache / f"left{k}.so").exists() for k in range(2)):
        assert time.monotonic() < deadline, sorted(p.name for p in cache.iterdir())
        time.sleep(0.2)


def test_stages_compiled_earlier_load_without_symbolic_work(cache, monkeypatch):
    """A structure whose kernels another process compiled loads them and their layout from
    the cache folder: no stage function is built, and every kernel, sparsity and row bound
    is the symbolic stages' own."""
    from planner.ocp import stages as stages_module
    from planner.ocp.problem import ProblemKey

    scene = Scene.model_validate({**_scene(0.33).model_dump(exclude_unset=True),
                                  "transcription": {"method": "legendre", "intervals": 8}})
    key = ProblemKey.of(scene).stage_key()
    plain = stages_module.stages(key)
    assert stages_module.compiled_kernels(key, plain, wait=True) is not None
    stages_module.stages.cache_clear()

    def built(*args):
        raise AssertionError("a stage function was built")

    monkeypatch.setattr(stages_module, "stage_function", built)
    assert stages_module.compiled_ready(key, wait=False)
    found = stages_module.stages(key, True)
    assert found.kernels is None and found.link == plain.link
    assert (found.bounds, found.kinds) == (plain.bounds, plain.kinds)
    rng = np.random.default_rng(7)
    for mine, theirs in ((found.derivatives.stage, plain.derivatives.stage),
                         (found.derivatives.terminal, plain.derivatives.terminal)):
        assert mine.jac_sp == theirs.jac_sp and mine.hess_sp == theirs.hess_sp
        assert np.array_equal(mine.grad_rows, theirs.grad_rows)
        args = [rng.uniform(0.1, 1.0, theirs.hess.sparsity_in(k).shape)
                for k in range(theirs.hess.n_in())]
        for f in ("rows", "cost", "jac", "grad"):
            ours, reference = getattr(mine, f), getattr(theirs, f)
            assert np.allclose(np.array(ours(*args[:ours.n_in()])),
                               np.array(reference(*args[:reference.n_in()])), rtol=1e-12)
        assert np.allclose(np.array(mine.hess(*args)), np.array(theirs.hess(*args)), rtol=1e-12)
    stages_module.stages.cache_clear()


def test_a_wait_waits_for_what_forked_children_asked_for(cache):
    """A plan's companion asks its parent's builder; the parent's wait waits for those
    builds too (a barrier the builder answers after every earlier request), so that a
    bench that plans a task and waits times the next plan on every kernel it met."""
    import fcntl
    import os

    import casadi as ca

    x = ca.SX.sym("x")
    assert compiled.library("first", [ca.Function("first_f", [x], [x])], background=True) is None
    assert compiled.wait(120) == []
    with open(cache / compiled.BUILD_LOCK, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the child's build waits for its release
        pid = os.fork()
        if pid == 0:
            try:
                compiled.library("later", [ca.Function("later_f", [x], [x * 5])],
                                 background=True)
                os._exit(0)
            finally:
                os._exit(1)
        os.waitpid(pid, 0)
        compiled.wait(1.0)  # runs out: the build waits for the lock
        assert not (cache / "later.so").exists()
    assert compiled.wait(120) == []
    assert (cache / "later.so").exists()
