"""Deadlines inside the library: every long computation stops part-way at its deadline and
says where, an Ipopt solve stops at its next iteration, and shared solvers are safe to
call from several threads at once."""

from __future__ import annotations

import re
import threading
import time

import casadi as ca
import numpy as np
import pytest

from planner import (
    budget,
    coupling,
    coupling_singularities,
    evaluation,
    examples,
    inverse,
    simulate,
    waves,
)
from planner.budget import BudgetExceeded
from planner.model import Robot, Structure
from planner.waves import motion_nlp, screening
from planner.waves.nlp import wave_structure
from planner.waves.region import RegionProblem

TWO_LINK = examples.example("two-link-waves").request["robot"]


def test_check_raises_only_past_the_deadline():
    budget.check(None, "x")
    budget.check(time.monotonic() + 60, "x")
    with pytest.raises(BudgetExceeded, match=r"^the thing ran past its deadline$"):
        budget.check(time.monotonic() - 1e-3, "the thing")
    assert issubclass(BudgetExceeded, ValueError)


def test_part_of_names_the_whole_computation():
    with pytest.raises(BudgetExceeded) as info, budget.part_of("the design"):
        budget.check(0.0, "the inner loop")
    assert str(info.value) == "the design: the inner loop ran past its deadline"
    with pytest.raises(BudgetExceeded) as info, budget.part_of("the design"):
        budget.check(0.0, "the design (start 2)")
    assert str(info.value) == "the design (start 2) ran past its deadline"


def _nlp_solver() -> tuple[ca.Function, dict]:
    x = ca.MX.sym("x", 50)
    nlp = {"x": x, "f": ca.sumsqr(ca.sin(x) - ca.cos(ca.cumsum(x))), "g": x[0]}
    options = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
               **budget.ipopt_stop(nlp)}
    return ca.nlpsol("stoppable", "ipopt", nlp, options), nlp


def test_an_ipopt_solve_stops_at_its_first_iteration_past_the_deadline():
    solver, _ = _nlp_solver()
    solver(x0=np.ones(50), lbg=-1, ubg=1)
    free = solver.stats()
    with budget.solving(time.monotonic() - 1.0):
        solver(x0=np.ones(50), lbg=-1, ubg=1)
    stopped = solver.stats()
    assert free["return_status"] != "User_Requested_Stop" and free["iter_count"] > 1
    assert (stopped["return_status"], stopped["iter_count"]) == ("User_Requested_Stop", 0)
    with budget.solving(time.monotonic() + 60.0):
        solver(x0=np.ones(50), lbg=-1, ubg=1)
    assert solver.stats()["iter_count"] == free["iter_count"]


def _simulation(duration: float, intervals: int) -> simulate.SimulationRequest:
    t = np.linspace(0.0, duration, intervals + 1)
    return simulate.SimulationRequest.model_validate({
        "robot": TWO_LINK, "t": t.tolist(), "tau": [[0.2]] * len(t),
        "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]}, "samples_per_interval": 4,
        "rtol": 1e-12, "atol": 1e-12})


def _stop_point(pattern: str, message: str) -> float:
    match = re.fullmatch(pattern, message)
    assert match, message
    return float(match[1])


def test_a_simulation_stops_part_way_at_its_deadline_and_says_where():
    request = _simulation(100.0, 4000)
    started = time.monotonic()
    with pytest.raises(BudgetExceeded) as info:
        simulate.run(request, deadline=started + 0.3)
    where = _stop_point(r"the simulation \(at t = (\S+) s of 100 s\) ran past its deadline",
                        str(info.value))
    assert 0.0 < where < 100.0
    assert simulate.run(_simulation(1.0, 4)).status == "completed"  # no deadline, no bound


def test_one_long_interval_stops_between_its_outputs():
    """A torque interval is integrated output by output under a deadline: one CVODES call
    over a whole interval could run for minutes past it."""
    request = _simulation(100.0, 1).model_copy(update={"samples_per_interval": 100})
    with pytest.raises(BudgetExceeded) as info:
        simulate.run(request, deadline=time.monotonic() + 0.3)
    where = _stop_point(r"the simulation \(at t = (\S+) s of 100 s\) ran past its deadline",
                        str(info.value))
    assert 0.0 < where < 100.0


