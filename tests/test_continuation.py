"""The planner's rescue of hard underactuated tasks: the continuation from relaxed dynamics,
a first start stopped when it stalls, a refinement that leaves a mesh artefact, and the
companion process that solves the continuation beside the plan's own starts."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import wait_until

from app.settings import Settings
from planner.dynamics import Dynamics
from planner.examples import seed_arm
from planner.ocp import continuation, plan, portfolio
from planner.ocp.attempt import artefact
from planner.ocp.instance import initial_point, instance
from planner.ocp.mesh import Mesh
from planner.ocp.monitor import STALL_FLOOR, STALL_WINDOW, IterationMonitor
from planner.ocp.outcome import interpolant
from planner.ocp.solve import Budget, solve
from planner.scene import Scene
from testbed.suites.ordinary import singular_configuration


@pytest.fixture(scope="module")
def crossing() -> Scene:
    """The seed's 4-link arm, g = 0, moving by up to 0.6 rad per joint either side of a
    configuration where its waveless M_pa is singular: from the interpolation Ipopt's steps
    stay at a thousandth of a Newton step, with a dozen line-search trials each. No torque
    limit: with one a stalled first start goes to the duration probe (see below)."""
    rng = np.random.default_rng(1)
    robot = seed_arm(True)
    centre = singular_configuration(robot, rng)
    assert centre is not None
    move = rng.uniform(-1.2, 1.2, 4)
    rest = [0.0] * 4
    return Scene.model_validate({"robot": robot.model_dump(mode="json"), "task": {
        "duration": 2.0, "initial": {"q": (centre - move / 2).round(6).tolist(), "dq": rest},
        "final": {"q": (centre + move / 2).round(6).tolist(), "dq": rest},
        "objective": {"effort": 1.0}}})


def _children() -> list[int]:
    """Live child processes of this process (from /proc)."""
    me, out = os.getpid(), []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == me and fields[0] != "Z":
                out.append(int(entry.name))
    return out


def test_the_relaxed_guess_satisfies_every_row_of_the_dynamics(crossing: Scene):
    robot = crossing.robot
    x = np.linspace(0.0, 1.0, 7)
    guess = continuation.relaxed_guess(crossing, robot, 2.0)(x)
    dyn = Dynamics(robot)
    order = [*robot.active, *robot.passive]
    for q, dq, ddq, tau in zip(guess["q"], guess["dq"], guess["ddq"], guess["tau"], strict=True):
        forces = dyn.mass_matrix(q) @ ddq + dyn.bias(q, dq)
        np.testing.assert_allclose(tau, forces[order], atol=1e-9)
    assert guess["tau"].shape == (7, robot.n)


def test_the_continuation_verifies_a_crossing_the_direct_start_stalls_on(crossing: Scene):
    result = plan(crossing)
    strategies = [p.strategy for p in result.mesh_passes]
    assert result.solver.success and result.verification.verified
    assert result.mesh_passes[0].status == "Stalled"
    assert result.mesh_passes[0].iterations == STALL_WINDOW
    assert result.solver.strategy.startswith("continuation")
    relaxed = [p for p in result.mesh_passes if "relaxed" in p.strategy]
    assert [p.strategy for p in relaxed] == [
        f"continuation: relaxed, virtual weight {w:g}"
        for w in continuation.VIRTUAL_WEIGHTS[:len(relaxed)]]
    # the last relaxed plan is next to an optimum of the task's own NLP: its first solve
    # from there takes a handful of iterations and changes the objective by under 1 %
    first_real = strategies.index("continuation")
    assert result.mesh_passes[first_real].iterations <= 10
    assert result.mesh_passes[first_real].objective == pytest.approx(
        relaxed[-1].objective, rel=0.01)
    assert result.solver.iterations <= 400


def test_a_limited_crossing_that_stalls_is_probed_through_the_continuation(
        crossing: Scene, monkeypatch: pytest.MonkeyPatch):
    """With a torque limit the stalled first start is followed by the duration probe, whose
    motion without limits is the continuation's; the plan it starts keeps the limit."""
    monkeypatch.setenv(portfolio.ENVIRONMENT, "1")
    # a budget long enough that the first start's share of it (shortest.FIRST_SHARE) ends
    # by its stall (an iteration count) on a loaded machine too, not by the clock
    limited = crossing.model_copy(update={
        "task": crossing.task.model_copy(update={"torque_limit": 20.0}),
        "solver": crossing.solver.model_copy(update={"max_wall_time": 600.0})})
    result = plan(limited)
    assert result.solver.success and result.verification.verified
    assert result.solver.strategy == "shortest-duration plan"
    unlimited = [p.strategy for p in result.mesh_passes
                 if p.strategy.startswith("shortest-duration probe, the task without")]
    assert unlimited and all("continuation" in s for s in unlimited)
    assert result.verification.torque_excess <= 1e-6 * 20.0