@pytest.mark.parametrize("kind", ["zoh", "linear", "cubic"])
def test_a_deadline_leaves_the_trajectory_as_it_was(kind):
    t = np.linspace(0.0, 2.0, 9)
    request = simulate.SimulationRequest.model_validate({
        "robot": TWO_LINK, "t": t.tolist(), "tau": np.sin(3 * t)[:, None].tolist(),
        "interpolation": kind, "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]},
        "samples_per_interval": 7, "rtol": 1e-12, "atol": 1e-12})
    free, bounded = simulate.run(request), simulate.run(request, deadline=time.monotonic() + 60)
    assert bounded.t == free.t and bounded.status == free.status == "completed"
    np.testing.assert_allclose(bounded.q, free.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(bounded.dq, free.dq, rtol=0, atol=1e-8)


def test_an_inverse_dynamics_stops_part_way_at_its_deadline():
    request = inverse.InverseDynamicsRequest.model_validate(
        {**examples.example("seed-arm-waves").request, "rtol": 1e-13, "atol": 1e-13})
    with pytest.raises(BudgetExceeded) as info:
        inverse.solve(request, deadline=time.monotonic() + 0.05)
    where = _stop_point(r"the inverse dynamics \(at t = (\S+) s of \S+ s\) ran past its "
                        r"deadline", str(info.value))
    assert 0.0 <= where < request.duration


def test_dynamics_and_coupling_check_their_deadline_as_they_go():
    states = [{"q": [0.1 * k, 0.2], "dq": [0.0, 0.0]} for k in range(3)]
    request = evaluation.DynamicsRequest.model_validate({"robot": TWO_LINK, "states": states})
    with pytest.raises(BudgetExceeded, match=r"^the dynamics \(at state 0 of 3\) ran past"):
        evaluation.evaluate(request, deadline=time.monotonic() - 1.0)
    grid = {"lower": [0.0, 0.0], "upper": [3.0, 3.0], "points": 300}
    request = coupling.CouplingRequest.model_validate({"robot": TWO_LINK, "grid": grid})
    with pytest.raises(BudgetExceeded, match=r"^the coupling analysis: the evaluation of Mpa "
                                             r"\(at configuration 0 of 90,000\) ran past"):
        coupling.analyse(request, deadline=time.monotonic() - 1.0)


@pytest.mark.parametrize("name", ["two-link-wave-design", "seed-arm-wave-design"])
def test_a_wave_design_stops_at_its_deadline(name):
    request = waves.WaveDesignRequest.model_validate(examples.example(name).request)
    with pytest.raises(BudgetExceeded, match=r"^the wave design\b.* ran past its deadline$"):
        waves.design(request, deadline=time.monotonic() + 0.2)


@pytest.mark.parametrize("region", [None, {"lower": [0.0, 1.4], "upper": [0.2, 1.8]},
                                    {"lower": [0.1, 1.4], "upper": [0.1, 1.8]}])
def test_the_screening_is_counted_as_the_design_builds_it(region):
    request = examples.example("two-link-wave-design").request
    if region is not None:
        request = {**request, "motion": None, "region": region}
    design = waves.WaveDesignRequest.model_validate(request)
    base = design.robot.without_waves()
    upper = np.full(len(base.active), design.amplitude_max)
    cands = screening.candidates(len(upper), design.frequency_max, upper,
                                 screening.phases_per_joint(len(upper)))
    per_candidate = (screening.SCREEN_STEPS + 1 if region is None else len(RegionProblem(
        design, wave_structure(base), base).samples))
    assert design.screening == len(cands) * per_candidate


def test_a_screening_too_large_is_refused_before_anything_is_built():
    eight = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.0,
                        "joint": "passive" if k % 2 == 0 else "active"} for k in range(8)],
             "gravity": 9.81}
    huge = {"robot": eight, "amplitude_max": 0.05, "frequency_max": 6, "margin": 0.01,
            "region": {"lower": [0.0] * 8, "upper": [1.0] * 8}}
    with pytest.raises(ValueError, match="frequency_max: the screening would evaluate "
                                         "136,048,896 configurations, more than the limit of "
                                         "5,000,000"):
        waves.WaveDesignRequest.model_validate(huge)