def _monitor(violations: list[float]) -> IterationMonitor:
    monitor = IterationMonitor.__new__(IterationMonitor)  # no solver needed for the rule
    monitor.violations = violations
    return monitor


def test_a_solve_stalls_when_its_violation_stays_put_over_the_window():
    flat = [0.3] * (STALL_WINDOW + 1)
    assert _monitor(flat).stalled()
    assert not _monitor(flat[:-1]).stalled()  # not before a whole window has passed
    halving = [0.3] * STALL_WINDOW + [0.3, 0.14]
    assert not _monitor(halving).stalled()
    feasible = [10 * STALL_FLOOR] + [STALL_FLOOR / 2] * (STALL_WINDOW + 1)
    assert not _monitor(feasible).stalled()


def _outcome(objective: float, error: float, success: bool = True) -> SimpleNamespace:
    return SimpleNamespace(solution=SimpleNamespace(objective=objective, success=success),
                           errors=np.array([error / 2, error]))


def test_a_refinement_whose_objective_grows_without_gaining_accuracy_left_an_artefact():
    assert artefact(_outcome(723.0, 0.075), _outcome(2848.0, 0.11))
    assert not artefact(_outcome(723.0, 0.075), _outcome(1200.0, 0.01))  # more accurate
    assert not artefact(_outcome(1.12, 0.02), _outcome(1.13, 0.02))  # the same optimum
    assert not artefact(_outcome(723.0, 0.075, success=False), _outcome(2848.0, 0.11))