def test_concurrent_simulations_of_one_arm_agree_with_a_lone_one():
    """One integrator serves every simulation of an arm; called from several threads at
    once it corrupted its memory (the process died)."""
    request = _simulation(2.0, 40)
    alone = simulate.run(request)
    results: list[simulate.Trajectory] = []
    threads = [threading.Thread(target=lambda: results.append(simulate.run(request)))
               for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(results) == 4 and all(r == alone for r in results)


def test_chunks_check_the_deadline_before_every_chunk_the_first_included():
    parts = list(budget.chunks(10, 4, time.monotonic() + 60, "the thing", "point"))
    assert parts == [slice(0, 4), slice(4, 8), slice(8, 10)]
    with pytest.raises(BudgetExceeded, match=r"^the thing \(at point 0 of 10\) ran past"):
        next(budget.chunks(10, 4, time.monotonic() - 1.0, "the thing", "point"))


def test_the_inverse_dynamics_torques_and_a_minimum_refinement_check_their_deadline():
    request = inverse.InverseDynamicsRequest.model_validate(
        examples.example("two-link-waves").request)
    pb = inverse._Problem(request.robot, request.passive_motion, request.duration,
                          request.sigma_threshold, deadline=time.monotonic() - 1.0)
    q, dq = np.zeros((5000, 2)), np.zeros((5000, 2))
    with pytest.raises(BudgetExceeded, match=r"^the inverse dynamics' torques \(at sample 0 "
                                             r"of 5,000\) ran past"):
        inverse._torques(pb, q, dq, np.zeros((5000, 1)))
    with pytest.raises(BudgetExceeded, match=r"^the refinement ran past"):
        coupling_singularities._refine_minimum(
            request.robot, Structure.of(request.robot), np.array([0.0, 1.0]),
            np.array([0.5, 2.0]), np.array([0.2, 1.5]), time.monotonic() - 1.0, "the refinement")


def _long_output(duration: float, tau: float) -> simulate.SimulationRequest:
    return simulate.SimulationRequest.model_validate({
        "robot": TWO_LINK, "t": [0.0, duration], "tau": [[tau]] * 2,
        "initial": {"q": [0.3, -0.2], "dq": [0.0, 0.5]}, "rtol": 1e-12, "atol": 1e-12})


def test_an_output_of_many_steps_is_integrated_in_slices_to_the_same_state(monkeypatch):
    """Under a deadline one output is reached in CVODES calls of at most SLICE_STEPS steps
    (checked between them); the state is that of the one call made without a deadline,
    and an output that needs more than MAX_STEPS steps fails as it did."""
    calls: list[str] = []
    real = budget.check
    monkeypatch.setattr(budget, "check", lambda d, what: (calls.append(what), real(d, what)))
    request = _long_output(20.0, 0.2)  # about 7,000 steps
    free, bounded = simulate.run(request), simulate.run(request, deadline=time.monotonic() + 60)
    slices = sum(what.startswith("the simulation (at t = ") for what in calls)
    assert slices >= 2 and bounded.status == free.status == "completed"
    np.testing.assert_allclose(bounded.q, free.q, rtol=0, atol=1e-7)
    too_fast = _long_output(1.0, 1e4)
    assert simulate.run(too_fast, deadline=time.monotonic() + 60) == simulate.run(too_fast)
    assert simulate.run(too_fast).message.endswith(
        "more than 200000 steps before the next output (the motion is too fast for the "
        "tolerances) (CVODES CV_TOO_MUCH_WORK)")


def test_a_motion_nlp_is_not_built_when_its_build_would_end_past_the_deadline(monkeypatch):
    s = wave_structure(Robot.model_validate(TWO_LINK).without_waves())
    built, _ = motion_nlp.solver(s, 2)  # measures the pace of this arm's builds
    assert motion_nlp.solver(s, 2, time.monotonic() - 1.0)[0] is built  # built: no wait
    monkeypatch.setitem(motion_nlp._pace, s, 1.0)  # as if one interval took 1 s to build
    with pytest.raises(BudgetExceeded, match=r"^the motion NLP: building it for 3 collocation "
                                             r"intervals would take about 3 s \(at the pace "):
        motion_nlp.solver(s, 3, time.monotonic() + 2.5)
    assert (s, 3) not in motion_nlp._built
    assert motion_nlp.solver(s, 3, time.monotonic() + 3.5)[1] > 0