def test_a_companion_solves_the_continuation_and_is_gone_when_the_plan_returns(
        crossing: Scene, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(portfolio.ENVIRONMENT, "2")
    before = set(_children())  # e.g. multiprocessing's resource tracker, started by others
    result = plan(crossing)
    assert result.solver.success and result.verification.verified
    strategies = {p.strategy.split(":")[0] for p in result.mesh_passes}
    assert "continuation" in strategies and "direct" in strategies
    assert result.solver.iterations == sum(p.iterations for p in result.mesh_passes)
    wait_until(lambda: set(_children()) <= before, 10.0)  # a thread reaps the companion


def test_a_cancelled_plan_ends_cancelled_whatever_its_companion_found(
        crossing: Scene, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(portfolio.ENVIRONMENT, "2")
    before = set(_children())
    result = plan(crossing, progress=lambda p: p.iteration < 5)
    assert result.solver.status == "User_Requested_Stop" and not result.solver.success
    wait_until(lambda: set(_children()) <= before, 10.0)  # a thread reaps the companion


def test_a_companion_stops_once_the_process_that_forked_it_is_gone(
        monkeypatch: pytest.MonkeyPatch):
    guard = portfolio.orphan_guard()
    assert guard(None) is True  # type: ignore[arg-type]
    monkeypatch.setattr(os, "getppid", lambda: 1)
    assert guard(None) is False  # type: ignore[arg-type]


def _state(pid: int) -> str:
    """The process's state letter (R, S, T, Z, ...), "gone" when it has none."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return "gone"


def _paused(companion: portfolio.Companion) -> None:
    """Defer the companion until it is paused: right after the fork it may not yet have
    said that it dies with this process (then it only runs at the lowest priority)."""
    wait_until(lambda: companion.defer() or companion.paused, 10.0)


def test_a_deferred_companion_is_paused_until_it_is_waited_for(
        monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(portfolio, "PAUSE", 60.0)
    companion = portfolio.Companion(lambda guard: time.sleep(30))
    try:
        _paused(companion)
        assert portfolio.PAUSABLE
        wait_until(lambda: _state(companion.pid) == "T", 10.0)  # once the signal lands
        companion.wait(time.perf_counter() + 0.1)
        wait_until(lambda: _state(companion.pid) in {"S", "R"}, 10.0)
    finally:
        companion.stop()


def test_a_deferred_companion_goes_on_by_itself_after_its_pause(
        monkeypatch: pytest.MonkeyPatch):
    """Checks that take long (a hard plan's) leave the companion to go on beside them, at
    the lowest priority."""
    monkeypatch.setattr(portfolio, "PAUSE", 0.3)
    companion = portfolio.Companion(lambda guard: time.sleep(30))
    try:
        _paused(companion)
        wait_until(lambda: not companion.paused and _state(companion.pid) in {"S", "R"}, 10.0)
        assert os.getpriority(os.PRIO_PROCESS, companion.pid) == portfolio.LOWEST
    finally:
        companion.stop()


def test_a_paused_companion_dies_with_the_process_that_forked_it(
        monkeypatch: pytest.MonkeyPatch):
    """kill -9 of a plan's process while its companion is paused leaves no companion
    behind, stopped for ever."""
    monkeypatch.setattr(portfolio, "PAUSE", 60.0)
    read, write = os.pipe()
    middle = os.fork()
    if middle == 0:  # the plan's process
        try:
            companion = portfolio.Companion(lambda guard: time.sleep(60))
            _paused(companion)
            os.write(write, str(companion.pid).encode())
            time.sleep(60)
        finally:
            os._exit(0)
    pid = int(os.read(read, 32))
    wait_until(lambda: _state(pid) == "T", 10.0)
    os.kill(middle, signal.SIGKILL)
    os.waitpid(middle, 0)
    wait_until(lambda: _state(pid) in {"gone", "Z"}, 10.0)


def test_a_companion_that_cannot_be_paused_runs_at_the_lowest_priority(
        monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(portfolio, "PAUSABLE", False)
    companion = portfolio.Companion(lambda guard: time.sleep(30))
    try:
        companion.defer()
        assert os.getpriority(os.PRIO_PROCESS, companion.pid) == portfolio.LOWEST
        assert _state(companion.pid) != "T"
    finally:
        companion.stop()


def test_a_stopped_companion_is_reaped_by_a_thread_not_by_the_plan(
        monkeypatch: pytest.MonkeyPatch):
    companion = portfolio.Companion(lambda guard: time.sleep(30))
    reapers = []
    waitpid = os.waitpid

    def recording(pid: int, options: int) -> tuple[int, int]:
        reapers.append(threading.current_thread())
        return waitpid(pid, options)

    monkeypatch.setattr(os, "waitpid", recording)
    companion.stop()
    wait_until(lambda: not Path(f"/proc/{companion.pid}").exists(), 10.0)  # no zombie
    assert reapers and threading.main_thread() not in reapers


def test_a_companion_gets_its_priority_back_before_it_is_killed(
        monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(portfolio, "PAUSABLE", False)
    companion = portfolio.Companion(lambda guard: time.sleep(30))
    companion.defer()
    at_kill = []
    kill = os.kill

    def recording(pid: int, sig: int) -> None:
        at_kill.append(os.getpriority(os.PRIO_PROCESS, pid))
        kill(pid, sig)

    monkeypatch.setattr(os, "kill", recording)
    companion.stop()
    assert at_kill == [os.getpriority(os.PRIO_PROCESS, 0)]


def test_a_service_plan_may_use_every_core_unless_told(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda _: set(range(8)))
    monkeypatch.delenv(portfolio.ENVIRONMENT)
    assert Settings(workers=2).plan_processes() == 8  # the core tokens share them
    assert Settings(solver_processes=1).plan_processes() == 1


def test_the_relaxed_nlps_virtual_torques_are_the_passive_joints_generalised_forces(
        crossing: Scene):
    # solved, the relaxed NLP's torque rows after the active ones hold what the passive
    # rows of M ddq + h ask for at the collocation points, computed here independently
    robot, T = crossing.robot, 2.0
    inst = instance(crossing, robot, Mesh.uniform(10), T, continuation.VIRTUAL_WEIGHTS[0])
    x0 = initial_point(inst, continuation.relaxed_guess(crossing, robot, T), T, robot)
    solution = solve(inst, x0, Budget.of(200, 60.0), None, 0)
    assert solution.success
    interp = interpolant(inst, robot, T, solution.x)
    points = np.asarray(inst.problem.transcription.knot_positions)
    t = (inst.mesh.breaks[:-1, None] * T + np.diff(inst.mesh.breaks)[:, None] * T * points).ravel()
    dyn = Dynamics(robot)
    q, dq, ddq, tau = interp.q(t), interp.dq(t), interp.dq(t, derivative=1), interp.tau(t)
    na = len(robot.active)
    assert np.abs(tau[:, na:]).max() > 1e-2  # the virtual torques are at work
    for k in range(len(t)):
        forces = dyn.mass_matrix(q[k]) @ ddq[k] + dyn.bias(q[k], dq[k])
        np.testing.assert_allclose(tau[k, na:], forces[robot.passive], atol=1e-6)
        np.testing.assert_allclose(tau[k, :na], forces[robot.active], atol=1e-6)
